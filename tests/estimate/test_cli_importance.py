"""``mcverify estimate --method importance`` end to end on a tiny real campaign whose front vehicle
draws its acceleration from a range: scenario values replace the episode's own draws, the folder's
files, diagnostics and warnings, and resume."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

import mcverify
import mcverify.errors
from mcverify.campaign import executors
from mcverify.campaign.spec import campaign_from_dict
from mcverify.cli import main
from mcverify.episode.rollout import run_episodes
from mcverify.estimate.importance_run import scenario_bounds, scenario_nominal

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "tiny.toml"


@pytest.fixture
def campaign_file(tmp_path: Path) -> Path:
    text = FIXTURE.read_text().replace('[grid]\n"scenario.front_speed_kmh" = [25, 36]',
                                       '[model.scenario]\nfront_accel_range_mps2 = [1.0, 3.0]')
    path = tmp_path / "tiny_range.toml"
    path.write_text(text)
    return path


def test_given_scenario_values_replace_the_draws():
    camp = campaign_from_dict({"campaign": {"name": "r", "seed": 1, "episodes": 1},
                               "model": {"sim": {"control_period_s": 0.1, "substeps": 20, "max_time_s": 0.5},
                                         "scenario": {"front_accel_range_mps2": [1.0, 3.0]}}})
    cell = camp.cells[0]
    assert scenario_bounds(cell) == {"front_accel_mps2": (1.0, 3.0)}
    planner = executors.solver_for(cell.params)
    own = run_episodes(cell, [0], camp.seed, planner).rows[0]
    given = run_episodes(cell, [0], camp.seed, planner, scenarios={0: {"front_accel_mps2": 2.5}}).rows[0]
    assert given["sample_front_accel_mps2"] == 2.5 != own["sample_front_accel_mps2"]


def test_veh_o_arrival_draws_are_sampling_parameters():
    opposing = {"kind": "human", "spawn": "lane_entry", "spawn_gap_range_m": [100.0, 200.0],
                "spawn_delay_range_s": [0.0, 8.0], "speed_range_mps": [8.0, 18.0]}
    camp = campaign_from_dict({"campaign": {"name": "r", "seed": 1, "episodes": 1},
                               "model": {"opposing": opposing}})
    assert scenario_bounds(camp.cells[0]) == {"opp_speed_mps": (8.0, 18.0), "opp_spawn_gap_m": (100.0, 200.0),
                                              "opp_spawn_delay_s": (0.0, 8.0)}
    at_start = campaign_from_dict({"campaign": {"name": "r", "seed": 1, "episodes": 1},
                                   "model": {"opposing": {**opposing, "spawn": "start"}}})
    assert scenario_bounds(at_start.cells[0]) == {"opp_speed_mps": (8.0, 18.0)}  # gap and delay do not apply
    jitter = campaign_from_dict({"campaign": {"name": "r", "seed": 1, "episodes": 1},
                                 "model": {"opposing": {**opposing, "spawn_delay_s": 1.5, "spawn_delay_sd_s": 0.125}}})
    assert scenario_nominal(jitter.cells[0]).describe(list(scenario_bounds(jitter.cells[0]))) == [
        "opp_speed_mps ~ uniform on [8, 18]", "opp_spawn_gap_m ~ uniform on [100, 200]",
        "opp_spawn_delay_s ~ normal(1.5, 0.125) truncated to [0, 8]"]


def test_importance_cli_writes_its_estimate_and_resumes(tmp_path: Path, campaign_file: Path, capsys):
    out = tmp_path / "est"
    argv = ["estimate", str(campaign_file), "--method", "importance", "--target", "ellipse", "--samples", "8",
            "--ce-samples", "8", "--ce-iterations", "1", "--run-dir", str(out)]
    assert main(argv) == 0
    est = json.loads((out / "estimate.json").read_text())
    (cell,) = est["cells"]
    assert cell["parameters"] == ["front_accel_mps2"] and cell["episodes"] == 16 and cell["cpu_s"] > 0
    assert cell["failures"] == 0 and any("failing samples" in w for w in cell["warnings"])  # 1 s episodes: safe
    report = (out / "report.md").read_text()
    assert "ESS" in report and "![importance_cell000](figures/importance_cell000.png)" in report
    assert (out / "figures" / "importance_cell000.png").stat().st_size > 0
    (row,) = pq.read_table(out / "cells.parquet").to_pylist()
    assert row["method"] == "importance" and row["estimate"] == cell["estimate"]
    assert row["parameters"] == "front_accel_mps2"
    assert mcverify.open_run(out).finished  # the manifest says the estimate is complete
    finished = json.loads((out / "manifest.json").read_text())["finished_utc"]
    before = (out / "estimate.json").read_text()
    assert main(["estimate", "--resume", str(out)]) == 0
    assert (out / "estimate.json").read_text() == before
    for extra in (["--set", "noise.scale=2"], ["--seed", "3"]):  # the folder keeps its model and seed
        assert main(["estimate", "--resume", str(out), *extra]) == 2
        assert "--resume keeps the estimate's campaign, seed and settings" in capsys.readouterr().err
    assert json.loads((out / "manifest.json").read_text())["finished_utc"] == finished


def test_a_cell_without_ranges_is_refused(tmp_path: Path, capsys):
    assert main(["estimate", str(FIXTURE), "--method", "importance", "--run-dir", str(tmp_path / "x")]) == 2
    assert "draws no scenario parameter from a range" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()  # refused before any folder is made, so a retry is not blocked


def test_the_score_that_steers_cross_entropy_is_the_splitting_score_at_the_episode_end():
    from mcverify.estimate.closed_loop import HELD_FACTOR
    from mcverify.estimate.importance_run import ClosedLoopScore

    held = ClosedLoopScore(None, 0, None, [], target="ellipse", score="h_ef_held")
    plain = ClosedLoopScore(None, 0, None, [], target="ellipse")
    row = {"outcome": "overtook", "min_h_front": 0.4, "both_infeasible_steps": 3}
    assert plain._score(row) == -0.4
    assert held._score(row) == pytest.approx(-0.4 * HELD_FACTOR ** 3)
    # the event itself scores the same (>= 0) under both: the estimate counts the same episodes
    inside = {"outcome": "overtook", "min_h_front": -0.2, "both_infeasible_steps": 6}
    assert held._score(inside) == plain._score(inside) == 0.2
    assert held._score({"outcome": "error"}) == -float("inf")


def test_importance_score_must_fit_the_target(tmp_path: Path, campaign_file: Path, capsys):
    argv = ["estimate", str(campaign_file), "--method", "importance", "--target", "collision", "--score", "h_ef_held",
            "--run-dir", str(tmp_path / "x")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "does not steer towards --target collision" in err[0]


def test_the_scenario_draws_follow_the_seed(tmp_path: Path, campaign_file: Path, monkeypatch):
    """Repetitions with distinct --seed are independent: the cross-entropy and mixture draws of the
    scenario parameters change with the seed (and replay with it), not only the episodes' noise."""
    from mcverify.estimate import importance_run

    drawn: list[np.ndarray] = []

    def no_episodes(self, theta):  # the draws are what is checked: no closed loop needed
        drawn.append(np.array(theta))
        return np.full(theta.shape[0], -1.0)

    monkeypatch.setattr(importance_run.ClosedLoopScore, "__call__", no_episodes)
    runs = {}
    for name, seed in (("a", 1), ("b", 2), ("c", 1)):
        drawn.clear()
        assert main(["estimate", str(campaign_file), "--method", "importance", "--target", "ellipse", "--samples",
                     "6", "--ce-samples", "10", "--ce-iterations", "1", "--seed", str(seed), "--run-dir",
                     str(tmp_path / name), "-q"]) == 0
        runs[name] = np.concatenate(drawn)
    assert np.array_equal(runs["a"], runs["c"])
    assert not np.allclose(runs["a"], runs["b"])


def test_the_cells_of_one_campaign_draw_their_own_scenarios(tmp_path: Path, monkeypatch):
    """Two cells of one estimate (same --seed) are independent estimates: their cross-entropy and
    mixture draws differ (they used to coincide: the draws were keyed by the seed alone)."""
    from mcverify.estimate import importance_run

    path = tmp_path / "two_cells.toml"
    path.write_text(FIXTURE.read_text() + '\n[model.scenario]\nfront_accel_range_mps2 = [1.0, 3.0]\n')
    drawn: dict[str, list[np.ndarray]] = {}

    def no_episodes(self, theta):
        drawn.setdefault(self.cell.name, []).append(np.array(theta))
        return np.full(theta.shape[0], -1.0)

    monkeypatch.setattr(importance_run.ClosedLoopScore, "__call__", no_episodes)
    assert main(["estimate", str(path), "--method", "importance", "--target", "ellipse", "--samples", "6",
                 "--ce-samples", "10", "--ce-iterations", "1", "--seed", "5", "--run-dir", str(tmp_path / "o"),
                 "-q"]) == 0
    first, second = (np.concatenate(v) for v in drawn.values())
    assert len(drawn) == 2 and not np.allclose(first, second)


@pytest.mark.parametrize("method", ["mc", "splitting", "importance"])
def test_a_campaign_that_fixes_the_noise_is_refused(tmp_path: Path, campaign_file: Path, capsys, method):
    """noise.key_seed replaces the campaign seed in every episode key: such an estimate would ignore
    --seed, so it is refused with one line before anything is written."""
    rc = main(["estimate", str(campaign_file), "--method", method, "--target", "ellipse", "--set",
               "noise.key_seed=5", "--run-dir", str(tmp_path / "o"), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "fixes the per-step noise (noise.key_seed)" in err[0]
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


def test_parallel_batches_give_the_same_estimate(tmp_path: Path, campaign_file: Path):
    """--workers 2 runs the batches of episodes as parallel work units; an episode does not depend
    on its batch or on the order the units finish in, so the estimate is the one of this process."""
    args = ["estimate", str(campaign_file), "--method", "importance", "--target", "ellipse", "--samples", "16",
            "--ce-samples", "10", "--ce-iterations", "1", "--seed", "3", "-q"]
    assert main([*args, "--run-dir", str(tmp_path / "here")]) == 0
    assert main([*args, "--workers", "2", "--run-dir", str(tmp_path / "two")]) == 0
    here, two = (json.loads((tmp_path / d / "estimate.json").read_text())["cells"][0] for d in ("here", "two"))
    same = ("estimate", "low", "high", "failures", "ess", "proposal_a", "proposal_b", "ce_levels", "episodes", "steps")
    assert {k: here[k] for k in same} == {k: two[k] for k in same}
    assert two["cpu_s"] > 0


TILT = "gap_max_m=1000,split_m=30,y_approach=-3,y_jump=3"  # a window the 1 s episodes are inside of


def test_a_noise_tilt_draws_inside_its_window_only():
    """In its window the tilt draws and weighs; a window the episodes never reach leaves every row as
    the plain run's, bit for bit (only the tilt's own keys are added, with ratio 1)."""
    from mcverify.sim.noise import NoiseTilt  # noqa: PLC0415

    camp = campaign_from_dict({"campaign": {"name": "r", "seed": 1, "episodes": 1},
                               "model": {"sim": {"control_period_s": 0.1, "substeps": 20, "max_time_s": 1.0},
                                         "noise": {"kind": "paper"}}})
    cell = camp.cells[0]
    planner = executors.solver_for(cell.params)
    plain = run_episodes(cell, [0, 1], camp.seed, planner).rows
    y = np.zeros(9)
    y[1], y[4] = -3.0, 3.0
    unreached = run_episodes(cell, [0, 1], camp.seed, planner,
                             noise_tilt=NoiseTilt(theta=tuple(y), split_m=2.2, gap_max_m=2.5)).rows
    tilted = run_episodes(cell, [0, 1], camp.seed, planner,
                          noise_tilt=NoiseTilt(theta=tuple(y), split_m=30.0, gap_max_m=1000.0, band_steps=3)).rows
    tilt_keys = ("noise_log_lr", "noise_tilt_sums", "noise_tilt_counts", "solve_time_mean_s", "solve_time_max_s")
    for a, b in zip(plain, unreached, strict=True):
        assert {k: v for k, v in a.items() if k not in tilt_keys} == {k: v for k, v in b.items() if k not in tilt_keys}
        assert b["noise_log_lr"] == 0.0 and b["noise_tilt_counts"] == [0.0, 0.0, 0.0]
    for row in tilted:
        assert row["noise_tilt_counts"] == [3.0, 0.0, 0.0] and row["noise_log_lr"] != 0.0  # veh_f over 30 m ahead


@pytest.mark.slow  # two closed-loop estimates (25-45 s); the tilt's draws and worker invariance are tested apart
def test_the_noise_tilt_cli_records_the_fitted_tilt_and_runs_the_same_on_workers(tmp_path: Path, campaign_file: Path):
    args = ["estimate", str(campaign_file), "--method", "importance", "--target", "ellipse", "--samples", "16",
            "--ce-samples", "10", "--ce-iterations", "1", "--seed", "3", "--noise-tilt", TILT, "-q"]
    assert main([*args, "--run-dir", str(tmp_path / "here")]) == 0
    assert main([*args, "--workers", "2", "--run-dir", str(tmp_path / "two")]) == 0
    here, two = (json.loads((tmp_path / d / "estimate.json").read_text())["cells"][0] for d in ("here", "two"))
    assert len(here["noise_tilt"]["theta"]) == 9 and here["noise_tilt"]["gap_max_m"] == 1000.0
    same = ("estimate", "low", "high", "failures", "ess", "proposal_a", "proposal_b", "noise_tilt", "episodes")
    assert {k: here[k] for k in same} == {k: two[k] for k in same}
    assert "noise tilt" in (tmp_path / "here" / "report.md").read_text()


@pytest.mark.parametrize("extra, message", [
    (["--method", "importance", "--noise-tilt", "y_jump=3"], "gap_max_m is required"),
    (["--method", "importance", "--noise-tilt", "gap_max_m=3,y_jmp=3"], "expected KEY=VALUE"),
    (["--method", "importance", "--noise-tilt", "gap_max_m=3,defensive=0"], "defensive in (0, 1]"),
    (["--method", "splitting", "--noise-tilt", "gap_max_m=3"], "--noise-tilt is a proposal of --method importance"),
])
def test_a_bad_noise_tilt_is_one_line(tmp_path: Path, campaign_file: Path, capsys, extra, message):
    rc = main(["estimate", str(campaign_file), *extra, "--run-dir", str(tmp_path / "o"), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and message in err[0]


def test_the_final_draws_are_kept_and_give_the_estimate(tmp_path: Path, campaign_file: Path):
    """samples_cell000.parquet holds the final draws: mean(weight * failed) is the stored estimate,
    exactly, and each draw's scenario value lies in the cell's range."""
    import pyarrow.parquet as pq  # noqa: PLC0415

    out = tmp_path / "est"
    assert main(["estimate", str(campaign_file), "--method", "importance", "--target", "ellipse", "--samples", "12",
                 "--ce-samples", "10", "--ce-iterations", "1", "--seed", "4", "--noise-tilt", TILT, "--run-dir",
                 str(out), "-q"]) == 0
    cell = json.loads((out / "estimate.json").read_text())["cells"][0]
    kept = pq.read_table(out / "samples_cell000.parquet").to_pydict()
    weight, failed = np.array(kept["weight"]), np.array(kept["failed"])
    assert len(weight) == 12 and kept["cell_episode"] == list(range(10, 22))
    assert float((weight * failed).mean()) == cell["estimate"]
    assert all(1.0 <= a <= 3.0 for a in kept["sample_front_accel_mps2"]) and all(np.isfinite(kept["noise_log_lr"]))


def test_quiet_keeps_the_progress_lines_off_stderr(tmp_path: Path, campaign_file: Path, capsys):
    args = ["estimate", str(campaign_file), "--method", "importance", "--target", "ellipse", "--samples", "4",
            "--ce-samples", "4", "--ce-iterations", "1"]
    assert main([*args, "--run-dir", str(tmp_path / "loud")]) == 0
    assert "cross-entropy iteration" in capsys.readouterr().err
    assert main([*args, "--run-dir", str(tmp_path / "quiet"), "-q"]) == 0
    err = capsys.readouterr().err
    assert "cross-entropy iteration" not in err and "estimate folder" not in err


@pytest.mark.parametrize("workers", [None, pytest.param("2", marks=pytest.mark.slow)])
def test_an_interrupt_mid_cell_resumes_to_the_uninterrupted_estimate(tmp_path: Path, campaign_file: Path,
                                                                      monkeypatch, workers):
    """Killed after two batches of the cell in progress, --resume reruns only the batches that were not
    finished and ends with the uninterrupted run's estimate and final draws."""
    from mcverify.estimate import evaluations, importance_run  # noqa: PLC0415

    extra = ["--workers", workers] if workers else []
    args = ["estimate", str(campaign_file), "--method", "importance", "--target", "ellipse", "--samples", "16",
            "--ce-samples", "16", "--ce-iterations", "1", "--seed", "5", "-q", *extra]
    assert main([*args, "--run-dir", str(tmp_path / "whole")]) == 0

    batches = []
    real = importance_run.ClosedLoopScore._keep

    def keep_then_stop(self, rows, values):
        real(self, rows, values)
        batches.append(len(rows))
        if len(batches) == 2:
            raise KeyboardInterrupt

    monkeypatch.setattr(importance_run.ClosedLoopScore, "_keep", keep_then_stop)
    cut = tmp_path / "cut"
    assert main([*args, "--run-dir", str(cut)]) == 130
    kept = evaluations.cache_file(cut, 0)
    assert len(kept.read_text().splitlines()) == 16  # two batches of 8
    monkeypatch.setattr(importance_run.ClosedLoopScore, "_keep", real)

    ran = []
    real_run = importance_run.run_episodes if not workers else None
    if not workers:
        monkeypatch.setattr(importance_run, "run_episodes", lambda *a, **k: ran.append(a[1]) or real_run(*a, **k))
    assert main(["estimate", "--resume", str(cut), "-q", *extra]) == 0
    if not workers:
        assert sorted(e for part in ran for e in part) == list(range(16, 32))  # the kept 16 did not run again
    whole, resumed = (json.loads((tmp_path / d / "estimate.json").read_text())["cells"][0] for d in ("whole", "cut"))
    same = ("estimate", "low", "high", "failures", "ess", "proposal_a", "proposal_b", "ce_levels", "episodes", "steps")
    assert {k: whole[k] for k in same} == {k: resumed[k] for k in same}
    draws = [pq.read_table(d / "samples_cell000.parquet").to_pylist() for d in (tmp_path / "whole", cut)]
    assert repr(draws[0]) == repr(draws[1])  # repr: NaN (no turn to Q2) reads the same on both sides
    assert not kept.exists()  # removed once the cell is stored


def test_a_final_draw_replays_bit_for_bit_with_the_fitted_noise_tilt(tmp_path: Path, campaign_file: Path, capsys):
    """``mcverify replay ESTIMATE_DIR EPISODE`` re-simulates a final draw from its scenario values and the
    noise tilt the final draws came from; a kept value that differs is a failed replay (exit 1)."""
    out = tmp_path / "est"
    assert main(["estimate", str(campaign_file), "--method", "importance", "--target", "ellipse", "--samples", "8",
                 "--ce-samples", "8", "--ce-iterations", "1", "--seed", "4", "--noise-tilt", TILT, "-q",
                 "--run-dir", str(out)]) == 0
    draws = pq.read_table(out / "samples_cell000.parquet").to_pylist()
    assert [d["cell_episode"] for d in draws] == list(range(8, 16))
    assert len({d["noise_log_lr"] for d in draws}) > 1  # the tilt weighs each draw: a replay must redraw it
    capsys.readouterr()
    assert main(["replay", str(out), "13"]) == 0
    said = capsys.readouterr().out
    assert "episode 13 reproduced exactly (the values its estimate folder keeps)" in said
    assert (out / "replay" / "cell000-episode-000013.parquet").is_file()
    # the audit: the draw replayed exactly, then on the same inputs with IPOPT at every step
    assert main(["replay", str(out), "13", "--backend", "ipopt"]) == 0
    said = capsys.readouterr().out
    assert said.startswith("final draw 13: ") and "the reference solver ipopt: " in said
    assert ("confirmed by the reference solver" in said) != ("solver-dependent" in said)
    assert (out / "replay" / "cell000-episode-000013-ipopt.parquet").is_file()
    assert main(["replay", str(out), "3"]) == 2  # a cross-entropy episode: not kept
    assert capsys.readouterr().err.strip() == (f"mcverify: error: {out}: episode 3 of cell all is not a kept final "
                                               "draw; the final draws are episodes 8 to 15 (the cross-entropy "
                                               "iterations' are not kept)")
    assert main(["replay", str(out), "13", "--cell", "nope"]) == 2
    assert capsys.readouterr().err.strip() == f"mcverify: error: {out}: no estimated cell 'nope'; cells: all"
    table = pq.read_table(out / "samples_cell000.parquet")
    lr = table.column("noise_log_lr").to_pylist()
    lr[5] += 1e-12  # the draw of episode 13
    pq.write_table(table.set_column(table.schema.get_field_index("noise_log_lr"), "noise_log_lr", [lr]),
                   out / "samples_cell000.parquet")
    assert main(["replay", str(out), "13"]) == 1
    assert "noise_log_lr: stored" in capsys.readouterr().err
    lr[5] -= 1e-12
    weight = table.column("weight").to_pylist()
    weight[5] *= 2  # the estimate is mean(weight * failed): a weight that the proposal does not give is caught
    table = table.set_column(table.schema.get_field_index("noise_log_lr"), "noise_log_lr", [lr])
    pq.write_table(table.set_column(table.schema.get_field_index("weight"), "weight", [weight]),
                   out / "samples_cell000.parquet")
    assert main(["replay", str(out), "13"]) == 1
    assert "weight: stored" in capsys.readouterr().err
    pq.write_table(table.drop_columns(["sample_front_accel_mps2"]), out / "samples_cell000.parquet")
    assert main(["replay", str(out), "13"]) == 2  # a damaged folder is one line, not a traceback
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "its kept estimate is damaged (KeyError" in err
    with pytest.raises(mcverify.errors.RunError, match="must be an integer >= 0, not -1"):
        mcverify.replay(out, -1)
    with pytest.raises(mcverify.errors.RunError, match="must be an integer >= 0, not '13'"):
        mcverify.replay(out, "13")


def test_the_report_names_the_replay_of_the_first_failing_draw():
    from mcverify.estimate.importance_run import _replay_text  # noqa: PLC0415

    cell = {"cell": "scenario=A,method=MPC-DC eps=0.3", "failing_draws": [131, 140]}
    assert _replay_text(Path("/r/e st"), cell, 1) == "`mcverify replay '/r/e st' 131` (2 failing)"
    assert _replay_text(Path("/r/e"), cell, 8) == (
        "`mcverify replay /r/e 131 --cell 'scenario=A,method=MPC-DC eps=0.3'` (2 failing)")
    assert _replay_text(Path("/r/e"), {"cell": "all", "failing_draws": []}, 1) == "-"
    assert _replay_text(Path("/r/e"), {"cell": "all"}, 1) == "-"  # a folder from before the column


def test_an_estimate_describes_its_cells_without_the_campaigns_episode_counts(tmp_path: Path, campaign_file: Path,
                                                                               capsys):
    """The estimator chooses its episodes: the start notice must not promise the file's `episodes`."""
    args = ["estimate", str(campaign_file), "--method", "importance", "--target", "ellipse", "--samples", "2",
            "--ce-samples", "2", "--ce-iterations", "0", "--run-dir", str(tmp_path / "e")]
    assert main(args) == 0
    err = capsys.readouterr().err
    assert "tiny: 1 cells\n  [0] all eps=" in err and "episodes=" not in err


def test_estimate_dry_run_plans_each_method_and_makes_no_folder(tmp_path, capsys):
    """``estimate --dry-run``: every check of a new estimate, the episodes each method may run (from its
    options) and a CPU range; nothing is made."""
    jitter = "campaigns/veh_o_arrival_jitter.toml"
    out = str(tmp_path / "e")
    assert main(["estimate", jitter, "--method", "importance", "--ce-samples", "40", "--ce-iterations", "8",
                     "--samples", "200", "--dry-run", "--run-dir", out]) == 0
    text = capsys.readouterr().out
    assert "importance, target collision, 1 cell(s)" in text
    assert "8 cross-entropy iterations of 40 episodes (320;" in text and "at most 520 episodes per cell" in text
    assert "wall time on 1 worker(s)" in text, "importance runs in this process unless --workers is given"
    assert main(["estimate", jitter, "--method", "mc", "--budget", "300", "--workers", "2", "--dry-run"]) == 0
    text = capsys.readouterr().out
    assert "at most 300 episodes per cell, 300 in all" in text and "wall time on 2 worker(s)" in text
    assert main(["estimate", jitter, "--method", "splitting", "--particles", "10", "--replicates", "4",
                     "--dry-run"]) == 0
    text = capsys.readouterr().out
    # 10 particles x 4 runs, then about 10 ln(100) = 47 and 10 ln(1e5) = 116 iterations per run
    assert "40 whole episodes per cell" in text
    assert "about 47 iterations per run, at most 228 episode equivalents" in text
    assert "about 116 iterations per run, at most 504 episode equivalents" in text
    assert not (tmp_path / "e").exists(), "a dry run makes no folder"


@pytest.mark.parametrize(("options", "fragment"), [
    (["--method", "importance", "--cell", "nope"], "no cell 'nope' in"),
    (["--method", "splitting", "--target", "unsafe"], "splitting estimates --target collision or ellipse"),
    (["--method", "importance", "--samples", "1"], "need at least 2 samples"),
    (["--method", "mc", "--particles", "3"], "--particles is for --method splitting, not mc"),
])
def test_estimate_dry_run_refuses_what_the_estimate_would(capsys, options, fragment):
    assert main(["estimate", "campaigns/veh_o_arrival_jitter.toml", *options, "--dry-run"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and fragment in err[0]


def test_estimate_dry_run_does_not_apply_to_resume(tmp_path, capsys):
    assert main(["estimate", "--resume", str(tmp_path), "--dry-run"]) == 2
    assert "--dry-run checks a campaign file; it does not apply to --resume" in capsys.readouterr().err
