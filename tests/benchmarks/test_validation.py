"""``python -m benchmarks.validation``: the reference is the gap-free prefix of a crude estimate folder, the
splitting and subset simulation runs are pooled into repetitions that equal the estimator's own interval, and
folders that do not belong together are refused with one line."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from benchmarks import section, validation, validation_reference, validation_report
from mcverify import files, store
from mcverify.errors import RunError
from mcverify.estimate import splitting, subset_run
from mcverify.estimate.folder import ESTIMATE

CAMPAIGN = "toy"


def _manifest(out: Path, method: str | None, seed: int, target: str = "ellipse", params: dict | None = None) -> None:
    """A manifest of one cell; ``method`` None writes a run folder's (no estimate spec)."""
    out.mkdir(parents=True)
    cell = {"index": 0, "name": "all", "params": params or {"barrier": {"epsilon": 0.1}, "noise": {"scale": 2.0}}}
    manifest = {"campaign": {"name": CAMPAIGN, "seed": seed}, "cells": [cell]}
    if method is not None:
        manifest["estimate"] = {"method": method, "target": target}
    files.write_json_atomic(out / store.MANIFEST, manifest)


def _reference(out: Path, events: list[list[bool]], method: str | None = "mc", seed: int = 1,
               params: dict | None = None) -> None:
    """A crude estimate folder (or, with ``method`` None, a run folder) whose chunk i holds 4 episodes
    with the given ellipse violations; a None chunk is left missing (a gap in the pre-assigned order)."""
    _manifest(out, method, seed=seed, params=params)
    for i, chunk_events in enumerate(events):
        if chunk_events is None:
            continue
        chunk = store.Chunk(0, tuple(range(4 * i, 4 * i + 4)))
        rows = [{"cell_index": 0, "cell_episode": e, "outcome": "overtake", "ellipse_violation": v, "steps": 80}
                for e, v in zip(chunk.episode_ids, chunk_events, strict=True)]
        store.append_record(out, store.write_chunk(out, chunk, rows))


def _splitting(out: Path, seed: int, runs: list[float], target: str = "ellipse", score: str = "h_ef",
              params: dict | None = None) -> None:
    # as the estimator writes it: the target is per cell
    _manifest(out, "splitting", seed=seed, target=None, params=params)
    files.write_json_atomic(out / ESTIMATE, {"spec": {"particles": 4, "score": score}, "cells": [
        {"cell": "all", "target": target, "runs": runs, "steps": 100 * len(runs), "cpu_s": 5.0 * len(runs)}]})


def test_reference_is_the_gap_free_prefix(tmp_path):
    _reference(tmp_path / "ref", [[True, False, False, False], [False, False, True, False], None,
                                  [True, True, True, True]])
    ref = validation_reference.reference(tmp_path / "ref")
    # the fourth chunk lies after the gap: not part of the pre-assigned prefix
    assert (ref.n, ref.k, ref.p) == (8, 2, 0.25)
    assert ref.low < 0.25 < ref.high and ref.mean_episode_steps == 80


def test_a_run_folder_is_a_reference_for_the_target_named(tmp_path):
    _reference(tmp_path / "run", [[True, False, False, False], [False, False, True, False]], method=None)
    ref = validation_reference.reference(tmp_path / "run", target="ellipse")
    assert (ref.target, ref.n, ref.k) == ("ellipse", 8, 2)
    assert validation_reference.reference(tmp_path / "run", target="collision").k == 0  # no collision flag here
    with pytest.raises(RunError, match="give --target"):
        validation_reference.reference(tmp_path / "run")


def test_reference_folders_of_one_cell_with_distinct_seeds_pool(tmp_path):
    _reference(tmp_path / "a", [[True, False, False, False], None, [True, True, True, True]], method=None)
    _reference(tmp_path / "b", [[False, False, True, False], [False] * 4], method=None, seed=2)
    ref = validation_reference.reference([tmp_path / "a", tmp_path / "b"], target="ellipse")
    assert (ref.n, ref.k, ref.seeds) == (12, 2, (1, 2))  # a's prefix (4 episodes), then b's 8
    seq = validation_reference.reference_sequence([tmp_path / "a", tmp_path / "b"], "ellipse")
    assert seq.events.tolist() == [True, False, False, False] + [False, False, True, False] + [False] * 4
    _reference(tmp_path / "same", [[False] * 4], method=None)
    with pytest.raises(RunError, match="same seed"):
        validation_reference.reference([tmp_path / "a", tmp_path / "same"], target="ellipse")
    _reference(tmp_path / "other", [[False] * 4], method=None, seed=3, params={"noise": {"scale": 1.0}})
    with pytest.raises(RunError, match="another cell"):
        validation_reference.reference([tmp_path / "a", tmp_path / "other"], target="ellipse")
    _splitting(tmp_path / "s", 2, [0.1, 0.2])  # an estimator with one of the pooled folders' seeds
    with pytest.raises(RunError, match="reference's seed 2"):
        validation.pooled_repetitions([tmp_path / "s"], ref, group=2)


def test_an_estimate_reference_counts_its_own_target(tmp_path):
    _reference(tmp_path / "ref", [[True, False, False, False]])
    assert validation_reference.reference(tmp_path / "ref", target="ellipse").k == 1
    with pytest.raises(RunError, match="asks for another event"):
        validation_reference.reference(tmp_path / "ref", target="collision")


def test_pooled_runs_give_the_estimators_own_intervals(tmp_path):
    _reference(tmp_path / "ref", [[True, False, False, False]] * 5)
    _splitting(tmp_path / "s1", 11, [0.1, 0.3, 0.2])
    _splitting(tmp_path / "s2", 12, [0.25, 0.0, 0.4, 0.9])
    ref = validation_reference.reference(tmp_path / "ref")
    reps = validation.pooled_repetitions([tmp_path / "s1", tmp_path / "s2"], ref, group=2)
    pooled = [0.1, 0.3, 0.2, 0.25, 0.0, 0.4, 0.9]
    assert len(reps) == 3  # the seventh run is a short remainder, dropped
    for rep, start in zip(reps, (0, 2, 4), strict=True):
        runs = [splitting.AMSRun(v, 1, [], 4, 1, 10, False, 1) for v in pooled[start:start + 2]]
        own = splitting.from_runs(runs, 0.95)
        assert (rep.estimate, rep.high) == pytest.approx((own.estimate, own.high))
        assert rep.low == pytest.approx(own.low) and rep.steps == 200
    summary = validation.summarise(reps, ref)
    covered = sum(r.low <= 0.25 <= r.high for r in reps)
    assert summary["covered"] == covered and summary["repetitions"] == 3
    assert summary["bias"] == pytest.approx((0.2 + 0.225 + 0.2) / 3 / 0.25 - 1)
    # the runs one by one: all seven count, the remainder included
    pooled = validation.pooled_summary([tmp_path / "s1", tmp_path / "s2"], ref)
    assert (pooled["runs"], pooled["zero_runs"], pooled["particles"]) == (7, 1, 4)
    assert pooled["mean"] == pytest.approx(sum(pooled_values := [0.1, 0.3, 0.2, 0.25, 0.0, 0.4, 0.9]) / 7)
    assert pooled["standard_error"] == pytest.approx(float(np.std(pooled_values, ddof=1)) / 7**0.5)
    # crude: (1 - p) / p x 80 steps per episode; a run: (sd / p)^2 x 100 steps
    crude, run = 0.75 / 0.25 * 80, (float(np.std(pooled_values, ddof=1)) / 0.25) ** 2 * 100
    assert pooled["steps_ratio_vs_crude"] == pytest.approx(crude / run)


def test_folders_that_do_not_belong_together_are_refused(tmp_path):
    _reference(tmp_path / "ref", [[True, False, False, False]])
    _splitting(tmp_path / "a", 5, [0.1, 0.2])
    _splitting(tmp_path / "b", 5, [0.1, 0.2])
    _splitting(tmp_path / "c", 6, [0.1, 0.2], target="collision")
    ref = validation_reference.reference(tmp_path / "ref")
    with pytest.raises(RunError, match="same seed 5"):
        validation.pooled_repetitions([tmp_path / "a", tmp_path / "b"], ref, group=2)
    with pytest.raises(RunError, match="estimates 'collision'"):
        validation.pooled_repetitions([tmp_path / "c"], ref, group=2)
    with pytest.raises(RunError, match="is a splitting estimate; the reference must be crude Monte Carlo"):
        validation_reference.reference(tmp_path / "a")
    with pytest.raises(RunError, match="subset simulation's; splitting runs have no within-run error"):
        validation.pooled_repetitions([tmp_path / "a"], ref, group=1)
    _splitting(tmp_path / "d", 7, [0.1, 0.2], score="h_ef_held")
    with pytest.raises(RunError, match="differ in"):
        validation.pooled_repetitions([tmp_path / "a", tmp_path / "d"], ref, group=2)
    with pytest.raises(RunError, match="more than the 2 runs"):
        validation.pooled_repetitions([tmp_path / "a"], ref, group=3)
    # the reference's own seed: the estimator's episodes would replay the reference's
    _splitting(tmp_path / "e", 1, [0.1, 0.2])
    with pytest.raises(RunError, match="reference's seed 1"):
        validation.pooled_repetitions([tmp_path / "e"], ref, group=2)
    # another model (a --set change): refused; a field the reference lacks (added later) is not compared
    _splitting(tmp_path / "f", 8, [0.1, 0.2], params={"barrier": {"epsilon": 0.3}, "noise": {"scale": 2.0}})
    with pytest.raises(RunError, match=r"another model than the reference: barrier.epsilon = 0.3 \(reference 0.1\)"):
        validation.pooled_repetitions([tmp_path / "f"], ref, group=2)
    _splitting(tmp_path / "g", 9, [0.1, 0.2], params={"barrier": {"epsilon": 0.1}, "noise": {"scale": 2.0},
                                                      "mpc": {"ipm_central_attempt": "off"}})
    assert len(validation.pooled_repetitions([tmp_path / "g"], ref, group=2)) == 1


def test_cli_writes_the_section_and_refuses_bad_input_in_one_line(tmp_path, capsys):
    _reference(tmp_path / "ref", [[True, False, False, False]] * 3)
    _splitting(tmp_path / "s1", 11, [0.1, 0.3, 0.2, 0.25])
    bench = tmp_path / "BENCH.md"
    bench.write_text("# Benchmarks\n\nhand-written\n")
    assert validation.main([str(tmp_path / "ref"), "--splitting", str(tmp_path / "s1"), "--group", "2", "4",
                 "--write", str(bench), "--figure", str(tmp_path / "fig.png")]) == 0
    assert (tmp_path / "fig.png").stat().st_size > 0
    text = bench.read_text()
    assert "hand-written" in text and section.markers("validation")[0] in text
    assert "| splitting (h_ef), 2 runs of 4 particles | 2 |" in text
    assert "| splitting (h_ef), 4 runs of 4 particles | 1 |" in text
    assert "(h_ef), the 4 AMS runs of 4 particles one by one" in text
    assert validation.main([str(tmp_path / "ref"), "--splitting", str(tmp_path / "s1"), "--write", str(bench),
                            "--section", "validation_other"]) == 0
    again = bench.read_text()
    assert again.startswith(text.rstrip("\n")) and section.markers("validation", "validation_other")[0] in again
    capsys.readouterr()
    assert validation.main([str(tmp_path / "nowhere"), "--splitting", str(tmp_path / "s1")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nowhere" in err[0]


def test_sequential_runs_are_consecutive_disjoint_and_checked_against_the_rest():
    rng = np.random.default_rng(5)
    events = rng.random(3000) < 0.05
    steps = np.full(events.size, 80.0)
    reps = validation.sequential_repetitions(events, steps, 0.08)
    assert len(reps) > 10
    start = 0
    for r in reps:
        n = int(round(r.steps / 80))
        block = events[start:start + n]
        # the run is exactly `mcverify estimate --until-halfwidth 0.08` on its own episodes
        res = validation.sequential_estimate(block, validation.StopRule(0.08))
        assert res.status == "halfwidth" and res.n == n and (res.low, res.high) == (r.low, r.high)
        assert r.reference_p == pytest.approx((events.sum() - block.sum()) / (events.size - n))
        start += n
    assert start <= events.size  # the unfinished last run is dropped


def test_sequential_runs_cut_from_one_stream_keep_their_coverage():
    """On i.i.d. episodes at p = 0.05, runs stopped at a relative half-width of 50 % (each with its
    leave-out reference, as on the closed loop) cover in at least 95 % of 200+ runs."""
    rng = np.random.default_rng(0)
    events = rng.random(200_000) < 0.05
    reps = validation.sequential_repetitions(events, np.ones(events.size), 0.5, relative=True)
    assert len(reps) >= 200
    assert np.mean([r.low <= r.reference_p <= r.high for r in reps]) >= 0.95
    assert np.mean([r.low <= 0.05 <= r.high for r in reps]) >= 0.95


def test_cli_sequential_rows_use_the_reference_episodes(tmp_path, capsys):
    _reference(tmp_path / "ref", [[False] * 4] * 40 + [[True, False, False, False]] * 10)
    assert validation.main([str(tmp_path / "ref"), "--sequential", "0.2", "--no-write",
                 "--json", str(tmp_path / "v.json")]) == 0
    res = store.read_json(tmp_path / "v.json")
    (row,) = res["estimators"]
    assert row["leave_out_reference"] and row["repetitions"] >= 1 and row["method"] == "mc"
    assert "| mc, stopped at half-width 0.2 |" in capsys.readouterr().out
    assert validation.main([str(tmp_path / "ref"), "--sequential", "0.0001", "--no-write"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "too few" in err[0]


def _importance(out: Path, seed: int, estimate: float, low: float, high: float, anytime_lower: float,
                failures: int, ess: float) -> None:
    _manifest(out, "importance", seed=seed)
    files.write_json_atomic(out / ESTIMATE, {"spec": {"method": "importance"}, "cells": [
        {"cell": "all", "target": "ellipse", "estimate": estimate, "low": low, "high": high, "steps": 300,
         "cpu_s": 7.0, "anytime_lower": anytime_lower, "failures": failures, "ess": ess,
         "warnings": ["few failing samples"] if failures < 10 else []}]})


def test_importance_repetitions_and_their_diagnostics(tmp_path, capsys):
    _reference(tmp_path / "ref", [[True, False, False, False]] * 5)  # p = 0.25
    folders = [tmp_path / f"is{i}" for i in range(3)]
    _importance(folders[0], 11, 0.24, 0.15, 0.33, 0.10, 12, 10.5)
    _importance(folders[1], 12, 0.10, 0.05, 0.15, 0.02, 4, 3.0)  # misses p, low; its lower bound holds
    _importance(folders[2], 13, 0.40, 0.30, 0.50, 0.27, 20, 17.0)  # misses p, high; so does its lower bound
    ref = validation_reference.reference(tmp_path / "ref")
    reps = validation.importance_repetitions(folders, ref)
    summary = validation.summarise(reps, ref)
    assert (summary["covered"], summary["with_warnings"]) == (1, 1)
    imp = validation.importance_summary(reps, ref)
    assert imp["failures_median_min_max"] == [12, 4, 20] and imp["ess_median_min_max"] == [10.5, 3.0, 17.0]
    assert (imp["with_anytime_lower"], imp["anytime_lower_held"], imp["anytime_lower_median"]) == (3, 2, 0.10)
    bench = tmp_path / "BENCH.md"
    assert validation.main([str(tmp_path / "ref"), "--importance", *map(str, folders),
                 "--write", str(bench)]) == 0
    text = bench.read_text()
    assert "| importance | 3 | 1/3 = 33% " in text
    assert ("- importance, the 3 estimates: failing samples per estimate median 12 (4-20), their effective sample "
            "size median 10.5 (3.0-17.0); the one-sided anytime-valid lower bound is at or below p in 2 of 3 "
            "(median 0.1000)") in text


def _subset(out: Path, seed: int, runs: list[float], performance: str = "margin-ladder", samples: int = 200,
            covs: list[float | None] | None = None) -> None:
    # as subset simulation writes it: the target is in the spec and in the cell, each run's record in runs/
    _manifest(out, "subset", seed=seed)
    spec = {"method": "subset", "samples": samples, "performance": performance}
    files.write_json_atomic(out / ESTIMATE, {"spec": spec, "cells": [
        {"cell": "all", "target": "ellipse", "runs": runs, "steps": 1000 * len(runs), "cpu_s": 60.0 * len(runs)}]})
    for run_id, cov in enumerate(covs or [0.5] * len(runs)):
        path = subset_run.run_stem(out, 0, run_id).with_suffix(".json")
        path.parent.mkdir(exist_ok=True)
        files.write_json_atomic(path, {"run": {"estimate": runs[run_id], "cov": cov, "stages": [], "evaluations": 0,
                                               "steps": 0, "capped": False}})


def test_subset_runs_are_pooled_into_the_estimators_own_t_intervals_and_reported(tmp_path, capsys):
    _reference(tmp_path / "ref", [[True, False, False, False]] * 5)
    _subset(tmp_path / "u1", 21, [0.2, 0.3, 0.25])
    _subset(tmp_path / "u2", 22, [0.22, 0.35, 0.18])
    ref = validation_reference.reference(tmp_path / "ref")
    reps = validation.pooled_repetitions([tmp_path / "u1", tmp_path / "u2"], ref, group=3, method="subset")
    assert len(reps) == 2 and all(r.steps == 3000 for r in reps)
    first = np.array([0.2, 0.3, 0.25])
    half = 4.302652729911275 * first.std(ddof=1) / 3**0.5  # t(0.975, 2): what --replicates 3 reports
    assert (reps[0].estimate, reps[0].low, reps[0].high) == pytest.approx((0.25, 0.25 - half, 0.25 + half))
    _subset(tmp_path / "u3", 23, [0.2, 0.3], performance="robustness")
    with pytest.raises(RunError, match=r"differ in \(samples, performance\)"):
        validation.pooled_repetitions([tmp_path / "u1", tmp_path / "u3"], ref, group=2, method="subset")
    args = [str(tmp_path / "ref"), "--subset", str(tmp_path / "u1"), str(tmp_path / "u2"), "--group", "3",
            "--no-write"]
    assert validation.main(args) == 0
    out = capsys.readouterr().out
    assert "| subset (margin-ladder), 3 runs of 200 per stage | 2 |" in out
    assert "- subset (margin-ladder), the 6 runs of 200 per stage one by one" in out


def test_group_1_checks_each_subset_run_with_its_within_run_interval(tmp_path, capsys):
    _reference(tmp_path / "ref", [[True, False, False, False]] * 5)  # p = 0.25
    _subset(tmp_path / "u1", 21, [0.2, 0.5], covs=[0.2, 0.1])
    _subset(tmp_path / "u2", 22, [0.3, 0.1], covs=[None, 1.0])
    ref = validation_reference.reference(tmp_path / "ref")
    reps = validation.pooled_repetitions([tmp_path / "u1", tmp_path / "u2"], ref, group=1, method="subset")
    z = 1.959963984540054
    assert [(r.estimate, r.steps) for r in reps] == [(0.2, 1000), (0.5, 1000), (0.3, 1000), (0.1, 1000)]
    assert (reps[0].low, reps[0].high) == pytest.approx((0.2 * (1 - 0.2 * z), 0.2 * (1 + 0.2 * z)))
    assert (reps[1].low, reps[1].high) == pytest.approx((0.5 * (1 - 0.1 * z), 0.5 * (1 + 0.1 * z)))
    assert (reps[2].low, reps[2].high) == (0.0, math.inf)  # a run without a CoV: no bound
    assert (reps[3].low, reps[3].high) == pytest.approx((0.0, 0.1 * (1 + z)))  # the low end clipped at 0
    args = [str(tmp_path / "ref"), "--subset", str(tmp_path / "u1"), str(tmp_path / "u2"), "--group", "1", "2",
            "--no-write"]
    assert validation.main(args) == 0
    out = capsys.readouterr().out
    assert "| subset (margin-ladder), 1 run of 200 per stage, within-run interval | 4 | 3/4 = 75% " in out
    assert "| subset (margin-ladder), 2 runs of 200 per stage | 2 |" in out


def test_the_figure_turns_to_a_log_axis_where_the_estimates_span_more_than_two_decades():
    row = {"intervals": [[1e-3, 0.0, 3e-3], [2e-3, 1e-3, 4e-3]]}
    assert validation_report._log_floor([row]) is None  # within two decades: linear
    row["intervals"].append([1e-8, 0.0, 5e-8])
    assert validation_report._log_floor([row]) == pytest.approx(1e-8 / 3)
