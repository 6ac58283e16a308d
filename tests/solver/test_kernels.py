"""Kernel cache (mcverify.solver.kernels): hashing, reuse without a compiler, concurrency, list/clear."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from mcverify.model import ModelParams
from mcverify.ocp.problem import OcpStructure
from mcverify.solver import kernels

REPO = Path(__file__).resolve().parents[2]
TINY = OcpStructure(horizon=3, order_m=1)  # compiles in about a second


def fake_compiler_dir(tmp_path: Path, body: str) -> Path:
    """A folder holding an executable ``gcc`` script, to put first on PATH."""
    folder = tmp_path / "fakebin"
    folder.mkdir(exist_ok=True)
    script = folder / kernels.COMPILER
    script.write_text("#!/bin/sh\n" + body + "\n")
    script.chmod(0o755)
    return folder


def test_hash_is_stable_and_follows_structure():
    st = OcpStructure.from_params(ModelParams())
    assert kernels.kernel_hash(st) == kernels.kernel_hash(OcpStructure(50, 2))
    others = [
        dataclasses.replace(st, horizon=40),
        dataclasses.replace(st, order_m=3),
        dataclasses.replace(st, with_opposing=True),
        dataclasses.replace(st, uniform_dt=False),
    ]
    hashes = {kernels.kernel_hash(s) for s in [st, *others]}
    assert len(hashes) == 5
    name = kernels.kernel_name(st)
    assert name.startswith("tocbf-N50-m2-") and name.endswith(kernels.kernel_hash(st)[:12])


def test_numeric_params_do_not_change_the_kernel():
    p = ModelParams()
    q = dataclasses.replace(p, barrier=dataclasses.replace(p.barrier, ellipse_a_m=9.0, lambdas_m=(2.0, 0.1)))
    assert kernels.kernel_name(OcpStructure.from_params(p)) == kernels.kernel_name(OcpStructure.from_params(q))


def test_kernel_dir_resolution(monkeypatch, tmp_path):
    monkeypatch.delenv(kernels.ENV_KERNEL_DIR, raising=False)
    assert kernels.resolve_kernel_dir() == REPO / "kernels"  # source checkout
    monkeypatch.setenv(kernels.ENV_KERNEL_DIR, str(tmp_path))
    assert kernels.resolve_kernel_dir() == tmp_path
    assert kernels.resolve_kernel_dir(tmp_path / "x") == tmp_path / "x"


def test_build_list_and_clear(monkeypatch, tmp_path):
    monkeypatch.setenv(kernels.ENV_KERNEL_DIR, str(tmp_path))
    (tmp_path / "README.md").write_text("keep me\n")
    (tmp_path / "not-a-kernel").mkdir()
    kernel = kernels.get_kernel(TINY)
    assert kernel.so_path.is_file() and kernel.c_path.is_file()
    listed = kernels.list_kernels()
    assert [k["name"] for k in listed] == [kernel.name]
    manifest = json.loads((kernel.path / "manifest.json").read_text())
    for key in ("structure", "casadi_version", "compiler_command", "compile_seconds", "created", "hash"):
        assert key in manifest
    assert manifest["structure"] == dataclasses.asdict(TINY)
    assert manifest["hash"] == kernels.kernel_hash(TINY)
    assert kernels.get_kernel(TINY).manifest == manifest  # second call: cached
    assert kernels.clear_kernels() == 1
    assert kernels.list_kernels() == []
    assert (tmp_path / "README.md").read_text() == "keep me\n"
    assert (tmp_path / "not-a-kernel").is_dir()
    assert kernels.clear_kernels() == 0


def test_missing_compiler_gives_clear_error(monkeypatch, tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    monkeypatch.setenv("PATH", str(empty))
    with pytest.raises(kernels.KernelBuildError, match=r"gcc.*install a C compiler") as info:
        kernels.get_kernel(TINY, tmp_path / "k")
    assert "\n" not in str(info.value)
    assert list((tmp_path / "k").iterdir()) == [tmp_path / "k" / f".{kernels.kernel_name(TINY)}.lock"]


def test_failing_compiler_gives_clear_error(monkeypatch, tmp_path):
    fake = fake_compiler_dir(tmp_path, 'echo "fatal: broken toolchain" >&2; exit 1')
    monkeypatch.setenv("PATH", f"{fake}{os.pathsep}{os.environ['PATH']}")
    with pytest.raises(kernels.KernelBuildError, match="failed.*broken toolchain"):
        kernels.get_kernel(TINY, tmp_path / "k")
    assert kernels.list_kernels(tmp_path / "k") == []
    assert not any(p.name.startswith(".tmp-") for p in (tmp_path / "k").iterdir())


def run_python(code: str, env: dict, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)], env=env, cwd=REPO,
        capture_output=True, text=True, timeout=timeout,
    )


def test_second_process_reuses_cached_kernel_without_compiler(tmp_path):
    """The cache holds the N = 50 kernel; a process whose gcc always fails still solves."""
    kernels.get_kernel(OcpStructure.from_params(ModelParams()))  # make sure it is cached (same dir as below)
    marker = tmp_path / "compiler-was-called"
    fake = fake_compiler_dir(tmp_path, f'touch "{marker}"; exit 1')
    env = dict(os.environ)  # same cache directory ($MCVERIFY_KERNEL_DIR or the default) as this process
    env["PATH"] = f"{fake}{os.pathsep}{env['PATH']}"
    proc = run_python(
        """
        import numpy as np
        from mcverify.levels import Level
        from mcverify.model import ModelParams
        from mcverify.solver.mpc import MpcSolver
        level = Level(0.3, -0.3135)
        sol = MpcSolver(ModelParams()).solve(np.array([10., 0, 0, 10]), np.array([64., 0, 25 / 3.6]), 1, level)
        print("OK" if sol.success else "FAIL " + str(sol.status))
        """,
        env,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "OK"
    assert not marker.exists()


def test_concurrent_builds_compile_once(tmp_path):
    log = tmp_path / "gcc.log"
    real = shutil.which(kernels.COMPILER)
    fake = fake_compiler_dir(tmp_path, f'echo called >> "{log}"; exec "{real}" "$@"')
    env = dict(os.environ, PATH=f"{fake}{os.pathsep}{os.environ['PATH']}")
    env[kernels.ENV_KERNEL_DIR] = str(tmp_path / "k")
    code = """
        from mcverify.solver.kernels import get_kernel
        from mcverify.ocp.problem import OcpStructure
        print(get_kernel(OcpStructure(horizon=3, order_m=1)).hash)
    """
    procs = [
        subprocess.Popen([sys.executable, "-c", textwrap.dedent(code)], env=env, cwd=REPO,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for _ in range(2)
    ]
    outs = [p.communicate(timeout=120) for p in procs]
    assert all(p.returncode == 0 for p in procs), [o[1] for o in outs]
    assert outs[0][0] == outs[1][0] == kernels.kernel_hash(TINY) + "\n"
    assert log.read_text().count("called") == 1
    listed = kernels.list_kernels(tmp_path / "k")
    assert len(listed) == 1
    assert not any(p.name.startswith(".tmp-") for p in (tmp_path / "k").iterdir())


# ------------------------------------------------------------------------ runtime libraries


def test_runtime_library_built_once_listed_and_cleared(tmp_path, monkeypatch):
    lib = kernels.get_runtime_library("ipm", tmp_path)
    assert lib.so_path.is_file() and lib.so_path.name == "ipm.so"
    assert lib.name == f"rt-ipm-{kernels.runtime_hash('ipm')[:12]}"
    assert lib.manifest["compiler_command"] == " ".join([kernels.COMPILER, *kernels.RUNTIME_CFLAGS])
    # cached: a failing compiler is never called again
    fake = fake_compiler_dir(tmp_path, "exit 1")
    monkeypatch.setenv("PATH", f"{fake}{os.pathsep}{os.environ['PATH']}")
    assert kernels.get_runtime_library("ipm", tmp_path).manifest == lib.manifest
    assert [k["name"] for k in kernels.list_kernels(tmp_path)] == [lib.name]
    assert kernels.clear_kernels(tmp_path) == 1
    assert kernels.list_kernels(tmp_path) == []


def test_runtime_library_compiler_failure_is_one_line(tmp_path, monkeypatch):
    fake = fake_compiler_dir(tmp_path, 'echo "fatal: no space left" >&2; exit 1')
    monkeypatch.setenv("PATH", f"{fake}{os.pathsep}{os.environ['PATH']}")
    with pytest.raises(kernels.KernelBuildError, match="ipm runtime library.*no space left") as info:
        kernels.get_runtime_library("ipm", tmp_path / "k")
    assert "\n" not in str(info.value)
    assert not any(p.name.startswith(".tmp-") for p in (tmp_path / "k").iterdir())


def test_runtime_hash_follows_the_source(monkeypatch, tmp_path):
    src = tmp_path / "csrc"
    src.mkdir()
    (src / "ipm.c").write_text((kernels.CSRC_DIR / "ipm.c").read_text())
    monkeypatch.setattr(kernels, "CSRC_DIR", src)
    h = kernels.runtime_hash("ipm")
    (src / "ipm.c").write_text((kernels.CSRC_DIR / "ipm.c").read_text() + "\n/* changed */\n")
    assert kernels.runtime_hash("ipm") != h


def test_runtime_hash_follows_the_headers(monkeypatch, tmp_path):
    """ipm.c includes ipm.h: a change of the header (a constant, a struct) must rebuild the library."""
    src = tmp_path / "csrc"
    shutil.copytree(kernels.CSRC_DIR, src)
    monkeypatch.setattr(kernels, "CSRC_DIR", src)
    h = kernels.runtime_hash("ipm")
    header = (src / "ipm.h").read_text()
    (src / "ipm.h").write_text(header.replace("#define IPM_KAPPA_SOC 0.99", "#define IPM_KAPPA_SOC 0.9"))
    assert kernels.runtime_hash("ipm") != h
    (src / "ipm.h").write_text(header)
    assert kernels.runtime_hash("ipm") == h


def test_header_is_installed_with_the_package():
    pyproject = (REPO / "pyproject.toml").read_text()
    assert '"mcverify.solver" = ["csrc/*.c", "csrc/*.h"]' in pyproject
    assert '#include "ipm.h"' in (kernels.CSRC_DIR / "ipm.c").read_text()
