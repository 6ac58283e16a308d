"""Counterexamples in every report: counterexamples.parquet and the report's table (issue 19.4)."""

from __future__ import annotations

import math

import pyarrow.parquet as pq

from mcverify import store
from mcverify.analysis import counterexamples as cx
from mcverify.analysis import robustness as rb
from mcverify.reporting import counterexample_report, run_report
from tests import synthetic


def _small(raw, episodes=30):
    return {**raw, "campaign": {**raw["campaign"], "episodes": episodes}}


def test_report_lists_every_unsafe_episode_worst_first(tmp_path):
    probs = {"unsafe": 0.4, "overtook": 0.8, "went_back": 0.15, "error": 0.05}
    run = synthetic.make_run(tmp_path / "run", _small(synthetic.TABLE4), opposing=True, probs=lambda c: probs)
    run_report.write(run)
    rows = store.read_episodes(run).to_pylist()
    unsafe = sorted(r["episode_id"] for r in rows if rb.robustness(r, "safe") < 0.0)
    assert unsafe, "the synthetic run should have unsafe episodes"
    # negative robustness only where the row itself says unsafe (synthetic rows may flag more)
    assert all(r["safe"] is False for r in rows if r["episode_id"] in unsafe)
    cex = pq.read_table(run / counterexample_report.FILE).to_pylist()
    assert sorted(r["episode_id"] for r in cex) == unsafe
    robs = [r["robustness"] for r in cex]
    assert robs == sorted(robs) and all(x < 0 for x in robs)
    by_id = {r["episode_id"]: r for r in rows}
    for r in cex:
        stored = by_id[r["episode_id"]]
        assert r["cell"] == stored["cell"]
        assert r["first_unsafe_s"] == stored["first_unsafe_s"] or math.isnan(stored["first_unsafe_s"])
        assert r["replay"] == f"mcverify replay {run} {r['episode_id']}"
        assert r["failure_mode"].split("/")[0] in rb.SAFE_SET
        # each cell's overrides are in the table (the axis values of TABLE4)
        assert any(k.startswith("param:") for k in r)
    report = (run / run_report.REPORT).read_text()
    assert "Counterexamples (safe)" in report
    assert f"mcverify replay {run} {cex[0]['episode_id']}" in report
    assert "Failure modes" in report


def test_a_safe_run_says_so(tmp_path):
    run = synthetic.make_run(tmp_path / "run", _small(synthetic.TABLE3, 4), trajectories=False)
    rows = store.read_episodes(run).to_pylist()
    recs = cx.counterexamples(store.read_episodes(run), store.read_json(run / store.MANIFEST), str(run),
                              requirement="theorem5_certified")
    expected = sum(1 for r in rows if not rb.is_error_row(r) and (r.get("both_certified_infeasible_steps") or 0) > 0)
    assert len(recs) == expected
    t = counterexample_report.table([], "safe", len(rows))
    assert t.rows == [] and any("No episode violated" in n for n in t.notes)
