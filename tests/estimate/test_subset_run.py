"""``mcverify estimate --method subset``: the folder, its report and resume, with the closed loop replaced
by the structure-matched surrogate (exact p) so that the mechanics run in seconds; the closed-loop
problem itself is tested in test_input_vector.py, and a failing sample's replay end to end (slow)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from mcverify.campaign.spec import load_campaign
from mcverify.cli import main
from mcverify.estimate import subset_run
from mcverify.estimate.surrogate import Surrogate

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "tiny.toml"
CELL = "front_speed_kmh=36"


@dataclass
class _SurrogateProblem:
    surrogate: Surrogate
    key: str = "surrogate"

    @property
    def dimension(self) -> int:
        return self.surrogate.dimension

    def evaluate(self, x):
        return self.surrogate.evaluate(x)


@pytest.fixture
def surrogate(monkeypatch):
    s = Surrogate.at(1e-3, clock="decision")
    monkeypatch.setattr(subset_run, "problem_for", lambda cell, seed, target, performance: _SurrogateProblem(s))
    monkeypatch.setattr(subset_run, "check_law", lambda cell: None)
    return s


@pytest.fixture
def asked(surrogate, monkeypatch):
    """The performance function each run asked for."""
    names = []

    def problem_for(cell, seed, target, performance):
        names.append(performance)
        return _SurrogateProblem(surrogate)

    monkeypatch.setattr(subset_run, "problem_for", problem_for)
    return names


def _estimate(out: Path) -> dict:
    cells = json.loads((out / "estimate.json").read_text())["cells"]
    return {k: v for k, v in cells[0].items() if k != "cpu_s"}


def test_subset_folder_holds_the_estimate_its_interval_and_cost(tmp_path, surrogate, asked):
    out = tmp_path / "sub"
    argv = ["estimate", str(FIXTURE), "--method", "subset", "--target", "ellipse", "--stage-samples", "200",
            "--replicates", "3", "--cell", CELL, "--run-dir", str(out), "-q"]
    assert main(argv) == 0
    c = _estimate(out)
    assert c["method"] == "subset" and c["target"] == "ellipse" and len(c["runs"]) == 3
    assert c["low"] <= c["estimate"] <= c["high"] and c["estimate"] > 0
    assert c["steps"] > 0 and c["crude_steps_same_width"] > 0 and c["within_run_cov"] > 0
    assert len(c["stages"]) == 3 and all(s >= 2 for s in c["stages"])
    assert len(c["failing_samples"]) > 0
    x, g = subset_run.failing_inputs(out, 1, c["failing_samples"][0]["run"])
    assert x.shape[1] == surrogate.dimension and np.all(g <= 0)
    assert np.array_equal(surrogate.performance(x), g)  # the kept inputs give back their robustness
    report = (out / "report.md").read_text()
    assert "Subset simulation over the whole input vector" in report and "| front_speed_kmh=36 |" in report
    assert main(["report", str(out)]) == 0  # rebuilt from the stored runs, running nothing
    assert (out / "report.md").read_text() == report
    assert asked == ["robustness"] * 3 and "precursor ladder" not in report


@pytest.mark.parametrize("ladder", ["precursor-ladder", "margin-ladder"])
def test_a_ladder_is_recorded_in_the_folder_and_its_report(tmp_path, asked, ladder):
    out = tmp_path / "sub"
    argv = ["estimate", str(FIXTURE), "--method", "subset", "--target", "ellipse", "--stage-samples", "100",
            "--replicates", "2", "--cell", CELL, "--performance", ladder, "--run-dir", str(out), "-q"]
    assert main(argv) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["estimate"]["performance"] == ladder
    assert asked == [ladder] * 2
    assert f"climbing the {ladder.replace('-', ' ')} (performance function: the robustness / (1 + " in (
        out / "report.md").read_text()


def test_an_interrupted_subset_estimate_resumes_to_the_uninterrupted_one(tmp_path, surrogate):
    campaign = load_campaign(FIXTURE)
    spec = subset_run.SubsetSpec("ellipse", samples=100, runs=2)
    subset_run.run(campaign, spec, tmp_path / "whole", progress=lambda msg: None, cells=[CELL])

    class Stop(KeyboardInterrupt):
        pass

    def stop_after_the_first_run(msg: str) -> None:
        if "run 0 done" in msg:
            raise Stop

    with pytest.raises(Stop):
        subset_run.run(campaign, spec, tmp_path / "cut", progress=stop_after_the_first_run, cells=[CELL])
    assert not (tmp_path / "cut" / "estimate.json").exists()
    subset_run.resume(tmp_path / "cut", campaign, progress=lambda msg: None)
    assert _estimate(tmp_path / "cut") == _estimate(tmp_path / "whole")


def test_subset_bad_options_are_one_line(capsys):
    for argv, message in (
        (["--p0", "0.3", "--stage-samples", "10"], "n * p0 must be an integer"),
        (["--replicates", "1"], "--replicates must be at least 2"),
        (["--particles", "4"], "--particles is for --method splitting"),
        (["--method", "splitting", "--performance", "precursor-ladder"], "--performance is for --method subset"),
        (["--set", "noise.structured_share=0.5"], "noise.structured_share = 0.5"),
    ):
        assert main(["estimate", str(FIXTURE), "--method", "subset", *argv]) == 2, argv
        err = capsys.readouterr().err.strip()
        assert message in err and len(err.splitlines()) == 1, err


def test_subset_dry_run_counts_stages(capsys):
    assert main(["estimate", str(FIXTURE), "--method", "subset", "--stage-samples", "100", "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "8 subset simulation runs per cell of 100 episodes per stage" in out
    assert "at p = 1e-05: about 5 stages per run, 3680 episodes per cell" in out
    assert "target collision (performance function robustness)" in out
    assert main(["estimate", str(FIXTURE), "--method", "subset", "--performance", "precursor-ladder", "--dry-run"]) == 0
    assert "(performance function precursor-ladder)" in capsys.readouterr().out


@pytest.mark.slow
def test_a_failing_closed_loop_sample_replays_bit_for_bit(tmp_path, capsys):
    """On the closed loop (tiny fixture, veh_f 18.5 m ahead: h_ef starts at 0.51 and falls below eps = 0.3
    within the 1 s episode at 25 km/h), every sample breaks invariance; a kept sample replays exactly."""
    out = tmp_path / "sub"
    cell = "front_speed_kmh=25"
    assert main(["estimate", str(FIXTURE), "--method", "subset", "--target", "invariance", "--stage-samples", "10",
                 "--p0", "0.2", "--replicates", "2", "--cell", cell, "--set", "scenario.front_x_m=18.5",
                 "--run-dir", str(out), "-q"]) == 0
    c = _estimate(out)
    assert c["estimate"] == 1.0 and len(c["failing_samples"]) == 20
    capsys.readouterr()
    assert main(["replay", str(out), "3", "--cell", cell]) == 0
    assert "failing sample 3 reproduced exactly" in capsys.readouterr().out
    assert main(["replay", str(out), "3", "--cell", cell, "--backend", "ipopt"]) == 0
    said = capsys.readouterr().out
    assert said.startswith("failing sample 3: ") and "invariance: event" in said
    assert main(["replay", str(out), "20", "--cell", cell]) == 2
    assert "has 20 failing samples (0 to 19), not 20" in capsys.readouterr().err


def test_each_run_says_every_stage_it_closes_unless_quiet(tmp_path, surrogate, capsys):
    argv = ["estimate", str(FIXTURE), "--method", "subset", "--target", "ellipse", "--stage-samples", "100",
            "--replicates", "2", "--cell", CELL]
    assert main([*argv, "--run-dir", str(tmp_path / "a")]) == 0
    err = capsys.readouterr().err
    stages = json.loads((tmp_path / "a" / "estimate.json").read_text())["cells"][0]["stages"]
    for run in (0, 1):
        lines = [ln for ln in err.splitlines() if ln.startswith(f"  cell {CELL} run {run}: ")]
        assert len(lines) == stages[run] and "the event, share" in lines[-1], err
        assert "level " in lines[0] and "(this stage 100 episodes" in lines[0] and "CPU-s so far" in lines[0]
    assert main([*argv, "--run-dir", str(tmp_path / "b"), "-q"]) == 0
    assert "CPU-s so far" not in capsys.readouterr().err
