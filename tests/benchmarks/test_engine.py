"""The engine benchmark's bookkeeping (the benchmark itself is a command, ``python -m benchmarks.engine``,
not a timed test)."""

from __future__ import annotations

import math
from collections import Counter

import pytest

from benchmarks import engine as bench
from benchmarks import engine_report, section, sides
from benchmarks.agreement import agreement
from benchmarks.ratios import ratio_of_sums_interval
from benchmarks.solve_classes import SolveClass


def row(e, safe=True, outcome="overtook", d=0.8, g=40.0, t=6.5, solves=100):
    return {"cell_episode": e, "episode_id": e, "safe": safe, "outcome": outcome, "min_dist_front_m": d,
            "min_gap_opp_m": g, "overtake_time_s": t, "solves": solves}


def test_agreement_pairs_by_episode_and_lists_disagreements():
    naive = [row(0), row(1, safe=False, outcome="timeout"), row(2, t=math.nan)]
    engine = [row(2, t=7.0), row(1), row(0, d=0.75), row(3)]
    ag = agreement(naive, engine, key="cell_episode", values=sides.PAIRED_VALUES)
    assert ag["paired"] == 3 and ag["safe_agree"] == 2 and [d["cell_episode"] for d in ag["disagreements"]] == [1]
    assert ag["outcome_agree"] == 2
    assert ag["min_dist_front_m_absdiff_max"] == 0.050000000000000044
    assert ag["overtake_time_s_absdiff_max"] == 0.0  # the NaN pair is skipped
    assert "new_statuses" not in ag


def test_agreement_of_solver_runs_counts_statuses_and_intervals():
    def solver_row(e, safe=True, statuses='{"Solve_Succeeded": 3}'):
        return {"episode_id": e, "cell": "c", "safe": safe, "outcome": "overtook", "min_dist_front_m": 0.8,
                "overtake_time_s": 6.5, "solver_statuses": statuses}

    ref = [solver_row(0), solver_row(1)]
    new = [solver_row(1, safe=False, statuses='{"ipm": 2, "fallback": 1}'), solver_row(0, statuses='{"ipm": 3}')]
    ag = agreement(ref, new, status_column="solver_statuses")
    assert ag["paired"] == 2 and ag["safe_agree"] == 1 and ag["outcome_agree"] == 2
    assert ag["safe_agree_ci"][0] < 0.5 < ag["safe_agree_ci"][1] and ag["outcome_agree_ci"][1] == 1.0
    assert ag["new_statuses"] == {"ipm": 5, "fallback": 1}
    assert ag["disagreements"] == [{"episode_id": 1, "cell": "c", "safe_ref": True, "outcome_ref": "overtook",
                                    "min_dist_front_m_ref": 0.8, "overtake_time_s_ref": 6.5, "safe_new": False,
                                    "outcome_new": "overtook", "min_dist_front_m_new": 0.8,
                                    "overtake_time_s_new": 6.5}]
    assert agreement([], new)["safe_agree_ci"] is None


def _side(name, n, cpu):
    side = sides.SideResult(name, [], 0.0, 0.0)
    side.add("c", [row(i) for i in range(n)], cpu, cpu, Counter({SolveClass.CONVERGED: cpu / 2}))
    side.classes.add(SolveClass.CONVERGED, cpu / 2)
    return side


def test_the_section_replaces_the_last_run_and_keeps_the_rest_of_the_page(tmp_path):
    path = tmp_path / "BENCHMARKS.md"
    path.write_text("# Benchmarks\n\n## Other section\n\ntext\n")
    by_side = {"engine": _side("engine", 4, 60.0), "baseline": _side("baseline", 4, 120.0)}
    result = {"sides": by_side, "ratios": {"baseline": 2.0}, "peak_rss_mb": 500.0, "machine": "m", "cells": ["c"],
              "backend": "ipm", "load_average": [1.0, 1.0, 1.0], "setup_cpu_s": 1.0,
              "agreement": {"baseline": agreement([row(0)], [row(0)], key="episode_id", values=sides.PAIRED_VALUES)},
              "command": "python -m benchmarks.engine", "campaign": "x"}
    section.write("engine", engine_report.markdown(result), path)
    path.write_text(path.read_text() + "\n## Later\n")
    section.write("engine", engine_report.markdown(result), path)
    text = path.read_text()
    begin, end = section.markers("engine")
    assert text.count(begin) == 1 and text.count(end) == 1, "the section is replaced, not appended"
    assert text.index("## Other section") < text.index(begin) < text.index(end) < text.index("## Later")
    assert "Command: `python -m benchmarks.engine`; commit `" in text and "; machine: " in text
    assert "**2.00x**" in text and "| converged | 7.50 (0.2, 30000.0) | 15.00 (0.2, 60000.0) |" in text
    assert "| whole episode | 15.00 | 30.00 |" in text and "| c | 15.00 | 30.00 |" in text
    # where each cell's solver time goes, by class in SolveClass order
    assert ("| cell | engine: converged / rescued / certified infeasible / presumed infeasible / other failure |"
            in text) and "| c | 7.50 / 0.00 / 0.00 / 0.00 / 0.00 | 15.00 / 0.00 / 0.00 / 0.00 / 0.00 |" in text
    assert by_side["engine"].episodes_per_cpu_min == 4.0 and by_side["engine"].cpu_ms_per_solve == 150.0
    assert "engine / compiled IPOPT loop: 2.00x" in engine_report.render(result)


@pytest.mark.slow  # three full closed-loop episodes on three solver loops: about 3 minutes
def test_solve_classes_account_for_every_solve_of_every_side():
    """On a short two-cell campaign: each side's class counts add up to the solves its rows report,
    and the paired sides agree on the verdicts (the same problems, solved by IPOPT or the fast path)."""
    from mcverify.campaign.spec import campaign_from_dict

    raw = {"campaign": {"name": "mix", "seed": 3, "episodes": 2, "common_random_numbers": True},
           "model": {"sim": {"max_time_s": 0.1}, "noise": {"kind": "paper"}, "opposing": {"kind": "human"}},
           "axes": {"method": {"VL-CBF": {"barrier.epsilon": 0.3}, "MPC-DC": {"mpc.controller": "mpcdc"}}}}
    import benchmarks.engine as eng

    camp = campaign_from_dict(raw)
    orig = eng.load_campaign
    eng.load_campaign = lambda path, **_: camp
    try:
        result = eng.run(campaign="mix", engine_episodes=2, baseline_episodes=1, progress=lambda m: None)
    finally:
        eng.load_campaign = orig
    assert result["cells"] == [c.name for c in camp.cells] and set(result["sides"]) == {"engine", "baseline"}
    for name, side in result["sides"].items():
        assert sum(side.classes.count.values()) == side.solves > 0, name
        assert side.classes.total_cpu_s <= side.cpu_s
        assert sum(n for n, _ in side.per_cell.values()) == len(side.rows)
        per_cell = sum(sum(c.values()) for c in side.per_cell_classes.values())
        assert per_cell == pytest.approx(side.classes.total_cpu_s), name  # the cells' split adds up
    assert len(result["sides"]["engine"].rows) == 4 and len(result["sides"]["baseline"].rows) == 2
    converged = sum(a["attempts"] for k, a in result["ipm_attempts"].items() if k.endswith(":Converged"))
    assert converged >= result["sides"]["engine"].classes.count[SolveClass.CONVERGED] > 0  # warm-up not counted
    assert all(a["cpu_s"] >= 0 for a in result["ipm_attempts"].values())
    ag = result["agreement"]["baseline"]
    assert ag["paired"] == 2 and ag["safe_agree"] == 2 and set(result["ratios"]) == {"baseline"}
    assert result["ratio_intervals"] == {"baseline": None}  # the loop ran 1 of the engine's 2 episodes per cell


def _cell_side(name, cpu_by_cell, clocks_by_cell):
    """A side whose cells' episodes have the given solver clocks (one solve each) and measured CPU."""
    side = sides.SideResult(name, [], 0.0, 0.0)
    for k, (cell, clocks) in enumerate(clocks_by_cell.items()):
        rows = [{"cell": cell, "episode_id": 10 * k + e, "cell_episode": e, "solves": 1, "solve_time_mean_s": c}
                for e, c in enumerate(clocks)]
        side.add(cell, rows, cpu_by_cell[cell], cpu_by_cell[cell])
    return side


def test_episode_cpu_is_the_cells_cpu_split_by_the_solver_clock():
    side = _cell_side("engine", {"a": 10.0, "b": 3.0}, {"a": [1.0, 3.0], "b": [0.0, 0.0, 0.0]})
    assert sides.episode_cpu_s(side) == {0: 2.5, 1: 7.5, 10: 1.0, 11: 1.0, 12: 1.0}  # b: no solver clock, equal


def test_ratio_interval_needs_the_same_episodes_and_holds_the_measured_ratio():
    engine = _cell_side("engine", {"a": 4.0, "b": 8.0}, {"a": [1.0, 2.0, 1.5], "b": [2.0, 5.0, 3.0]})
    loop = _cell_side("baseline", {"a": 20.0, "b": 40.0}, {"a": [4.0, 9.0, 8.0], "b": [11.0, 20.0, 14.0]})
    measured = engine.episodes_per_cpu_min / loop.episodes_per_cpu_min
    assert measured == pytest.approx(5.0)
    # independent episodes: the cells are strata (df 4); common random numbers: episode k of the mix is
    # the unit (3 units, df 2), so the interval is wider here
    strata, blocks = sides.ratio_interval(engine, loop, False), sides.ratio_interval(engine, loop, True)
    for ci in (strata, blocks):
        assert ci.low < measured < ci.high and ci.level == 0.95
    assert blocks.high - blocks.low > strata.high - strata.low
    cpu_e, cpu_l = sides.episode_cpu_s(engine), sides.episode_cpu_s(loop)
    by_k = [(sum(cpu_l[i] for i in (k, 10 + k)), sum(cpu_e[i] for i in (k, 10 + k))) for k in range(3)]
    assert blocks == ratio_of_sums_interval([n for n, _ in by_k], [d for _, d in by_k])
    fewer = _cell_side("baseline", {"a": 20.0, "b": 40.0}, {"a": [4.0, 9.0], "b": [11.0, 20.0]})
    assert sides.ratio_interval(engine, fewer, True) is None
    result = {"ratios": {"baseline": measured}, "ratio_intervals": {"baseline": blocks}}
    assert engine_report.ratio_text(result, "baseline", bold=True).startswith(
        "engine / compiled IPOPT loop: **5.00x** episodes per CPU-minute "
        f"(95 % interval {blocks.low:.2f}-{blocks.high:.2f} ")
    result["ratio_intervals"] = {"baseline": None}
    assert "(no interval: the sides ran different episodes)" in engine_report.ratio_text(result, "baseline")


def test_attempt_lines_count_the_cpu_of_attempts_that_did_not_converge():
    lines = engine_report.attempt_lines({"warm1:Converged": {"attempts": 3, "cpu_s": 1.0},
                                         "warm1:Line_Search_Failed": {"attempts": 1, "cpu_s": 0.5}})
    assert lines == ["IPM attempts (engine, all episodes): warm1:Converged 3 (1.0 s), warm1:Line_Search_Failed 1 "
                     "(0.5 s); 0.5 of 1.5 CPU-s in attempts that did not converge"]
    assert engine_report.attempt_lines({}) == []


def test_naive_planner_wraps_its_solvers():
    from benchmarks.naive import NaiveOptiSolver, naive_planner
    from benchmarks.solve_classes import ClassTally, TimedSolver
    from mcverify.model import ModelParams

    planner = naive_planner(ModelParams(), wrap=lambda s: TimedSolver(s, ClassTally()))
    assert isinstance(planner.plain, TimedSolver) and isinstance(planner.plain.solver, NaiveOptiSolver)


def _short_cell():
    from mcverify.campaign.spec import campaign_from_dict

    raw = {"campaign": {"name": "phases", "seed": 3, "episodes": 2},
           "model": {"sim": {"max_time_s": 0.2}, "noise": {"kind": "paper"}}}
    return campaign_from_dict(raw).cells[0]


@pytest.mark.slow  # a timed closed-loop run; a benchmark tool, not the engine
def test_engine_phases_add_up_to_the_measured_cpu():
    from benchmarks.solver import stub_planner
    from mcverify.episode.rollout import PhaseClock, run_episodes

    cell = _short_cell()
    clock = PhaseClock()
    side = bench._timed("engine", lambda: run_episodes(cell, [0, 1, 2], 3, stub_planner(cell.params),
                                                       clock=clock).rows)
    phases = bench.engine_phases(side.rows, clock, side.cpu_s)
    assert phases["control_steps"] == 10  # 0.2 s at 50 Hz; the planner phase runs once per step
    assert clock.calls["plant"] == 20  # observe, then advance, in every step
    assert phases["plant"] > 0 and phases["solver_wall"] == 0.0  # the stub solves nothing
    total = phases["planner"] + phases["plant"] + phases["other"]
    assert math.isclose(total, side.cpu_s, rel_tol=1e-9, abs_tol=1e-6)
    side.phases = phases
    lines = engine_report.phase_lines(side, {"compute_ms": 1.0, "transfer_ms": 0.01, "batch": 3.0})
    assert "planner" in lines[0] and "plant" in lines[0] and "per control step of the batches" in lines[1]
    assert "device-to-host copies: 0.010 ms" in lines[2]


def test_plant_transfer_split_is_measured_per_step():
    split = bench.plant_transfer_ms(_short_cell(), batch=3, seed=3, reps=5)
    assert split["batch"] == 3.0 and split["compute_ms"] > 0 and split["transfer_ms"] >= 0


def test_bench_settings_reach_every_cell_and_bad_ones_are_one_line(monkeypatch, capsys):
    """``python -m benchmarks.engine --set``/``--seed``: written into the campaign before its cells are
    expanded, as for ``mcverify run``; a bad setting stops with one line (exit 2) before anything runs."""
    cells, seed, _ = bench.pick_cells(bench.DEFAULT_CAMPAIGN, "all", None,
                                      settings=["mpc.q2_solve=when_needed"], seed=7)
    assert seed == 7 and cells and all(c.params.mpc.q2_solve == "when_needed" for c in cells)
    seen = {}

    class Stop(Exception):
        pass

    def fake_run(**kwargs):  # the command's arguments, without running a benchmark
        seen.update(kwargs)
        raise Stop

    monkeypatch.setattr(bench, "run", fake_run)
    with pytest.raises(Stop):
        bench.main(["--no-write", "--seed", "7", "--set", "mpc.q2_solve=when_needed"])
    assert seen["seed"] == 7 and seen["settings"] == ["mpc.q2_solve=when_needed"]
    monkeypatch.undo()
    assert bench.main(["--no-write", "--set", "mpc.no_such_field=1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no_such_field" in err[0]
