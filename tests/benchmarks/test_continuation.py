"""benchmarks.continuation: the rare cell's section is read from stored crude run folders and rare-event
estimate folders (subset simulation, splitting, importance sampling) of one cell at several noise scales,
checked against crude Monte Carlo where it ran and against each other."""

from __future__ import annotations

import synthetic

from benchmarks import continuation, section
from mcverify import files, store
from mcverify.campaign.spec import campaign_from_dict
from mcverify.estimate import folder

CELL = {"campaign": {"name": "cont", "seed": 5, "episodes": 200}, "model": {"barrier": {"epsilon": 0.1}}}


def _raw(scale: float, **campaign) -> dict:
    return {"campaign": {**CELL["campaign"], **campaign}, "model": {**CELL["model"], "noise": {"scale": scale}}}


def _finish(path):
    manifest = store.read_json(path / store.MANIFEST)
    manifest["finished_utc"] = "2026-01-01T11:30:00+00:00"
    files.write_json_atomic(path / store.MANIFEST, manifest)
    return path


def _crude(tmp_path, scale: float):
    run = synthetic.make_run(tmp_path / f"crude{scale}", _raw(scale),
                             probs=lambda cell: {"unsafe": 0.05 * cell.params.noise.scale, "overtook": 0.9,
                                                 "went_back": 0.05}, trajectories=False)
    return _finish(run)


def _subset(tmp_path, scale: float, estimate: float, runs=(0.9, 1.0, 1.1), target="ellipse", performance=None):
    out = tmp_path / f"subset{scale}{performance or ''}"
    camp = campaign_from_dict(_raw(scale, seed=int(100 * scale)))
    spec = {"method": "subset", "target": target, "samples": 200, "p0": 0.1, "runs": 3, "level": 0.95,
            "max_stages": 20, **({"performance": performance} if performance else {})}
    folder.create(out, camp, spec, None)
    cell = {"cell_index": 0, "cell": "all", "target": target, "estimate": estimate, "low": 0.5 * estimate,
            "high": 1.5 * estimate,
            "relative_halfwidth": 0.5, "within_run_cov": 0.4, "runs": [r * estimate for r in runs],
            "stages": [3, 3, 3], "steps": 100_000, "cpu_s": 2000.0, "crude_steps_same_width": 1e7}
    files.write_json_atomic(out / folder.ESTIMATE, {"spec": spec, "cells": [cell]})
    return _finish(out)


def _other_method(tmp_path, scale: float, method: str, estimate: float, half: float = 0.5):
    """A finished splitting or importance estimate folder: its spec as the CLI stores it, estimate.json's keys."""
    out = tmp_path / f"{method}{scale}"
    camp = campaign_from_dict(_raw(scale, seed=int(100 * scale) + 1))
    spec = ({"method": "splitting", "score": "h_ef_run", "particles": 20, "k": 1, "replicates": 10, "level": 0.95,
             "max_iterations": 2000} if method == "splitting" else
            {"method": "importance", "target": "ellipse", "samples": 800, "ce_samples": 100, "rho": 0.1,
             "alpha": 0.1, "level": 0.95, "max_ce_iterations": 0, "score": None,
             "noise_tilt": {"theta": [0, 0, 0, 0, 4.0, 0, 0, 0, 0], "split_m": 3.05, "gap_max_m": 4.1,
                            "band_steps": 1.0, "defensive": 0.3, "theta_max": 6.0}})
    folder.create(out, camp, spec, None)
    cell = {"cell_index": 0, "cell": "all", "target": "ellipse", "estimate": estimate, "low": (1 - half) * estimate,
            "high": (1 + half) * estimate, "relative_halfwidth": half, "steps": 50_000, "cpu_s": 900.0,
            "crude_steps_same_width": 2e6, **({"runs": [0.8 * estimate, 1.2 * estimate]} if method == "splitting"
                                               else {})}
    files.write_json_atomic(out / folder.ESTIMATE, {"spec": spec, "cells": [cell]})
    return _finish(out)


def test_the_section_sets_subset_beside_crude_and_says_what_crude_would_need(tmp_path, capsys):
    crude = _crude(tmp_path, 2.0)
    rate = 0.05 * 2.0
    args = ["--estimate", str(_subset(tmp_path, 2.0, rate)), str(_subset(tmp_path, 1.0, 1e-4)),
            "--crude", str(crude), "--figure", str(tmp_path / "c.png"), "--write", str(tmp_path / "B.md")]
    assert continuation.main(args) == 0
    text = (tmp_path / "B.md").read_text()
    assert "<!-- benchmarks.continuation:begin" in text and "| noise.scale | crude Monte Carlo" in text
    crude_point, _ = continuation.read_crude(crude, "noise.scale", "ellipse")
    assert f"{crude_point.k}/{crude_point.n} =" in text  # counted from episodes.parquet, not typed in
    row_2 = next(line for line in text.splitlines() if line.startswith("| 2 |"))
    row_1 = next(line for line in text.splitlines() if line.startswith("| 1 |"))
    assert "overlap" in row_2 and "no crude reference" in row_1
    assert "at 1, subset (robustness): no crude reference" in text and "100x" in text  # 1e7 crude steps against 1e5
    assert (tmp_path / "c.png").stat().st_size > 0
    capsys.readouterr()


def test_each_row_names_the_performance_function_its_runs_climbed(tmp_path, capsys):
    ladder = _subset(tmp_path, 1.0, 2e-4, performance="precursor-ladder")
    args = ["--estimate", str(_subset(tmp_path, 1.0, 1e-4)), str(ladder), "--figure", str(tmp_path / "c.png"),
            "--no-write"]
    assert continuation.main(args) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| 1 |")]
    assert len(rows) == 2 and "| subset (robustness) |" in rows[0] and "| subset (precursor-ladder) |" in rows[1]
    assert (tmp_path / "c.png").stat().st_size > 0


def test_a_disagreement_is_flagged(tmp_path, capsys):
    crude = _crude(tmp_path, 2.0)
    args = ["--estimate", str(_subset(tmp_path, 2.0, 1e-4)), "--crude", str(crude), "--no-write"]
    assert continuation.main(args) == 0
    assert "DISAGREE" in capsys.readouterr().out


def test_folders_of_another_cell_or_unfinished_are_one_line(tmp_path, capsys):
    other = synthetic.make_run(tmp_path / "other", {**_raw(2.0), "model": {"barrier": {"epsilon": 0.3},
                                                                          "noise": {"scale": 2.0}}},
                               trajectories=False)
    args = ["--estimate", str(_subset(tmp_path, 1.0, 1e-4)), "--crude", str(other), "--no-write"]
    assert continuation.main(args) == 2
    assert "is not finished" in capsys.readouterr().err
    _finish(other)
    assert continuation.main(["--estimate", str(tmp_path / "subset1.0"), "--crude", str(other), "--no-write"]) == 2
    err = capsys.readouterr().err
    assert "holds another cell" in err and "barrier" in err and err.count("\n") == 1
    assert continuation.main(["--estimate", str(tmp_path / "none"), "--no-write"]) == 2
    assert "no manifest.json" in capsys.readouterr().err


def test_crude_runs_of_one_value_are_pooled_unless_they_share_a_seed(tmp_path, capsys):
    def crude(name: str, seed: int):
        run = synthetic.make_run(tmp_path / name, _raw(2.0, seed=seed),
                                 probs=lambda cell: {"unsafe": 0.1, "overtook": 0.9, "went_back": 0.05},
                                 trajectories=False)
        return _finish(run)

    a, b = crude("a", 1), crude("b", 2)
    one, _ = continuation.read_crude(a, "noise.scale", "ellipse")
    two, _ = continuation.read_crude(b, "noise.scale", "ellipse")
    args = ["--estimate", str(_subset(tmp_path, 2.0, 0.1)), "--crude", str(a), str(b), "--no-write"]
    assert continuation.main(args) == 0
    out = capsys.readouterr().out
    assert f"{one.k + two.k}/{one.n + two.n} =" in out and "(2 runs pooled)" in out and "seeds 1, 2" in out
    args[args.index(str(b))] = str(crude("c", 1))
    assert continuation.main(args) == 2
    err = capsys.readouterr().err
    assert "ran the same seed (1)" in err and err.count("\n") == 1


def _bound(tmp_path, scale: float, lower: float, target="ellipse"):
    out = tmp_path / f"strata{scale}"
    out.mkdir(parents=True)
    params = store.read_manifest(_crude(tmp_path, scale))["cells"][0]["params"]  # the same cell, as recorded
    files.write_json_atomic(out / "bound.json", {"target": target, "level": 0.95, "lower": lower, "point": 4 * lower,
                                                 "episodes": 600, "events": 7, "seed": 0, "strata": "s.toml",
                                                 "settings": [], "params": params})
    return out


def test_the_stratified_bound_is_a_column_a_line_and_a_marker(tmp_path, capsys):
    args = ["--estimate", str(_subset(tmp_path, 2.0, 0.1)), "--stratified", str(_bound(tmp_path, 2.0, 5.3e-5)),
            str(_bound(tmp_path, 1.0, 6e-7)), "--figure", str(tmp_path / "c.png"), "--no-write"]
    assert continuation.main(args) == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith("| 2 |"))
    assert ">= 5.3e-05 (7 events in 600)" in row
    assert "at 1: stratified lower bound >= 6e-07 (7 events in 600 episodes; the strata's point 2.4e-06)" in out
    assert (tmp_path / "c.png").stat().st_size > 0
    args[args.index("--stratified") + 1] = str(_bound(tmp_path / "other", 2.0, 1e-5, target="collision"))
    assert continuation.main(args) == 2
    assert "bounds collision, not the estimates' ellipse" in capsys.readouterr().err


def test_splitting_and_importance_sit_beside_subset_and_a_disagreement_between_methods_is_reported(tmp_path, capsys):
    crude = _crude(tmp_path, 2.0)
    rate = 0.05 * 2.0
    args = ["--estimate", str(_subset(tmp_path, 2.0, rate)), str(_other_method(tmp_path, 2.0, "splitting", rate)),
            str(_other_method(tmp_path, 2.0, "importance", 0.3 * rate, half=0.2)), "--crude", str(crude),
            "--figure", str(tmp_path / "c.png"), "--no-write"]
    assert continuation.main(args) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("| 2 |")]
    assert len(rows) == 3
    assert "| subset (robustness) |" in rows[0]
    assert "| splitting (score h_ef_run) |" in rows[1] and "| 40x |" in rows[1]  # 2e6 crude steps against 5e4
    assert "| importance (noise tilt y_jump 4) |" in rows[2] and "| – | – |" in rows[2]  # no runs, no stages
    # the importance estimate (0.03 [0.024, 0.036]) misses both others' intervals: said, not averaged
    disagree = [line for line in out.splitlines() if line.startswith("- Methods disagree")]
    assert len(disagree) == 2 and all("importance (noise tilt y_jump 4) 0.03 [0.024, 0.036]" in d for d in disagree)
    assert "Splitting: `mcverify estimate --method splitting`" in out and "Importance sampling:" in out
    assert (tmp_path / "c.png").stat().st_size > 0


def test_a_folder_of_crude_monte_carlo_given_as_an_estimate_is_one_line(tmp_path, capsys):
    run = synthetic.make_run(tmp_path / "mc", _raw(2.0), trajectories=False)
    assert continuation.main(["--estimate", str(_finish(run)), "--no-write"]) == 2
    err = capsys.readouterr().err
    assert "is not a rare-event estimate" in err and err.count("\n") == 1


def test_a_second_section_keeps_the_first_and_a_foreign_name_is_one_line(tmp_path, capsys):
    page = tmp_path / "B.md"
    page.write_text("# Benchmarks\n\n" + section.wrap("continuation", "the continuation's own table"))
    args = ["--estimate", str(_other_method(tmp_path, 1.1, "splitting", 1e-3)), "--section", "continuation_methods",
            "--write", str(page)]
    assert continuation.main(args) == 0
    assert continuation.main(args) == 0  # rewritten in place, not appended
    text = page.read_text()
    begin, end = section.markers("continuation", "continuation_methods")
    assert text.count(begin) == 1 and text.count(end) == 1 and "the continuation's own table" in text
    assert "generated by python -m benchmarks.continuation --section continuation_methods" in begin
    capsys.readouterr()
    args[args.index("continuation_methods")] = "rare"
    assert continuation.main(args) == 2
    err = capsys.readouterr().err
    assert "that is the section of python -m benchmarks.rare" in err and err.count("\n") == 1


def test_an_extinct_splitting_estimate_shows_no_width_and_its_warning(tmp_path, capsys):
    out = _other_method(tmp_path, 1.1, "splitting", 0.0)
    stored = store.read_json(out / folder.ESTIMATE)
    warning = "10 of 10 runs estimate 0 (extinct: every particle killed at one level)"
    stored["cells"][0].update(relative_halfwidth=None, crude_steps_same_width=None, runs=[0.0] * 10, low=0.0,
                              high=0.0, warnings=[warning])
    files.write_json_atomic(out / folder.ESTIMATE, stored)  # as the estimator writes it: no width, a warning
    args = ["--estimate", str(out), "--stratified", str(_bound(tmp_path, 1.1, 5.3e-5)), "--figure",
            str(tmp_path / "c.png"), "--no-write"]  # the figure draws the 0 at the axis' floor
    assert continuation.main(args) == 0
    text = capsys.readouterr().out
    row = next(line for line in text.splitlines() if line.startswith("| 1.1 |"))
    assert "| 0 [0, 0] | splitting (score h_ef_run) |" in row and row.count("| – |") >= 3
    assert f"- at 1.1, splitting (score h_ef_run) warns: {warning}" in text
    assert "has no width to compare" in text
    assert "- Not credible at 1.1, splitting (score h_ef_run): its interval [0, 0] lies below the stratified lower " \
           "bound 5.3e-05, so it reads low." in text
    assert (tmp_path / "c.png").stat().st_size > 0
