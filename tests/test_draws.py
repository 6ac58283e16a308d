"""The registry of per-episode draws (mcverify.draws): streams, columns, ranges, read by every layer."""

from __future__ import annotations

import math

import jax
import pytest

from mcverify.campaign.spec import campaign_from_dict
from mcverify.draws import DRAW_NAMES, DRAWS, SCENARIO_STREAM, field_value
from mcverify.episode.draws import episode_key, sample_scenario
from mcverify.errors import CampaignError
from mcverify.estimate import importance_run
from mcverify.model import ModelParams
from mcverify.schema import COLUMN_NAMES, column

LANE_ENTRY = {"opposing": {"kind": "human", "spawn": "lane_entry", "speed_range_mps": [10.0, 14.0],
                           "spawn_gap_range_m": [60.0, 90.0], "spawn_delay_range_s": [0.5, 2.0]},
              "scenario": {"front_accel_range_mps2": [1.0, 3.0], "front_accel_onset_range_s": [1.0, 4.0],
                           "front_accel_duration_range_s": [0.5, 2.5]}}


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
                      "opp_spawn_gap_m": (60.0, 90.0), "opp_spawn_delay_s": (0.5, 2.0),
                      "front_accel_onset_s": (1.0, 4.0), "front_accel_duration_s": (0.5, 2.5)}
    nominal = importance_run.scenario_nominal(cell)
    assert nominal.mean[3] == 1.0 and nominal.sd[3] == 0.5  # the spawn delay: a truncated normal
    assert all(math.isnan(m) for i, m in enumerate(nominal.mean) if i != 3)  # the others uniform


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


# ------------------------------------------------------------------ the burst's onset and duration

TABLE3 = {"scenario": {"front_accel_range_mps2": [3.0, 5.0], "front_accel_onset_s": 3.5,
                       "front_accel_duration_s": 1.5},
          "opposing": {"kind": "autonomous", "x_m": 450.0, "speed_mps": 15.0}}
DRAWN_BURST = {**TABLE3, "scenario": {**TABLE3["scenario"], "front_accel_onset_range_s": [1.0, 4.0],
                                      "front_accel_duration_range_s": [0.5, 2.5]}}


def test_a_drawn_burst_lies_in_its_ranges_is_keyed_and_varies_across_episodes():
    p = _params(DRAWN_BURST)
    draws = [sample_scenario(episode_key(2024, 1, e), p) for e in range(64)]
    onsets = [d["front_accel_onset_s"] for d in draws]
    durations = [d["front_accel_duration_s"] for d in draws]
    assert all(1.0 < x <= 4.0 for x in onsets) and all(0.5 < x <= 2.5 for x in durations)
    assert len(set(onsets)) == len(onsets) and len(set(durations)) == len(durations)
    assert sample_scenario(episode_key(2024, 1, 17), p) == draws[17]  # the same (seed, cell, episode): the same
    assert onsets[17] != sample_scenario(episode_key(2025, 1, 17), p)["front_accel_onset_s"]  # another seed


def test_the_burst_draws_leave_every_other_draw_as_it_was():
    """Adding the ranges changes no other draw (their streams are new), and without them the episode
    keeps the fixed onset and duration: the campaigns of fixed bursts draw what they drew before."""
    fixed, drawn = _params(TABLE3), _params(DRAWN_BURST)
    for e in range(8):
        key = episode_key(2024, 2, e)
        before, after = sample_scenario(key, fixed), sample_scenario(key, drawn)
        assert (before["front_accel_onset_s"], before["front_accel_duration_s"]) == (3.5, 1.5)
        others = [n for n in DRAW_NAMES if n not in ("front_accel_onset_s", "front_accel_duration_s")]
        assert [after[n] for n in others] == [before[n] for n in others]
        unit = float(jax.random.uniform(jax.random.fold_in(key, SCENARIO_STREAM + 0), (), dtype=float))
        assert before["front_accel_mps2"] == 5.0 - 2.0 * unit  # alpha_f from stream 0, bit for bit
    default = sample_scenario(jax.random.PRNGKey(0), ModelParams())
    assert default["front_accel_onset_s"] == 0.0 and default["front_accel_duration_s"] == math.inf


@pytest.mark.parametrize(("field", "bad"), [
    ("front_accel_onset_range_s", [4.0, 1.0]), ("front_accel_onset_range_s", [-1.0, 2.0]),
    ("front_accel_onset_range_s", [1.0]), ("front_accel_duration_range_s", [0.0, 0.0]),
    ("front_accel_duration_range_s", [1.0, math.inf]), ("front_accel_duration_range_s", [-0.5, 1.0]),
])
def test_a_bad_burst_range_is_refused_in_one_line_naming_the_field(field, bad):
    with pytest.raises(CampaignError, match=f"scenario.{field}") as err:
        _params({**TABLE3, "scenario": {**TABLE3["scenario"], field: bad}})
    assert "\n" not in str(err.value)
