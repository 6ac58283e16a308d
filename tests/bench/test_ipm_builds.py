"""``python -m mcverify.bench.ipm_builds``: two builds of the C interior point replayed on recorded
solves, bit for bit; a baseline built from a git revision; bad revisions refused in one line."""

from __future__ import annotations

import shutil
import subprocess

import pytest

from mcverify.bench import ipm_builds
from mcverify.bench import recorded_ipm as R
from mcverify.campaign.spec import campaign_from_dict
from mcverify.solver import kernels


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    raw = {"campaign": {"name": "rec", "seed": 3, "episodes": 1},
           "model": {"sim": {"max_time_s": 0.2}, "noise": {"kind": "paper"}}}
    path = tmp_path_factory.mktemp("rec") / "rec.pkl"
    R.save(R.record_engine([campaign_from_dict(raw).cells[0]], 3, [0]), path)
    return str(path)


def test_a_build_of_the_same_source_gives_the_same_bits(recording, tmp_path):
    for f in kernels.CSRC_DIR.iterdir():
        if f.suffix in (".c", ".h"):
            shutil.copy(f, tmp_path / f.name)
    kernels.compile_runtime(tmp_path / "ipm.c", tmp_path / "ipm.so", what="a copy")
    out = ipm_builds.compare([recording], tmp_path / "ipm.so", progress=lambda *a, **k: None)
    assert out["solves"] >= 10 and out["differ"] == 0
    assert all(row["runs"] > 0 for row in out["attempts"].values())  # every attempt kind was replayed
    assert out["runs"] == sum(row["runs"] for row in out["attempts"].values())
    assert "| all |" in ipm_builds.markdown(out)


def _git_head() -> bool:
    repo = kernels.CSRC_DIR.parents[2]
    return subprocess.run(["git", "-C", str(repo), "rev-parse", "HEAD"], capture_output=True).returncode == 0


@pytest.mark.skipif(not _git_head(), reason="not a git checkout")
def test_a_revision_is_compiled_with_the_bindings_abi(tmp_path):
    import ctypes

    from mcverify.solver.ipm import check_abi
    so = ipm_builds.build_revision("HEAD", tmp_path)
    assert (tmp_path / "ipm.h").is_file()
    check_abi(ctypes.CDLL(str(so)))  # raises if the build does not match the binding


def test_a_bad_revision_is_one_line(capsys, recording):
    assert ipm_builds.main(["--recording", recording, "--baseline-rev", "no-such-revision"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("mcverify: error: git revision 'no-such-revision'") and "\n" not in err
