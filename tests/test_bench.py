"""`mcverify bench`'s bookkeeping (the benchmark itself is a command, not a timed test)."""

from __future__ import annotations

import math

from mcverify import bench


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
