"""The noise tilt for importance sampling (:class:`mcverify.sim.tilt.NoiseTilt`): its draws follow
its density, its likelihood ratio is exact and bounded, and the plant draws every untilted step as
the plain :func:`~mcverify.sim.plant.observe` does."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate, stats

from mcverify.campaign.spec import campaign_from_dict
from mcverify.sim import plant as pl
from mcverify.sim import tilt as tl


@pytest.mark.parametrize("theta", [2.5, -1.5, 0.3, 6.0])
def test_tilted_draws_follow_the_tilted_density(theta):
    """Kolmogorov-Smirnov of the inverse-CDF draws against the CDF of q_theta on [-1, 1]."""
    u = jax.random.uniform(jax.random.PRNGKey(7), (4000,), dtype=float, minval=-1.0, maxval=1.0)
    z = np.asarray(tl.tilted_unit(u, theta))
    cdf = lambda x: (np.exp(theta * x) - np.exp(-theta)) / (np.exp(theta) - np.exp(-theta))  # noqa: E731
    assert stats.kstest(z, cdf).pvalue > 1e-3
    assert z.min() >= -1.0 and z.max() <= 1.0


def test_a_vanishing_tilt_is_the_uniform_itself():
    u = jnp.linspace(-1.0, 1.0, 11)
    assert np.array_equal(np.asarray(tl.tilted_unit(u, 0.0)), np.asarray(u))
    assert np.allclose(np.asarray(tl.tilt_density_ratio(u, 1e-9)), 1.0)
    # continuous through theta = 0 (the closed forms divide by theta)
    assert np.allclose(np.asarray(tl.tilted_unit(u, 1e-4)), np.asarray(u), atol=1e-4)


@pytest.mark.parametrize("theta", [4.0, -3.0])
def test_the_mixture_likelihood_ratio_reweights_to_the_nominal_probability(theta):
    """One tilted step under the episode-level mixture: E_q[w 1{z > 0.9}] = P_nominal(z > 0.9) = 0.05
    exactly (quadrature over the mixture density), and no weight exceeds 1 / defensive."""
    defensive = 0.3
    ratio = lambda z: float(tl.tilt_density_ratio(z, theta))  # noqa: E731
    mixture = lambda z: 0.5 * (defensive + (1 - defensive) * ratio(z))  # noqa: E731
    weight = lambda z: float(np.exp(tl.episode_log_lr(np.log(ratio(z)), defensive)))  # noqa: E731
    value, _ = integrate.quad(lambda z: mixture(z) * weight(z), 0.9, 1.0)
    assert value == pytest.approx(0.05, rel=1e-9)
    total, _ = integrate.quad(mixture, -1.0, 1.0)
    assert total == pytest.approx(1.0, rel=1e-9)
    log_ratios = jnp.linspace(-50.0, 50.0, 201)
    assert float(jnp.max(tl.episode_log_lr(log_ratios, defensive))) <= -np.log(defensive) + 1e-12


def _tilt(band_thetas: dict[int, tuple[float, float, float]], band_steps: float = 1e9,
          defensive: float = 0.3) -> tl.NoiseTilt:
    """Tilts per band (0 approach (3, 5] m, 1 jump (2, 3] m, 2 alongside)."""
    theta = np.zeros((3, 3))
    for band, values in band_thetas.items():
        theta[band] = values
    return tl.NoiseTilt(theta=tuple(theta.ravel()), split_m=3.0, gap_max_m=5.0, band_steps=band_steps,
                           defensive=defensive)


def _lane(gap_x_m: float):
    """One episode's plant with veh_f ``gap_x_m`` ahead of the ego's front bumper, both in the ego lane."""
    p = campaign_from_dict({"campaign": {"name": "x", "seed": 1, "episodes": 1}}).cells[0].params
    lane = jax.tree_util.tree_map(lambda a: a[0], pl.initial_plant(p, [0.0]))
    ego_x = float(lane.front[0]) - p.geometry.length_m - gap_x_m
    return p, lane._replace(ego=lane.ego.at[0].set(ego_x))


def test_the_plant_tilts_only_inside_the_window_and_counts_the_ratio():
    p, far = _lane(10.0)
    _, near = _lane(4.0)  # the approach band
    pp = pl.plant_params(p)
    tilt = _tilt({0: (1.0, -3.0, 2.0)})
    key = jax.random.PRNGKey(11)
    for step in range(20):
        s = jnp.int32(step)
        plain_front, plain_opp = pl.observe(far, key, s, pp)
        front, opp, after = pl.observe_tilted(far, key, s, pp, tilt.params(), jnp.bool_(True))
        # outside the window (gap 10 m > 5 m): the plain draws bit for bit, no ratio
        assert np.array_equal(np.asarray(front), np.asarray(plain_front)) and np.array_equal(opp, plain_opp)
        assert float(after.tilt_log_ratio) == 0.0 and not np.any(np.asarray(after.tilt_counts))
        front, _, after = pl.observe_tilted(near, key, s, pp, tilt.params(), jnp.bool_(True))
        speed = float(near.front[1])
        half = p.noise.scale * np.array([p.noise.pos_far_m, p.noise.pos_far_m, p.noise.speed_rel * speed])
        z = (np.asarray(front) - np.array([float(near.front[0]), 0.0, float(near.front[1])])) / half
        assert np.allclose(np.asarray(after.tilt_sums)[:3], z, atol=1e-9)
        assert np.asarray(after.tilt_counts).tolist() == [1.0, 0.0, 0.0]
        expected = float(tl.tilt_log_density_ratio(jnp.asarray(z), jnp.asarray([1.0, -3.0, 2.0])))
        assert float(after.tilt_log_ratio) == pytest.approx(expected, abs=1e-9)
        # a stopped episode's draws are not counted
        _, _, frozen = pl.observe_tilted(near, key, s, pp, tilt.params(), jnp.bool_(False))
        assert float(frozen.tilt_log_ratio) == 0.0 and not np.any(np.asarray(frozen.tilt_counts))


def test_a_tilt_moves_the_draws_the_way_it_says():
    """y tilt -3 on the approach, defensive 0.3 per episode: the y units average 0.7 (coth(-3) + 1/3)
    = -0.47 over episodes (70 % tilted, 30 % uniform)."""
    p, near = _lane(4.0)
    pp = pl.plant_params(p)
    numbers = _tilt({0: (0.0, -3.0, 0.0)}).params()
    keys = jax.vmap(lambda e: jax.random.fold_in(jax.random.PRNGKey(5), e))(jnp.arange(4000))
    run = jax.jit(jax.vmap(lambda k: pl.observe_tilted(near, k, jnp.int32(7), pp, numbers, jnp.bool_(True))[2]))
    sums = np.asarray(run(keys).tilt_sums)
    assert sums[:, 1].mean() == pytest.approx(0.7 * (1 / np.tanh(-3.0) + 1 / 3.0), abs=0.03)
    assert abs(sums[:, 0].mean()) < 0.05 and abs(sums[:, 2].mean()) < 0.05  # untilted units stay uniform


def test_each_band_is_tilted_for_band_steps_steps_only():
    p, approach = _lane(4.0)
    _, jump = _lane(2.5)
    pp = pl.plant_params(p)
    numbers = _tilt({0: (0.0, -3.0, 0.0), 1: (0.0, 3.0, 0.0)}, band_steps=2).params()
    key = jax.random.PRNGKey(21)
    lane = approach
    for step in range(3):
        front, _, lane = pl.observe_tilted(lane, key, jnp.int32(step), pp, numbers, jnp.bool_(True))
    assert np.asarray(lane.tilt_counts).tolist() == [2.0, 0.0, 0.0]  # the third approach step drew plainly
    plain, _ = pl.observe(lane, key, jnp.int32(2), pp)
    assert np.array_equal(np.asarray(front), np.asarray(plain))
    lane = jump._replace(tilt_log_ratio=lane.tilt_log_ratio, tilt_sums=lane.tilt_sums, tilt_counts=lane.tilt_counts)
    for step in range(3, 6):
        _, _, lane = pl.observe_tilted(lane, key, jnp.int32(step), pp, numbers, jnp.bool_(True))
    assert np.asarray(lane.tilt_counts).tolist() == [2.0, 2.0, 0.0]
    assert float(tl.episode_log_lr(lane.tilt_log_ratio, 0.3)) <= -np.log(0.3) + 1e-12
