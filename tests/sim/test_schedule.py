"""Error schedules: validation, and the measurement they make (the paper's bounds times the units and shares)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from mcverify.model import ModelParams
from mcverify.sim import plant
from mcverify.sim.schedule import ErrorSchedule, GapBandSchedule, ScheduleStep, step_units, units_from_normals


@pytest.mark.parametrize(("units", "shares", "says"), [
    (np.full((4, 5), 1.5), (1.0, 1.0), "outside [-1, 1]"),
    (np.array([[0, 0, np.nan, 0, 0]]), (1.0, 1.0), "front_v at row 0 is nan"),
    (np.zeros((4, 3)), (1.0, 1.0), "shape (steps >= 1, 5)"),
    (np.zeros(5), (1.0, 1.0), "shape"),
    (np.zeros((0, 5)), (1.0, 1.0), "shape"),
    (np.zeros((4, 5)), (1.2, 1.0), "front_share must lie in [0, 1]"),
    (np.zeros((4, 5)), (1.0, float("nan")), "opp_share must lie in [0, 1]"),
    ([["a"] * 5], (1.0, 1.0), "must be numbers"),
])
def test_bad_schedules_are_rejected_with_one_line(units, shares, says):
    with pytest.raises(ValueError, match=None) as err:
        ErrorSchedule.of(units, *shares)
    assert says in str(err.value) and "\n" not in str(err.value)


def test_bad_gap_bands_are_rejected():
    with pytest.raises(ValueError, match="non-decreasing"):
        GapBandSchedule.of(np.zeros((3, 5)), [3.0, 2.0, 10.0])
    with pytest.raises(ValueError, match=r"shape \(3, 5\)"):
        GapBandSchedule.of(np.zeros((2, 5)), [1.0, 2.0, 10.0])


def test_steps_beyond_the_schedule_measure_exactly():
    s = ErrorSchedule.of(np.full((3, 5), 0.5))
    padded = s.padded(5)
    assert (padded[:3] == 0.5).all() and (padded[3:] == 0.0).all()
    assert s.padded(2).shape == (2, 5)


def test_units_from_normals_is_two_phi_minus_one():
    np.testing.assert_allclose(units_from_normals([0.0, 1.959963984540054, -1.0]), [0.0, 0.95, -0.6826894921370859],
                               rtol=1e-12)


def _step(units, band_units=None, edges=(2.0, 3.0, 15.0), banded=False, shares=(1.0, 1.0)):
    band_units = np.zeros((3, 5)) if band_units is None else band_units
    return ScheduleStep(jnp.asarray(units, dtype=float), jnp.asarray(band_units, dtype=float),
                        jnp.asarray(edges, dtype=float), jnp.asarray(banded), jnp.asarray(shares, dtype=float))


def test_gap_bands_pick_the_band_of_the_gap():
    bands = np.arange(15, dtype=float).reshape(3, 5) / 20.0
    for gap, row in [(1.0, 0), (2.5, 1), (10.0, 2)]:
        np.testing.assert_array_equal(step_units(_step(np.zeros(5), bands, banded=True), jnp.asarray(gap)), bands[row])
    np.testing.assert_array_equal(step_units(_step(np.zeros(5), bands, banded=True), jnp.asarray(20.0)), np.zeros(5))
    np.testing.assert_array_equal(step_units(_step(np.full(5, 0.3), bands), jnp.asarray(1.0)), np.full(5, 0.3))


def test_scheduled_measurement_is_share_times_unit_times_the_bound():
    p = ModelParams()
    pp = plant.plant_params(p)
    world = plant.initial_plant(p, [0.0])
    one = type(world)(*(a[0] for a in world))
    gap = float(plant.checks(one.ego, one.front, one.opp, jnp.zeros(2), pp).gap_front_m)
    assert gap > p.noise.near_threshold_m  # far noise
    units = np.array([0.5, -1.0, 1.0, 0.25, -0.5])
    key = jnp.zeros(2, dtype=jnp.uint32)  # unused: no draw
    front, _, applied = plant.observe_scheduled(one, key, _step(units, shares=(0.5, 0.0)), pp)
    pos, speed = p.noise.scale * p.noise.pos_far_m, p.noise.scale * p.noise.speed_rel * float(one.front[1])
    np.testing.assert_allclose(np.asarray(front), [float(one.front[0]) + 0.5 * 0.5 * pos, -0.5 * pos,
                                                   float(one.front[1]) + 0.5 * speed], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(np.asarray(applied), units)
    exact, _, _ = plant.observe_scheduled(one, key, _step(np.zeros(5)), pp)
    np.testing.assert_array_equal(np.asarray(exact), [float(one.front[0]), 0.0, float(one.front[1])])
