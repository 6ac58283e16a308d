"""benchmarks.eps_curve: the curve's section is read from a run's stored summary (never typed in), with
exact bounds where no event occurred and where crude Monte Carlo's reach ends."""

from __future__ import annotations

import json

import synthetic

from benchmarks import eps_curve
from mcverify import api, files, store


def _run(tmp_path):
    """A synthetic finished ε sweep: its episodes, its summary and a manifest as a finished run has it."""
    raw = {**synthetic.EPS_SWEEP, "campaign": {**synthetic.EPS_SWEEP["campaign"], "episodes": 40}}
    run = synthetic.make_run(tmp_path / "eps", raw, probs=synthetic.eps_probs, trajectories=False)
    api.report(run)
    manifest = store.read_json(run / store.MANIFEST)
    manifest.update(sessions=[{"started_utc": "2026-01-01T10:00:00+00:00", "workers": 2}],
                    finished_utc="2026-01-01T11:30:00+00:00", environment={"git_commit": "abcdef0123", "cpu_count": 2})
    files.write_json_atomic(run / store.MANIFEST, manifest)
    return run


def test_the_section_reads_the_runs_counts(tmp_path, capsys):
    run = _run(tmp_path)
    page = tmp_path / "B.md"
    assert eps_curve.main([str(run), "--write", str(page)]) == 0
    text = page.read_text()
    assert "<!-- benchmarks.eps_curve:begin" in text and "| noise | ε | P(collision) |" in text
    assert "wall 1.50 h on 2 local workers" in text and "commit `abcdef0`" in text
    cells = json.loads((run / "summary.json").read_text())["cells"]
    for c in cells:  # every cell's counts are in the table, as k/n
        for metric, _ in eps_curve.EVENTS:
            assert eps_curve.rate_text(c["rates"][metric]) in text
    assert any(c["rates"]["collision"]["k"] == 0 for c in cells) and "(≤ " in text
    capsys.readouterr()


def test_rate_text_is_a_bound_without_events():
    assert eps_curve.rate_text({"k": 0, "n": 64, "upper_one_sided": 0.0457}) == "0/64 (≤ 0.046)"
    assert eps_curve.rate_text({"k": 3, "n": 64, "rate": 3 / 64, "low": 0.0098, "high": 0.131}) == \
        "3/64 = 0.047 [0.0098, 0.13]"


def test_an_unfinished_or_missing_run_is_one_line(tmp_path, capsys):
    assert eps_curve.main([str(tmp_path / "none"), "--no-write"]) == 2
    assert "run folder not found" in capsys.readouterr().err
