"""[falsify] extremes: searched fields taken at their low or high bound only (bang-bang)."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from mcverify.campaign import executors
from mcverify.campaign.spec import campaign_from_dict
from mcverify.errors import CampaignError
from mcverify.falsify import search
from tests.falsify import fake_episodes

RAW = {
    "campaign": {"name": "corners", "seed": 5, "episodes": 1},
    "falsify": {"requirement": "ellipse", "population": 6,
                "extremes": ["noise.front_x_bias", "noise.structured_share"],
                "bounds": {"scenario.front_speed_mps": [5.0, 10.0], "noise.structured_share": [0.0, 1.0],
                           "noise.front_x_bias": [-1.0, 1.0]}},
}


def _space(raw=RAW):
    return campaign_from_dict(copy.deepcopy(raw), source="<test>").falsify


def test_an_extreme_field_takes_its_bounds_only():
    space = _space()
    assert space.extremes == ("noise.front_x_bias", "noise.structured_share")
    low = space.values([0.3, 0.0, 0.4999])
    high = space.values([0.3, 0.5, 1.0])
    assert low == {"scenario.front_speed_mps": 6.5, "noise.structured_share": 0.0, "noise.front_x_bias": -1.0}
    assert high == {"scenario.front_speed_mps": 6.5, "noise.structured_share": 1.0, "noise.front_x_bias": 1.0}
    assert "noise.front_x_bias in {-1, 1} (extremes)" in space.describe()
    assert "scenario.front_speed_mps in [5, 10]" in space.describe()


def test_without_extremes_the_field_is_continuous():
    raw = copy.deepcopy(RAW)
    del raw["falsify"]["extremes"]
    space = _space(raw)
    assert space.extremes == ()
    assert space.values([0.3, 0.25, 0.75])["noise.front_x_bias"] == 0.5


@pytest.mark.parametrize(("extremes", "nominal", "message"), [
    ("noise.front_x_bias", None, r"extremes: expected a list of searched field names"),
    (["noise.front_v_bias"], None, r"extremes: 'noise.front_v_bias' is not a searched field"),
    (["noise.front_x_bias", "noise.front_x_bias"], None, r"extremes: a field is named twice"),
    (["noise.front_x_bias"], {"noise.front_x_bias": {"mean": 0.0, "std": 0.5}},
     r"extremes: 'noise.front_x_bias' has a \[falsify.nominal\] entry"),
])
def test_bad_extremes_are_one_line(extremes, nominal, message):
    raw = copy.deepcopy(RAW)
    raw["falsify"]["extremes"] = extremes
    if nominal:
        raw["falsify"]["nominal"] = nominal
    with pytest.raises(CampaignError, match=message) as info:
        _space(raw)
    assert "\n" not in str(info.value)


def test_a_search_runs_its_extreme_fields_at_the_bounds_and_repeats(tmp_path):
    config = search.SearchConfig(raw=copy.deepcopy(RAW), source="<test>", method="cross-entropy", budget=18,
                                 seed=3, requirement="ellipse")
    result = search.start(config, tmp_path / "ce", make_executor=executors.SerialExecutor,
                          episode_fn=fake_episodes.turnback)
    biases = np.array([e.values["noise.front_x_bias"] for e in result.evaluations])
    shares = np.array([e.values["noise.structured_share"] for e in result.evaluations])
    speeds = np.array([e.values["scenario.front_speed_mps"] for e in result.evaluations])
    assert len(biases) == 18 and set(biases) <= {-1.0, 1.0} and set(shares) <= {0.0, 1.0}
    assert len(set(speeds)) > 10  # the scenario field stays continuous
    again = search.start(config, tmp_path / "ce-again", make_executor=executors.SerialExecutor,
                         episode_fn=fake_episodes.turnback)
    assert [e.values for e in again.evaluations] == [e.values for e in result.evaluations]
