"""``mcverify estimate --method mc``: sequential stopping through the real runner, executors and store.

Synthetic Bernoulli episodes (tests/synthetic_episodes.py) stand in for the closed loop: the rule,
the ordering, the skipping of decided cells, resume from stored chunks and the report columns are
what is tested; the coverage of the interval itself is tested in tests/analysis/test_sequential.py.
"""

from __future__ import annotations

import functools
import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import synthetic_episodes as synth

from mcverify import store
from mcverify.analysis.estimates import EstimateSpec
from mcverify.analysis.sequential import StopRule, sequential_estimate
from mcverify.campaign import executors
from mcverify.campaign.spec import campaign_from_dict
from mcverify.cli import main
from mcverify.errors import RunError
from mcverify.estimate import mc

RAW = {"campaign": {"name": "est", "seed": 5, "episodes": 3}, "grid": {"scenario.front_speed_kmh": [25, 36]}}
BUDGET = 400


def _campaign():
    return campaign_from_dict(RAW, episodes=BUDGET)


def _fn(p: float = 0.2):
    return functools.partial(synth.bernoulli, p=p)


def _expected(camp, spec: EstimateSpec, p: float = 0.2) -> list:
    """The estimate computed directly from the episode function, in episode order."""
    out = []
    for cell in camp.cells:
        rows = synth.bernoulli(cell, tuple(range(BUDGET)), camp.seed, False, (), p=p).rows
        x = np.array([r["collision_front"] for r in rows])
        out.append(sequential_estimate(x, spec.rule(), spec.level, spec.prior))
    return out


def test_stops_each_cell_at_the_first_ordered_episode_meeting_the_rule(tmp_path: Path):
    camp, spec = _campaign(), EstimateSpec("mc", "collision", 0.08, False, BUDGET)
    report = mc.run(camp, spec, tmp_path / "run", executor=executors.SerialExecutor(), chunk_size=16,
                    progress=False, episode_fn=_fn())
    summ = json.loads((tmp_path / "run" / "summary.json").read_text())
    got = summ["estimates"]["cells"]
    for cell, exp in zip(got, _expected(camp, spec), strict=True):
        assert exp.status == "halfwidth" and exp.n < BUDGET
        assert (cell["n"], cell["k"], cell["status"]) == (exp.n, exp.k, exp.status)
        assert cell["low"] == pytest.approx(exp.low) and cell["high"] == pytest.approx(exp.high)
        # decided cells skip their later chunks: at most the chunk that met the rule was run past n
        assert exp.n <= cell["episodes_run"] < exp.n + 16
    cells = pq.read_table(tmp_path / "run" / "cells.parquet").to_pylist()
    assert [c["estimate_n"] for c in cells] == [e.n for e in _expected(camp, spec)]
    assert cells[0]["estimate_method"] == "mc" and cells[0]["estimate_target"] == "collision"
    assert "Estimated collision rate per cell" in report.read_text()
    manifest = store.read_manifest(tmp_path / "run")
    assert manifest["estimate"]["halfwidth"] == 0.08 and manifest["finished_utc"]


def test_same_estimate_with_parallel_workers_completing_out_of_order(tmp_path: Path):
    camp, spec = _campaign(), EstimateSpec("mc", "collision", 0.3, True, BUDGET)
    mc.run(camp, spec, tmp_path / "a", executor=executors.SerialExecutor(), chunk_size=8, progress=False,
           episode_fn=_fn())
    mc.run(camp, spec, tmp_path / "b", executor=executors.LocalExecutor(2), chunk_size=5, progress=False,
           episode_fn=_fn())
    a, b = (json.loads((tmp_path / d / "summary.json").read_text())["estimates"]["cells"] for d in "ab")
    keys = ("n", "k", "estimate", "low", "high", "status")
    assert [[c[k] for k in keys] for c in a] == [[c[k] for k in keys] for c in b]
    assert [c["n"] for c in a] == [e.n for e in _expected(camp, spec)]


def test_resume_reads_the_stored_counts(tmp_path: Path):
    camp, spec = _campaign(), EstimateSpec("mc", "collision", 0.08, False, BUDGET)
    run_dir = tmp_path / "run"
    calls: list[int] = []

    def stop_after_three(record):
        calls.append(record.first_episode)
        if len(calls) == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        from mcverify.campaign import runner

        runner.run(camp, run_dir, executor=executors.SerialExecutor(), chunk_size=16, progress=False,
                   episode_fn=_fn(), on_chunk=stop_after_three, stopper=mc.SequentialStopper(2, spec),
                   manifest_extra={"estimate": spec.as_dict()})
    mc.resume(run_dir, executor=executors.SerialExecutor(), progress=False, episode_fn=_fn())
    got = json.loads((run_dir / "summary.json").read_text())["estimates"]["cells"]
    assert [(c["n"], c["k"]) for c in got] == [(e.n, e.k) for e in _expected(camp, spec)]


def test_budget_ends_a_cell_without_an_event(tmp_path: Path):
    camp = campaign_from_dict(RAW, episodes=40)
    spec = EstimateSpec("mc", "collision", 0.3, True, 40)
    mc.run(camp, spec, tmp_path / "run", executor=executors.SerialExecutor(), chunk_size=16, progress=False,
           episode_fn=_fn(0.0))
    got = json.loads((tmp_path / "run" / "summary.json").read_text())["estimates"]["cells"]
    assert all(c["status"] == "budget" and c["k"] == 0 and c["n"] == 40 and c["low"] == 0.0 for c in got)
    assert all(0.0 < c["high"] < 0.2 for c in got)


def test_resume_of_a_plain_run_is_refused(tmp_path: Path):
    from mcverify.campaign import runner

    runner.run(campaign_from_dict(RAW), tmp_path / "run", executor=executors.SerialExecutor(), progress=False,
               episode_fn=synth.episodes)
    with pytest.raises(RunError, match="not an estimate run"):
        mc.resume(tmp_path / "run", executor=executors.SerialExecutor(), progress=False, episode_fn=_fn())


@pytest.mark.parametrize("argv, message", [
    (["estimate", "x.toml", "--until-halfwidth", "abc"], "expected a number or a percentage"),
    (["estimate", "x.toml", "--until-halfwidth", "1.5"], "must be > 0"),
    (["estimate", "x.toml", "--target", "nope"], "unknown target"),
    (["estimate", "--resume", "r", "--until-halfwidth", "0.1"], "--resume keeps"),
])
def test_cli_bad_input_is_one_line(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1


def test_stop_rule_on_budget_only_is_allowed():
    assert StopRule(None, False, 10).halfwidth is None


def test_the_report_draws_the_estimates_against_epsilon(tmp_path: Path):
    raw = {"campaign": {"name": "eps", "seed": 5, "episodes": 3}, "grid": {"barrier.epsilon": [0.1, 0.3, 0.5]}}
    camp = campaign_from_dict(raw, episodes=200)
    spec = EstimateSpec("mc", "collision", 0.1, False, 200)
    report = mc.run(camp, spec, tmp_path / "run", executor=executors.SerialExecutor(), chunk_size=25,
                    progress=False, episode_fn=_fn(0.1))
    assert (tmp_path / "run" / "figures" / "estimate-vs-epsilon.png").stat().st_size > 1000
    assert "figures/estimate-vs-epsilon.png" in report.read_text()


def test_a_spent_budget_with_error_rows_is_finished():
    """The budget counts episodes: an error row is left out of the sequence but spends budget, so a
    cell that ran its whole budget is finished (it used to stay "running" for ever)."""
    import pyarrow as pa

    from mcverify.analysis.columns import Columns
    from mcverify.analysis.estimates import cell_estimate

    rows = [{"cell_episode": i, "outcome": "error" if i == 3 else "overtook", "collision_front": False,
             "collision_opp": False, "steps": 10} for i in range(20)]
    res = cell_estimate(Columns.from_table(pa.Table.from_pylist(rows)), EstimateSpec(budget=20))
    assert (res["status"], res["n"], res["episodes_used"], res["errors_used"]) == ("budget", 19, 20, 1)
    early = cell_estimate(Columns.from_table(pa.Table.from_pylist(rows[:12])), EstimateSpec(budget=20))
    assert early["status"] == "running" and early["n"] == 11


def _one_interval_folder(tmp_path: Path, p: float = 0.2) -> tuple[dict, list]:
    camp, spec = _campaign(), EstimateSpec("mc", "collision", 0.15, False, BUDGET)
    mc.run(camp, spec, tmp_path / "run", executor=executors.SerialExecutor(), chunk_size=16, progress=False,
           episode_fn=_fn(p))
    return json.loads((tmp_path / "run" / "summary.json").read_text()), _expected(camp, spec, p)


def test_an_estimate_folder_gives_its_target_one_interval_everywhere(tmp_path: Path):
    """Issue 51: the outcome tables, figures, summary.json and cells.parquet of an estimate folder carry
    the estimator's anytime-valid interval over the episodes it used, never a fixed-count one."""
    summ, expected = _one_interval_folder(tmp_path)
    assert summ["interval_method"] == "confidence-sequence"
    for cell, est, exp in zip(summ["cells"], summ["estimates"]["cells"], expected, strict=True):
        rate = cell["rates"]["collision"]
        assert (rate["k"], rate["n"]) == (est["k"], est["n"]) == (exp.k, exp.n)
        assert (rate["low"], rate["high"]) == (est["low"], est["high"])
        assert rate["method"] == "confidence-sequence" and est["episodes_run"] > exp.n  # a later chunk: cost only
        assert cell["valid"] == exp.n
    assert summ["episodes_run"] > summ["episodes"]
    cells = pq.read_table(tmp_path / "run" / "cells.parquet").to_pylist()
    assert [(c["collision_low"], c["collision_high"]) for c in cells] == [(e.low, e.high) for e in expected]
    assert {c["interval_method"] for c in cells} == {"confidence-sequence"}
    report = (tmp_path / "run" / "report.md").read_text()
    assert "exact Clopper-Pearson" not in report and "exact one-sided" not in report
    assert "anytime-valid (beta-binomial confidence sequence)" in report
    first = summ["cells"][0]["rates"]["collision"]
    assert f"{first['k']}/{first['n']} [{first['low']:.3f}, {first['high']:.3f}]" in report


def test_the_report_of_an_estimate_keeps_its_interval(tmp_path: Path, capsys):
    """`mcverify report` rebuilds the same numbers; another method or level is refused in one line."""
    summ, _ = _one_interval_folder(tmp_path)
    run_dir = tmp_path / "run"
    assert main(["report", str(run_dir)]) == 0
    assert json.loads((run_dir / "summary.json").read_text())["cells"] == summ["cells"]
    capsys.readouterr()
    for extra in (["--method", "wilson"], ["--level", "0.9"]):
        assert main(["report", str(run_dir), *extra]) == 2
        err = capsys.readouterr().err.strip()
        assert "estimate" in err and len(err.splitlines()) == 1


def test_resuming_a_complete_estimate_runs_and_rewrites_nothing(tmp_path: Path, capsys):
    """The one --resume rule of run, estimate and falsify: a complete folder says so and exits 0."""
    camp = campaign_from_dict(RAW, episodes=40)
    mc.run(camp, EstimateSpec("mc", "collision", 0.3, True, 40), tmp_path / "run",
           executor=executors.SerialExecutor(), chunk_size=16, progress=False, episode_fn=_fn(0.0))
    summary = (tmp_path / "run" / "summary.json").stat().st_mtime_ns
    capsys.readouterr()
    assert main(["estimate", "--resume", str(tmp_path / "run")]) == 0
    assert capsys.readouterr().out.startswith(f"{tmp_path / 'run'} is already complete: nothing to run")
    assert (tmp_path / "run" / "summary.json").stat().st_mtime_ns == summary
