"""`mcverify bench`'s bookkeeping (the benchmark itself is a command, not a timed test)."""

from __future__ import annotations

import math

from mcverify.bench import engine as bench


def row(e, safe=True, outcome="overtook", d=0.8, g=40.0, t=6.5, solves=100):
    return {"cell_episode": e, "safe": safe, "outcome": outcome, "min_dist_front_m": d, "min_gap_opp_m": g,
            "overtake_time_s": t, "solves": solves}


def test_agreement_pairs_by_episode_and_lists_disagreements():
    naive = [row(0), row(1, safe=False, outcome="timeout"), row(2, t=math.nan)]
    engine = [row(2, t=7.0), row(1), row(0, d=0.75), row(3)]
    ag = bench.agreement(naive, engine)
    assert ag["pairs"] == 3 and ag["same_safety"] == 2 and ag["disagreements"] == [1]
    assert ag["same_outcome"] == 2
    assert ag["max_abs_diff_min_dist_front_m"] == 0.050000000000000044
    assert ag["max_abs_diff_overtake_time_s"] == 0.0  # the NaN pair is skipped


def test_markdown_rows_go_into_the_bench_table(tmp_path):
    path = tmp_path / "BENCHMARKS.md"
    path.write_text("# Benchmarks\n\n## Other section\n\ntext\n")
    side = lambda n, cpu: bench.SideResult("x", [row(i) for i in range(n)], cpu, cpu)  # noqa: E731
    result = {"engine": side(4, 60.0), "naive": side(1, 600.0), "agreement": bench.agreement([row(0)], [row(0)]),
              "ratio": 40.0, "peak_rss_mb": 500.0, "machine": "m", "cell": "c", "backend": "ipopt",
              "command": "mcverify bench", "date": "2026-11-23", "campaign": "x"}
    bench.append_markdown(result, path)
    bench.append_markdown(result, path)
    text = path.read_text()
    assert text.count("| 2026-11-23 |") == 2 and text.count("| date |") == 1
    assert "## Other section" in text and "40.0x" in text
    assert result["engine"].episodes_per_cpu_min == 4.0 and result["naive"].episodes_per_cpu_min == 0.1
    assert result["engine"].cpu_ms_per_solve == 150.0


def _short_cell():
    from mcverify.run.campaign import campaign_from_dict

    raw = {"campaign": {"name": "phases", "seed": 3, "episodes": 2},
           "model": {"sim": {"max_time_s": 0.2}, "noise": {"kind": "paper"}}}
    return campaign_from_dict(raw).cells[0]


def test_engine_phases_add_up_to_the_measured_cpu():
    from mcverify.bench.solver_bench import stub_planner
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
    lines = bench.phase_lines(side, {"compute_ms": 1.0, "transfer_ms": 0.01, "batch": 3.0})
    assert "planner" in lines[0] and "plant" in lines[0] and "per control step of the 3-episode batch" in lines[1]
    assert "device-to-host copies: 0.010 ms" in lines[2]


def test_plant_transfer_split_is_measured_per_step():
    split = bench.plant_transfer_ms(_short_cell(), batch=3, seed=3, reps=5)
    assert split["batch"] == 3.0 and split["compute_ms"] > 0 and split["transfer_ms"] >= 0
