"""The registry of per-episode draws (mcverify.draws): streams, columns, ranges, read by every layer."""

from __future__ import annotations

import math

import jax
import pytest

from mcverify.campaign.spec import campaign_from_dict
from mcverify.draws import DRAW_NAMES, DRAWS, SCENARIO_STREAM, field_value
from mcverify.episode.draws import sample_scenario
from mcverify.errors import CampaignError
from mcverify.estimate import importance_run
from mcverify.model import ModelParams
from mcverify.schema import COLUMN_NAMES, column

LANE_ENTRY = {"opposing": {"kind": "human", "spawn": "lane_entry", "speed_range_mps": [10.0, 14.0],
                           "spawn_gap_range_m": [60.0, 90.0], "spawn_delay_range_s": [0.5, 2.0]},
              "scenario": {"front_accel_range_mps2": [1.0, 3.0]}}


def _params(model):
    return campaign_from_dict({"campaign": {"name": "d", "seed": 1, "episodes": 1}, "model": model}).cells[0].params


def test_each_draw_has_its_own_stream_and_a_stored_column():
    assert len({d.stream for d in DRAWS}) == len(DRAWS)
    for d in DRAWS:
        assert d.column in COLUMN_NAMES and column(d.column).unit == d.unit
        p = ModelParams()
        field_value(p, d.range_field), field_value(p, d.fixed_field)  # the fields exist in the model
        assert not d.sd_field or d.sd(p) >= 0.0


def test_a_draw_comes_from_its_stream_of_the_episode_key():
    """Bit for bit: uniform in (lo, hi] from fold_in(key, SCENARIO_STREAM + stream), as ever."""
    p = _params(LANE_ENTRY)
    key = jax.random.PRNGKey(7)
    got = sample_scenario(key, p)
    assert tuple(got) == DRAW_NAMES
    for d in DRAWS:
        lo, hi = d.range_of(p)
        unit = float(jax.random.uniform(jax.random.fold_in(key, SCENARIO_STREAM + d.stream), (), dtype=float))
        assert got[d.name] == float(hi - (hi - lo) * unit), d.name


def test_a_cell_without_veh_o_draws_no_veh_o_values():
    got = sample_scenario(jax.random.PRNGKey(0), _params({"opposing": {"kind": "none"}}))
    assert got["front_accel_mps2"] == ModelParams().scenario.front_accel_mps2
    assert all(math.isnan(got[n]) for n in ("opp_speed_mps", "opp_spawn_gap_m", "opp_spawn_delay_s"))


def test_importance_sampling_reads_the_ranges_and_normals_of_the_registry():
    p = _params({**LANE_ENTRY, "opposing": {**LANE_ENTRY["opposing"], "spawn_delay_s": 1.0,
                                            "spawn_delay_sd_s": 0.5}})
    cell = type("C", (), {"params": p})()
    bounds = importance_run.scenario_bounds(cell)
    assert bounds == {"front_accel_mps2": (1.0, 3.0), "opp_speed_mps": (10.0, 14.0),
                      "opp_spawn_gap_m": (60.0, 90.0), "opp_spawn_delay_s": (0.5, 2.0)}
    nominal = importance_run.scenario_nominal(cell)
    assert nominal.mean[3] == 1.0 and nominal.sd[3] == 0.5  # the spawn delay: a truncated normal
    assert all(math.isnan(m) for m in nominal.mean[:3])  # the others uniform


def test_the_schema_lists_the_draws_in_registry_order():
    sample_columns = [c for c in COLUMN_NAMES if c.startswith("sample_")]
    assert sample_columns == [d.column for d in DRAWS]


@pytest.mark.parametrize("draw", DRAWS, ids=lambda d: d.name)
def test_validation_refuses_a_range_beyond_the_registry_bounds_in_one_line(draw):
    p = _params(LANE_ENTRY)
    lo, hi = draw.lowest(p), draw.highest(p)
    section, name = draw.range_field.split(".")
    ok = [lo + 0.5, lo + 1.0] if math.isinf(hi) else [lo + 0.5 * (hi - lo), hi]
    model = {**LANE_ENTRY, section: {**LANE_ENTRY[section], name: ok}}
    assert _params(model) is not None  # within the bounds: accepted
    for bad in ([lo - 1.0, lo + 1.0], [ok[0], hi + 1.0]) if not math.isinf(hi) else ([lo - 1.0, lo + 1.0],):
        with pytest.raises(CampaignError, match=draw.range_field) as err:
            _params({**LANE_ENTRY, section: {**LANE_ENTRY[section], name: bad}})
        assert "\n" not in str(err.value)
