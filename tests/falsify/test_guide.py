"""[falsify] guide: the method minimises another value than the requirement (mcverify.analysis.robustness
guides), while counterexamples are still judged by the requirement."""

from __future__ import annotations

import copy
import math

import numpy as np
import pyarrow.parquet as pq
import pytest

from mcverify.analysis import robustness as rb
from mcverify.campaign import executors
from mcverify.campaign.spec import campaign_from_dict
from mcverify.control.decision import Mode
from mcverify.errors import CampaignError, RunError
from mcverify.falsify import report, search
from mcverify.model import GUIDE_NAMES
from tests.falsify import fake_episodes

RAW = {
    "campaign": {"name": "turnback", "seed": 5, "episodes": 1},
    "falsify": {"requirement": "ellipse", "population": 6, "stop_at_first": True,
                "bounds": {"scenario.front_speed_mps": [5.0, 10.0], "opposing.speed_mps": [8.0, 19.4]}},
}


def _search(tmp_path, guide: str | None, seed: int, method: str = "cma", budget: int = 36):
    raw = copy.deepcopy(RAW)
    if guide is not None:
        raw["falsify"]["guide"] = guide
    config = search.SearchConfig(raw=raw, source="<test>", method=method, budget=budget, seed=seed,
                                 requirement="ellipse")
    return search.start(config, tmp_path / f"{guide}-{method}-{seed}", make_executor=executors.SerialExecutor,
                        episode_fn=fake_episodes.turnback)


def test_guide_lists_agree():
    assert rb.GUIDES == GUIDE_NAMES and rb.GO_BACK_MODE == Mode.GO_BACK


def test_go_back_guide_of_a_trajectory():
    row = {"epsilon": 0.3, "h0_front": 0.9, "min_h_front": -0.2, "outcome": "went_back"}
    traj = {"t_s": np.arange(1, 6) * 0.02, "h_front": np.array([-0.2, 0.5, 0.4, 0.6, 0.45]),
            "mode": np.array([0, 0, 1, 1, 1]), "gap_front_m": np.ones(5), "collision_front": np.zeros(5),
            "gap_opp_m": np.full(5, np.nan), "collision_opp": np.zeros(5)}
    assert rb.guide_value(row, traj, "ellipse@go_back") == 0.4  # the dip before the switch is not counted
    assert rb.guide_value(row, traj, "invariance@go_back") == pytest.approx(0.1)
    assert rb.guide_value(row, traj, "safe@go_back") == 1.0 / rb.SAFE_GAP_SCALE_M  # the 1 m gap, in h_ef units
    assert rb.guide_value(row, {**traj, "mode": np.zeros(5)}, "ellipse@go_back") == math.inf
    assert rb.guide_value(row, None, "ellipse") == -0.2  # a requirement is its row's robustness
    assert math.isnan(rb.guide_value({**row, "outcome": "error"}, traj, "ellipse@go_back"))
    with pytest.raises(ValueError, match="unknown guide"):
        rb.guide_value(row, traj, "ellipse@overtake")


def test_a_bad_guide_is_one_line():
    raw = copy.deepcopy(RAW)
    raw["falsify"]["guide"] = "ellipse@overtake"
    with pytest.raises(CampaignError) as err:
        campaign_from_dict(raw, source="c.toml")
    text = str(err.value)
    assert text.startswith("c.toml [falsify].guide: unknown guide 'ellipse@overtake'; known: ") and "\n" not in text


def test_splitting_refuses_a_guide_without_a_running_value(tmp_path):
    with pytest.raises(RunError, match="'ellipse@go_back' has none"):
        _search(tmp_path, "ellipse@go_back", 0, method="splitting")


def test_the_method_is_told_the_guide_and_the_requirement_judges(tmp_path):
    result = _search(tmp_path, "ellipse@go_back", 1, method="random", budget=12)
    table = pq.read_table(result.out_dir / search.SEARCH).to_pydict()
    for v, told, rob in zip(table["scenario.front_speed_mps"], table["guide"], table["robustness"], strict=True):
        h, mode = fake_episodes.turnback_margins(v, 0.0)
        assert rob == pytest.approx(h.min(), abs=0.002)  # the requirement: min h_ef over the whole episode
        assert told == (pytest.approx(h[mode == 1].min(), abs=0.002) if v < 7.5 else math.inf)
    assert all((r < 0) == viol for r, viol in zip(table["robustness"], table["violated"], strict=True))
    facts = dict(report.facts(result, search.counterexample_records(result)))
    assert "minimised `ellipse@go_back` instead of the requirement" in facts["guide"]
