"""studies/t3-ellipse-graze/random_schedule_rate.py on constructed benchmark folders: the judged schedules it
counts, the cheapest whole restart, the exact bound and the beam's median."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import pytest

from mcverify.falsify import beam, beam_folder

SCRIPT = Path(__file__).resolve().parents[2] / "studies" / "t3-ellipse-graze" / "random_schedule_rate.py"


@pytest.fixture(scope="module")
def study():
    spec = importlib.util.spec_from_file_location("random_schedule_rate", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


SPEC = beam.BeamSpec(first_step=5, last_step=15, segment_steps=5, requirement="ellipse",
                     shape=beam.BeamShape(branching=1, width=4))


def _trial(folder: Path, restarts: list[tuple[list[float], int]]) -> None:
    """A trial folder whose beam/result.json holds restarts of (judged robustness values, control steps)."""
    summaries = tuple(
        beam_folder.RestartSummary(i, (), tuple(beam_folder.FrontierNode(r, r, "overtook", 30) for r in robs), 0,
                                   steps, 0, 9) for i, (robs, steps) in enumerate(restarts))
    summary = beam_folder.BeamSummary("t.toml", "ellipse", 0, 15, SPEC, 0.1, 100, summaries)
    (folder / "beam").mkdir(parents=True)
    (folder / "beam" / "result.json").write_text(json.dumps(summary.to_json()))


def test_schedules_are_counted_per_judged_node_and_only_whole_restarts_give_the_cost(study, tmp_path):
    random = tmp_path / "random-schedules"
    _trial(random / "trial-00", [([0.2, 0.3], 50), ([0.1, 0.4], 40)])
    _trial(random / "trial-01", [([0.5, 0.2], 45), ([0.3], 10)])  # the last restart cut by the budget
    assert study.random_schedules(random) == (7, 0, 2, 40, 2)


def test_the_beam_median_counts_a_failed_trial_beyond_the_budget(study, tmp_path):
    beam = tmp_path / "beam"
    _trial(beam / "trial-00", [([-0.1], 30)])
    _trial(beam / "trial-01", [([0.2, 0.3], 50), ([-0.2], 20)])  # found by the second restart: 70 steps
    _trial(beam / "trial-02", [([0.2, 0.3], 50)])
    assert study.beam_median(beam) == (0.7, 2, 3)


def test_the_printed_bound_is_the_geometric_median_at_the_exact_upper_rate(study, tmp_path, capsys, monkeypatch):
    root = tmp_path / "out" / "t"
    for t in range(3):
        _trial(root / "random-schedules" / f"trial-0{t}", [([0.2] * 4, 40)] * 25)  # 300 schedules, none violating
        _trial(root / "beam" / f"trial-0{t}", [([-0.1], 30)])
    monkeypatch.setattr("sys.argv", ["x", str(tmp_path / "out"), "--target", "t"])
    study.main()
    out = capsys.readouterr().out
    q_u = 1.0 - 0.05 ** (1 / 300)
    m = math.ceil(math.log(2) / -math.log1p(-q_u))
    assert "0 violations in 300 judged schedules over 3 trials (4 per restart)" in out
    assert f"median schedules to the first counterexample >= {m} " in out
    assert f"median cost to it >= {(m - 1) // 4 * 40 / 100:.3g} episode-equivalents" in out
    assert "median 0.3 episode-equivalents" in out
