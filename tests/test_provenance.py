"""code_version: which edits refuse a resume (the simulation layers, C included) and which do not."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from mcverify import provenance

PACKAGE = provenance.PACKAGE_DIR


@pytest.fixture
def package_copy(tmp_path: Path) -> Path:
    """A copy of the package's source tree (no caches) to edit."""
    dst = tmp_path / "mcverify"
    shutil.copytree(PACKAGE, dst, ignore=shutil.ignore_patterns("__pycache__", "*.so", "*.o"))
    return dst


def _append(path: Path, text: str) -> None:
    path.write_text(path.read_text() + text)


def test_every_part_of_the_package_is_classified() -> None:
    parts = {p.name for p in PACKAGE.iterdir() if (p.is_dir() and (p / "__init__.py").exists()) or p.suffix == ".py"}
    classified = set(provenance.SIMULATION_PARTS) | set(provenance.PRESENTATION_PARTS)
    assert parts - classified == set(), "classify new modules in provenance.SIMULATION_PARTS or PRESENTATION_PARTS"
    assert not set(provenance.SIMULATION_PARTS) & set(provenance.PRESENTATION_PARTS)


def test_the_c_solver_enters_the_hash() -> None:
    names = {p.relative_to(PACKAGE).as_posix() for p in provenance.simulation_files()}
    assert "solver/csrc/ipm.c" in names and "sim/plant.py" in names and "model/params.py" in names
    assert not any(n.startswith(("reporting/", "analysis/", "cli/")) for n in names)


@pytest.mark.parametrize("edited", ["solver/csrc/ipm.c", "sim/plant.py", "ocp/__init__.py", "model/noise.py"])
def test_editing_a_simulation_file_changes_the_version(package_copy: Path, edited: str) -> None:
    before = provenance.source_digest(package_copy)
    _append(package_copy / edited, "\n/* edited */\n" if edited.endswith(".c") else "\n# edited\n")
    assert provenance.source_digest(package_copy) != before


def test_adding_a_module_to_a_simulation_layer_changes_the_version(package_copy: Path) -> None:
    before = provenance.source_digest(package_copy)
    (package_copy / "sim" / "new_agent.py").write_text("X = 1\n")
    assert provenance.source_digest(package_copy) != before


@pytest.mark.parametrize("edited", ["reporting/cell_figures.py", "analysis/summary.py", "cli/run.py"])
def test_editing_presentation_does_not_change_the_version(package_copy: Path, edited: str) -> None:
    before = provenance.source_digest(package_copy)
    _append(package_copy / edited, "\n# edited\n")
    assert provenance.source_digest(package_copy) == before


def test_code_version_and_its_differences() -> None:
    version = provenance.code_version()
    assert version["source_sha256"] == provenance.source_digest()
    assert len(version["source_sha256"]) == 64 and version["jax"] and version["casadi"]
    other = {**version, "source_sha256": "0" * 64, "jax": "0.0.1"}
    diffs = provenance.code_differences(version, other)
    assert len(diffs) == 2 and any("jax" in d for d in diffs) and any("source" in d for d in diffs)
    assert provenance.code_differences(version, dict(version)) == []


def test_import_mcverify_has_no_side_effects_on_jax() -> None:
    """Reading runs and statistics from a notebook must not switch JAX to 64 bits or cap XLA."""
    code = (
        "import os, mcverify, mcverify.analysis.stats, mcverify.store, jax\n"
        "print(jax.config.jax_enable_x64, 'xla_cpu_max_isa' in os.environ.get('XLA_FLAGS', ''))\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["False", "False"]


def test_the_simulation_layer_sets_x64_and_pins_the_isa_whatever_the_caller_set() -> None:
    code = "import os, mcverify.sim, jax\nprint(jax.config.jax_enable_x64, '|', os.environ['XLA_FLAGS'])\n"
    for callers in (None, "--xla_cpu_max_isa=AVX2 intra_op_parallelism_threads=1"):
        env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
        if callers is not None:
            env["XLA_FLAGS"] = callers
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
        assert out.returncode == 0, out.stderr
        x64, flags = out.stdout.split("|")
        assert x64.strip() == "True"
        assert flags.split()[0] == "--xla_cpu_max_isa=AVX" and "AVX2" not in flags


def test_pinning_replaces_the_callers_cpu_flags_first_and_keeps_the_others() -> None:
    env = {"XLA_FLAGS": "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1 "
                        "--xla_dump_to=/tmp/d --xla_cpu_enable_fast_math=true --xla_cpu_max_isa=AVX512"}
    provenance.pin_xla_flags(env)
    # first: XLA stops reading at "intra_op_parallelism_threads=1", which once dropped a cap put after it
    assert env["XLA_FLAGS"].split() == [
        "--xla_cpu_max_isa=AVX", "intra_op_parallelism_threads=1", "--xla_dump_to=/tmp/d"]
    empty: dict[str, str] = {}
    assert provenance.pin_xla_flags(empty) == "--xla_cpu_max_isa=AVX" == empty["XLA_FLAGS"]


def test_the_pinned_flags_are_part_of_the_code_version() -> None:
    assert provenance.code_version()["xla_flags"] == provenance.pinned_xla_flags() == "--xla_cpu_max_isa=AVX"
    other = {**provenance.code_version(), "xla_flags": "--xla_cpu_max_isa=AVX2"}
    assert provenance.code_differences(provenance.code_version(), other) == [
        "xla_flags --xla_cpu_max_isa=AVX -> --xla_cpu_max_isa=AVX2"]


@pytest.mark.parametrize("edited", sorted(provenance.NOT_RESULTS))
def test_modules_that_cannot_change_a_row_do_not_change_the_version(package_copy: Path, edited: str) -> None:
    """The progress bar, the dry run's estimate, the executors: editing them never refuses a resume."""
    assert (package_copy / edited).is_file(), f"NOT_RESULTS names {edited}, which does not exist"
    before = provenance.source_digest(package_copy)
    _append(package_copy / edited, "\n# edited\n")
    assert provenance.source_digest(package_copy) == before


@pytest.mark.parametrize("edited", ["campaign/spec.py", "campaign/work.py", "campaign/scheduler.py",
                                    "campaign/runner.py", "episode/row.py"])
def test_the_run_layer_that_makes_rows_still_changes_the_version(package_copy: Path, edited: str) -> None:
    """Cell expansion, error rows and the rebuild of a run from its manifest do change rows."""
    before = provenance.source_digest(package_copy)
    _append(package_copy / edited, "\n# edited\n")
    assert provenance.source_digest(package_copy) != before


def test_git_commit_is_dirty_unless_only_ignored_paths_changed(tmp_path, monkeypatch):
    """A benchmark writing its section into results/BENCHMARKS.md does not make its own commit dirty."""
    import subprocess

    from mcverify import provenance

    def git(*args: str) -> None:
        subprocess.run(["git", "-C", str(tmp_path), *args], check=True, capture_output=True)

    git("init", "-q")
    (tmp_path / "mcverify").mkdir()
    (tmp_path / "mcverify" / "x.py").write_text("a = 1\n")
    (tmp_path / "results").mkdir()
    (tmp_path / "results" / "BENCHMARKS.md").write_text("# page\n")
    git("add", "-A")
    git("-c", "user.email=t@t", "-c", "user.name=t", "commit", "-qm", "c")
    monkeypatch.setattr(provenance, "PACKAGE_DIR", tmp_path / "mcverify")
    head = provenance.git_commit(short=True)
    assert head and not head.endswith("+dirty")
    (tmp_path / "results" / "BENCHMARKS.md").write_text("# page\nsection\n")
    assert provenance.git_commit(short=True) == head + "+dirty"
    assert provenance.git_commit(short=True, ignore=("results/BENCHMARKS.md",)) == head
    (tmp_path / "mcverify" / "x.py").write_text("a = 2\n")
    assert provenance.git_commit(short=True, ignore=("results/BENCHMARKS.md",)) == head + "+dirty"
