"""The JAX plant (mcverify.sim.plant): batching by fixed lane groups, checks against numpy, perception."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

from mcverify.episode.draws import episode_key
from mcverify.model import ModelParams
from mcverify.sim import lanes, plant

HUMAN = dataclasses.replace(
    ModelParams(),
    opposing=dataclasses.replace(ModelParams().opposing, kind="human", x_m=150.0, speed_mps=12.0, accel_mps2=1.6),
)


def run_world(params: ModelParams, ids: list[int], inputs: np.ndarray, steps: int = 12):
    """Drive the episodes ``ids`` (as one batch) with per-episode scripted inputs; collect everything."""
    keys = jnp.stack([episode_key(5, 0, e) for e in ids])
    world = lanes.LaneGroups(plant.initial_plant(params, [0.0] * len(ids)), keys, params)
    out = []
    for step in range(steps):
        front, opp = world.observe(step)
        ego = world.ego()
        subs = world.substeps_of(world.advance(inputs[ids, step], np.ones(len(ids), dtype=bool)))
        out.append((front, opp, ego, subs.ego, subs.opp, subs.h_front, subs.gap_opp_m))
    return out, world.trace()


@pytest.mark.parametrize("params", [ModelParams(), HUMAN], ids=["no-opposing", "human-opposing"])
def test_batch_rows_are_bit_identical_to_single_episodes(params):
    """vmap versus loop: 11 episodes in groups of LANES (8) - padded, split across two groups - give
    exactly the bits of each episode run alone, in any order."""
    rng = np.random.default_rng(0)
    inputs = np.stack([rng.uniform([-2, -0.1], [3, 0.1], (12, 2)) for _ in range(11)])
    batch, batch_trace = run_world(params, list(range(11)), inputs)
    for e in (0, 7, 8, 10):
        alone, alone_trace = run_world(params, [e], inputs)
        for b_step, a_step in zip(batch, alone, strict=True):
            for b_arr, a_arr in zip(b_step, a_step, strict=True):
                assert np.array_equal(b_arr[e], a_arr[0], equal_nan=True)
        for field in plant.SafetyTrace._fields:
            assert np.array_equal(getattr(batch_trace, field)[e], getattr(alone_trace, field)[0], equal_nan=True)
    reversed_batch, _ = run_world(params, [10, 3, 0], inputs)
    assert np.array_equal(reversed_batch[-1][2][0], batch[-1][2][10])


def test_opposing_checks_against_numpy():
    """Ego in the opposing lane facing veh_o: footprint gap, overlap and h_eo by hand."""
    pp = plant.plant_params(HUMAN)
    geo = HUMAN.geometry
    for gap in (12.0, 0.5, -0.3):
        x_o = 100.0 + geo.length_m + gap
        ego = jnp.array([100.0, 3.5, 0.0, 15.0])
        c = plant.checks(ego, jnp.array([40.0, 7.0]), jnp.array([x_o, -10.0]), jnp.array([1.0, 0.0]), pp)
        assert float(c.gap_opp_m) == pytest.approx(max(gap, 0.0), abs=1e-9)
        assert bool(c.hit_opp) == (gap < 0)
        assert float(c.h_opp) == pytest.approx(x_o - 100.0 - 25.0**2 / (2 * HUMAN.barrier.decel_max_mps2))
        assert bool(c.borrowing) and bool(c.opp_relevant)
    # back in its own lane the ego does not borrow: the opposing metrics do not count there
    c = plant.checks(jnp.array([100.0, 0.0, 0.0, 15.0]), jnp.array([40.0, 7.0]), jnp.array([110.0, -10.0]),
                     jnp.zeros(2), pp)
    assert not bool(c.borrowing) and not bool(c.opp_relevant) and not bool(c.hit_opp)


def test_no_opposing_vehicle_is_masked():
    pp = plant.plant_params(ModelParams())
    c = plant.checks(jnp.array([100.0, 3.5, 0.0, 15.0]), jnp.array([40.0, 7.0]), jnp.array([100.0, 0.0]),
                     jnp.zeros(2), pp)
    assert not bool(c.hit_opp) and np.isinf(float(c.gap_opp_m)) and not bool(c.opp_relevant)


def test_perception_noise_bounds_and_none_is_exact():
    for params, exact in ((dataclasses.replace(HUMAN, noise=dataclasses.replace(HUMAN.noise, kind="none")), True),
                          (HUMAN, False)):
        keys = jnp.stack([episode_key(1, 0, e) for e in range(16)])
        world = lanes.LaneGroups(plant.initial_plant(params, [0.0] * 16), keys, params)
        front, opp = world.observe(0)
        true_f = np.array([params.scenario.front_x_m, 0.0, params.scenario.front_speed_mps])
        true_o = np.array([params.opposing.x_m, -params.opposing.speed_mps])
        if exact:
            assert np.array_equal(front, np.tile(true_f, (16, 1))) and np.array_equal(opp, np.tile(true_o, (16, 1)))
            continue
        # far from both (gap > 2 m): position within +-0.5 m, speed within +-10 %
        assert np.all(np.abs(front[:, :2] - true_f[:2]) <= 0.5) and np.any(np.abs(front[:, 0] - true_f[0]) > 0.1)
        assert np.all(np.abs(front[:, 2] - true_f[2]) <= 0.1 * true_f[2] + 1e-12)
        assert np.all(np.abs(opp[:, 0] - true_o[0]) <= 0.5)
        assert np.all(np.abs(opp[:, 1] - true_o[1]) <= 0.1 * abs(true_o[1]) + 1e-12)
        assert not np.array_equal(front[:, 0], opp[:, 0] - true_o[0] + true_f[0])  # independent streams


def test_human_opposing_vehicle_accelerates_to_its_limit_in_the_plant():
    params = dataclasses.replace(HUMAN, opposing=dataclasses.replace(HUMAN.opposing, x_m=1000.0))
    inputs = np.zeros((1, 400, 2))
    out, _ = run_world(params, [0], inputs, steps=400)
    speeds = np.array([-step[4][0, -1, 1] for step in out])  # opp v at the last sub-step of each period
    assert np.all(np.diff(speeds) >= -1e-12) and speeds.max() == pytest.approx(params.opposing.speed_limit_mps)
    t_reach = (params.opposing.speed_limit_mps - params.opposing.speed_mps) / params.opposing.accel_mps2
    first = np.argmax(speeds >= params.opposing.speed_limit_mps - 1e-9) * params.sim.control_period_s
    assert first == pytest.approx(t_reach, abs=2 * params.sim.control_period_s)


def test_each_episode_accelerates_veh_f_from_its_own_onset_for_its_own_duration():
    """The burst's onset and duration are per episode (drawn, :data:`mcverify.draws.DRAWS`): three
    episodes of one batch, alpha_f = 2 m/s^2, veh_f gains alpha_f times the part of [0, t] its burst covers."""
    p = ModelParams()
    onsets, durations = [0.0, 0.101, 0.201], [np.inf, 0.2, 0.1]  # mid-sub-step edges: no rounding at t = onset
    keys = jnp.stack([episode_key(5, 0, e) for e in range(3)])
    world = lanes.LaneGroups(plant.initial_plant(p, [2.0] * 3, front_onsets_s=onsets, front_durations_s=durations),
                             keys, p)
    steps = round(0.5 / p.sim.control_period_s)
    for _ in range(steps):
        subs = world.substeps_of(world.advance(np.zeros((3, 2)), np.ones(3, dtype=bool)))
    t_s = steps * p.sim.control_period_s
    v0 = p.scenario.front_speed_mps
    for b in range(3):
        covered = max(0.0, min(t_s, onsets[b] + durations[b]) - onsets[b])
        assert subs.front[b, -1, 1] == pytest.approx(v0 + 2.0 * covered, abs=1e-9)
    default = plant.initial_plant(p, [2.0])
    assert (float(default.front_onset_s[0]), float(default.front_duration_s[0])) == (0.0, np.inf)
