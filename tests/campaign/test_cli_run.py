"""`mcverify run`: every user error is one line on stderr and exit status 2, no traceback, and
nothing already finished is touched."""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

import pytest
import synthetic_episodes as synth

from mcverify import cli, store
from mcverify.campaign import executors, runner
from mcverify.campaign.spec import campaign_from_dict

REPO = Path(__file__).resolve().parents[2]
FIXTURE = REPO / "tests" / "fixtures" / "tiny.toml"


def run_cli(capsys, *args: str) -> tuple[int, str]:
    code = cli.main(list(args))
    err = capsys.readouterr().err
    return code, err


def one_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("mcverify: error: "), err
    assert "Traceback" not in err
    return lines[0]


@pytest.fixture
def finished_run(tmp_path: Path) -> Path:
    camp = campaign_from_dict({"campaign": {"name": "s", "seed": 1, "episodes": 2}})
    run_dir = tmp_path / "done"
    runner.run(camp, run_dir, executor=executors.SerialExecutor(), chunk_size=1, progress=False,
               episode_fn=synth.episodes)
    return run_dir


def write(tmp_path: Path, text: str) -> str:
    path = tmp_path / "c.toml"
    path.write_text(text)
    return str(path)


HEAD = '[campaign]\nname = "x"\nepisodes = 2\n'


@pytest.mark.parametrize("text, fragment", [
    ("[campaign\nname = 1", "malformed TOML"),
    (HEAD + "[model.barrier]\nepsilonn = 0.2\n", "did you mean 'barrier.epsilon'"),
    (HEAD + "[model.sim]\nsubsteps = 2.5\n", "sim.substeps: expected an integer"),
    ('[campaign]\nname = "x"\nepisodes = -4\n', "episodes: must be >= 1"),
    (HEAD + "[model.barrier]\nepsilon = -0.3\n", "barrier.epsilon: must be >= 0"),
    (HEAD + '[grid]\n"noise.scale" = []\n', "non-empty list"),
    (HEAD + "[model.scenario]\nego_speed_mps = 30.0\n", "outside the ego speed range"),
    (HEAD + "[model.scenario]\nfront_accel_range_mps2 = [3.0, 1.0]\n", "front_accel_range_mps2"),
])
def test_bad_campaign_files(tmp_path, capsys, text, fragment):
    code, err = run_cli(capsys, "run", write(tmp_path, text), "--out", str(tmp_path / "out"))
    assert code == 2
    assert fragment in one_line(err)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("args, fragment", [
    (["run", "nope.toml"], "campaign file not found: nope.toml"),
    (["run", "."], "is a folder"),
    (["run"], "missing campaign file"),
    (["run", str(FIXTURE), "--episodes", "0"], "--episodes: must be >= 1"),
    (["run", str(FIXTURE), "--chunk-size", "0"], "--chunk-size: must be >= 1"),
    (["run", str(FIXTURE), "--workers", "two"], "expected an integer, got 'two'"),
    (["run", str(FIXTURE), "--executor", "slurm"], "invalid choice: 'slurm'"),
    (["run", str(FIXTURE), "--address", "10.1.2.3:6379"], "--address is for the Ray executor"),
    (["run", str(FIXTURE), "--frobnicate"], "unrecognized arguments: --frobnicate"),
    (["launch"], "invalid choice: 'launch'"),
    (["run", "--resume", "no/such/run"], "run folder not found: no/such/run"),
    (["run", str(FIXTURE), "--set", "mpc.backend"], "expected SECTION.FIELD=VALUE"),
    (["run", str(FIXTURE), "--set", "mpc.backnd=ipopt"], "did you mean 'mpc.backend'"),
    (["run", str(FIXTURE), "--set", "mpc.backend=cplex"], "unknown solver backend 'cplex'"),
    (["run", str(FIXTURE), "--set", "mpc.horizon=fifty"], "mpc.horizon"),
])
def test_bad_arguments(capsys, args, fragment):
    code, err = run_cli(capsys, *args)
    assert code == 2
    assert fragment in one_line(err)


def test_resume_errors(tmp_path, capsys, finished_run):
    (tmp_path / "empty").mkdir()
    code, err = run_cli(capsys, "run", "--resume", str(tmp_path / "empty"))
    assert code == 2 and "not an mcverify run folder (no manifest.json)" in one_line(err)

    ledger = (finished_run / store.LEDGER).read_bytes()
    report = (finished_run / "report.md").stat().st_mtime_ns
    # the one --resume rule (run, estimate, falsify): a complete folder is no error, and nothing is rewritten
    assert cli.main(["run", "--resume", str(finished_run)]) == 0
    assert capsys.readouterr().out.strip() == (f"{finished_run} is already complete: nothing to run "
                                               f"(`mcverify report {finished_run}` rebuilds its report)")
    assert (finished_run / "report.md").stat().st_mtime_ns == report
    for extra, fragment in [(["--episodes", "3"], "leave out --episodes"), (["--out", "x"], "leave out --out"),
                            (["--run-dir", "x"], "and --run-dir"),
                            (["--set", "mpc.backend=ipopt"], "and --set")]:
        code, err = run_cli(capsys, "run", "--resume", str(finished_run), *extra)
        assert code == 2 and fragment in one_line(err)
    assert (finished_run / store.LEDGER).read_bytes() == ledger, "finished work is untouched"

    code, err = run_cli(capsys, "run", str(FIXTURE), "--run-dir", str(finished_run))
    assert code == 2 and "already holds a run" in one_line(err)


def test_ray_errors_are_one_line(tmp_path, capsys, monkeypatch):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    code, err = run_cli(capsys, "run", str(FIXTURE), "--executor", "ray", "--address", f"127.0.0.1:{port}",
                        "--out", str(tmp_path / "a"))
    assert code == 2 and f"cannot reach the Ray cluster at 127.0.0.1:{port}" in one_line(err)
    monkeypatch.setitem(sys.modules, "ray", None)
    code, err = run_cli(capsys, "run", str(FIXTURE), "--executor", "ray", "--out", str(tmp_path / "b"))
    assert code == 2 and "pip install 'mcverify[ray]'" in one_line(err)
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_an_unwritable_output_folder_is_one_line(tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    code, err = run_cli(capsys, "run", str(FIXTURE), "--out", str(tmp_path / "file" / "run"))
    assert code == 2 and "file" in one_line(err)


def test_no_traceback_from_the_real_command(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[campaign]\nname = 'x'\nepisodes = 1\n[model.ego]\nspeed_max_mps = 'fast'\n")
    for args in (["run", str(bad)], ["run", "--resume", str(tmp_path)]):
        proc = subprocess.run([sys.executable, "-m", "mcverify.cli", *args], cwd=REPO, capture_output=True,
                              text=True, timeout=120)
        assert proc.returncode == 2, proc.stderr
        one_line(proc.stderr)
