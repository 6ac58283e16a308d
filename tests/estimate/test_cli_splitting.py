"""``mcverify estimate --method splitting`` end to end on the tiny real campaign (two 1 s cells):
the files, the flagged warnings of runs that cannot estimate, and a resume that keeps finished cells."""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow.parquet as pq
import pytest

import mcverify
from mcverify.campaign.spec import load_campaign
from mcverify.cli import main
from mcverify.estimate import replicates, splitting_run

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "tiny.toml"


def test_splitting_cli_writes_its_estimate_and_resumes(tmp_path: Path, capsys):
    out = tmp_path / "est"
    argv = ["estimate", str(FIXTURE), "--method", "splitting", "--particles", "2", "--replicates", "2",
            "--max-iterations", "1", "--run-dir", str(out)]
    assert main(argv) == 0
    est = json.loads((out / "estimate.json").read_text())
    assert [c["cell_index"] for c in est["cells"]] == [0, 1]
    for c in est["cells"]:
        assert c["target"] == "collision" and c["steps"] > 0 and c["cpu_s"] > 0
        assert any("iteration cap" in w for w in c["warnings"])  # 1 iteration cannot reach a collision
        assert any("only 2 AMS runs" in w and "--replicates 8" in w for w in c["warnings"])
    assert "| front_speed_kmh=25 |" in (out / "report.md").read_text()
    table = pq.read_table(out / "cells.parquet").to_pylist()  # the same results, one row per cell
    assert [r["cell_index"] for r in table] == [0, 1] and {r["method"] for r in table} == {"splitting"}
    assert [r["estimate"] for r in table] == [c["estimate"] for c in est["cells"]]
    assert table[0]["warnings"] == "; ".join(est["cells"][0]["warnings"])
    for c in est["cells"]:  # every run capped: no estimate, and the warning names the cause and the remedy
        assert c["capped"] == [True, True] and c["runs"] == [None, None]
        assert c["estimate"] is None and c["low"] is None and c["high"] is None
        assert any(w.startswith("not estimated") and "--max-iterations" in w for w in c["warnings"])
        assert not any("extinct" in w for w in c["warnings"])
    assert "| front_speed_kmh=25 | not estimated | - |" in (out / "report.md").read_text()
    assert mcverify.open_run(out).finished  # the manifest says the estimate is complete
    finished = json.loads((out / "manifest.json").read_text())["finished_utc"]
    before = (out / "estimate.json").read_text()
    report = (out / "report.md").read_text()
    (out / "report.md").unlink()
    capsys.readouterr()
    assert main(["estimate", "--resume", str(out)]) == 0  # complete: nothing run, nothing rewritten
    assert "is already complete: nothing to run" in capsys.readouterr().out
    assert (out / "estimate.json").read_text() == before and not (out / "report.md").exists()
    assert main(["report", str(out)]) == 0 and (out / "report.md").read_text() == report
    assert json.loads((out / "manifest.json").read_text())["finished_utc"] == finished
    assert main(argv) == 2 and "not empty" in capsys.readouterr().err


def test_splitting_bad_input_is_one_line(capsys):
    for argv, message in (
        (["estimate", str(FIXTURE), "--method", "splitting", "--until-halfwidth", "0.1"], "--until-halfwidth is for"),
        (["estimate", str(FIXTURE), "--method", "splitting", "--target", "unsafe"], "estimates --target collision or"),
        (["estimate", str(FIXTURE), "--method", "splitting", "--replicates", "1"],
         "--replicates must be at least 2 (got 1) for an interval"),
        (["estimate", str(FIXTURE), "--method", "splitting", "--particles", "1"],
         "--particles must be at least 2 (got 1): each AMS iteration kills 1 particle and branches the survivors"),
        (["estimate", str(FIXTURE), "--method", "splitting", "--score", "h_ef"], "not --target collision"),
    ):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert message in err and len(err.splitlines()) == 1, err


def test_an_interrupted_splitting_estimate_keeps_its_finished_runs(tmp_path: Path):
    """Each finished AMS run is on disk before it is reported: an interrupt after the first run leaves
    it there, --resume runs only the second, and the estimate is the uninterrupted one's (but CPU time)."""
    campaign = load_campaign(FIXTURE)
    spec = splitting_run.SplittingSpec("gap", particles=2, replicates=2, max_iterations=1)
    cells = ["front_speed_kmh=36"]
    splitting_run.run(campaign, spec, tmp_path / "whole", progress=lambda msg: None, cells=cells)

    class Stop(KeyboardInterrupt):
        pass

    def stop_after_the_first_run(msg: str) -> None:
        if "AMS run 0 done" in msg:
            raise Stop

    out = tmp_path / "stopped"
    with pytest.raises(Stop):
        splitting_run.run(campaign, spec, out, progress=stop_after_the_first_run, cells=cells)
    assert sorted(p.name for p in (out / replicates.RUNS).iterdir()) == ["cell001_run000.json"]
    assert not (out / "estimate.json").exists() and not mcverify.open_run(out).finished
    lines: list[str] = []
    splitting_run.resume(out, campaign, progress=lines.append)
    assert not any("AMS run 0 done" in line for line in lines), lines  # kept, not run again
    assert any("1 finished before, kept" in line for line in lines) and any("AMS run 1 done" in line for line in lines)
    assert mcverify.open_run(out).finished

    def without_cpu(path: Path) -> dict:
        (cell,) = json.loads((path / "estimate.json").read_text())["cells"]
        return {k: v for k, v in cell.items() if k != "cpu_s"}

    assert without_cpu(out) == without_cpu(tmp_path / "whole")
    assert len(without_cpu(out)["iterations"]) == 2


@pytest.mark.slow  # starts two worker processes (JAX, CasADi); the runs' local-worker determinism is tested by default
def test_splitting_runs_on_local_workers_give_the_same_estimate(tmp_path: Path):
    base = ["estimate", str(FIXTURE), "--method", "splitting", "--particles", "2", "--replicates", "2",
            "--max-iterations", "2", "--cell", "front_speed_kmh=36"]
    assert main([*base, "--run-dir", str(tmp_path / "serial")]) == 0
    assert main([*base, "--run-dir", str(tmp_path / "workers"), "--workers", "2"]) == 0
    a, b = (json.loads((tmp_path / d / "estimate.json").read_text())["cells"] for d in ("serial", "workers"))
    assert len(a) == len(b) == 1
    drop = lambda c: {k: v for k, v in c.items() if k != "cpu_s"}  # noqa: E731 - CPU time is the machine's
    assert drop(a[0]) == drop(b[0]) and len(a[0]["iterations"]) == 2


@pytest.mark.slow  # two AMS runs on the 8 s validation cell (about 50 s) and two replays
def test_a_failing_particle_replays_from_its_noise_lineage(tmp_path: Path, capsys):
    """Every particle at the failure level is kept with its lineage (episode id, noise branches) and
    `mcverify replay DIR K` re-simulates it from step 0 to the same running score, bit for bit."""
    campaign = Path(__file__).resolve().parents[2] / "campaigns" / "rare_validation_10hz.toml"
    out = tmp_path / "spl"
    assert main(["estimate", str(campaign), "--method", "splitting", "--target", "ellipse", "--score", "h_ef_run",
                 "--particles", "4", "--replicates", "2", "--seed", "4", "--set", "noise.scale=3",
                 "--set", "barrier.epsilon=0", "--run-dir", str(out), "-q"]) == 0
    (cell,) = json.loads((out / "estimate.json").read_text())["cells"]
    failing = cell["failing_particles"]
    assert len(failing) == 8 and all(p["score"] >= 0 for p in failing)
    assert failing[5]["branch_after_steps"]  # the particle replayed below was split off: its lineage is tested
    assert "`mcverify replay " in (out / "report.md").read_text()
    capsys.readouterr()
    assert main(["replay", str(out), "5"]) == 0
    assert "failing particle 5 reproduced exactly" in capsys.readouterr().out
    assert (out / "replay" / "cell000-particle-0005.png").stat().st_size > 0
    assert main(["replay", str(out), "8"]) == 2
    said = capsys.readouterr().err.strip()
    assert said == f"mcverify: error: {out}: cell all has 8 failing particles (0 to 7), not 8"
    est = json.loads((out / "estimate.json").read_text())
    est["cells"][0]["failing_particles"][5]["score"] += 1e-12
    (out / "estimate.json").write_text(json.dumps(est))
    assert main(["replay", str(out), "5"]) == 1
    assert "particle 5 does not reproduce" in capsys.readouterr().err
    for damage in ({"end_step": -3}, {"branch_ids": None}):  # a damaged record: one line, exit 2
        est["cells"][0]["failing_particles"][5].update(damage)
        (out / "estimate.json").write_text(json.dumps(est))
        assert main(["replay", str(out), "5"]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "its kept estimate is damaged" in err
