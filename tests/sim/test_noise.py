"""Perception noise: bounds, uniformity (Kolmogorov-Smirnov), the exact "none" kind, and keys that
do not depend on the batch."""

from __future__ import annotations

from dataclasses import replace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from mcverify.model import Noise
from mcverify.sim import noise

PAPER = Noise()
ROOT = jax.random.PRNGKey(2024)
N_DRAWS = 4000






def draw(model: Noise, x: float, y: float, v: float, gap: float, n: int = N_DRAWS) -> np.ndarray:
    """(n, 3) measurement errors [dx, dy, dv] for n independent steps of one episode."""

    @jax.jit
    def one(step):
        m = noise.measure_vehicle(noise.step_key(ROOT, step, 0), x, y, v, gap, model)
        return jnp.stack(m) - jnp.array([x, y, v])

    return np.asarray(jax.vmap(one)(jnp.arange(n)))


def assert_uniform(sample: np.ndarray, half_width: float) -> None:
    assert np.all(np.abs(sample) <= half_width * (1 + 1e-12))
    assert np.max(np.abs(sample)) > 0.99 * half_width  # the whole range is used
    assert stats.kstest(sample, "uniform", args=(-half_width, 2 * half_width)).pvalue > 1e-3


@pytest.mark.parametrize(
    ("gap", "pos_half"),
    [(5.0, 0.5), (2.0001, 0.5), (2.0, 0.1), (0.3, 0.1), (0.0, 0.1)],  # gap == threshold: near
)
def test_paper_regimes_bounds_and_uniformity(gap: float, pos_half: float) -> None:
    errors = draw(PAPER, 70.0, 0.2, 6.94, gap)
    assert_uniform(errors[:, 0], pos_half)
    assert_uniform(errors[:, 1], pos_half)
    assert_uniform(errors[:, 2], 0.1 * 6.94)
    # x, y and v noise are independent draws
    assert abs(np.corrcoef(errors.T)[0, 1]) < 0.06 and abs(np.corrcoef(errors.T)[0, 2]) < 0.06


def test_scale_and_negative_speed() -> None:
    errors = draw(replace(PAPER, scale=3.0), -12.0, 3.5, -15.0, 10.0)
    assert_uniform(errors[:, 0], 1.5)
    assert_uniform(errors[:, 2], 3.0 * 0.1 * 15.0)  # relative to |speed|


def test_zero_speed_has_no_speed_noise() -> None:
    assert np.all(draw(PAPER, 1.0, 0.0, 0.0, 5.0, n=50)[:, 2] == 0.0)


def test_none_kind_is_exact() -> None:
    values = (64.123456789, -0.000123, 6.944444444444445)
    got = jax.jit(lambda k: noise.measure_vehicle(k, *values, 0.5, Noise(kind="none")))(ROOT)
    assert tuple(float(v) for v in got) == values
    assert draw(Noise(kind="none"), *values, 0.5, n=20).max() == 0.0


def test_unknown_kind_raises_naming_valid_kinds() -> None:
    with pytest.raises(ValueError, match="paper, none"):
        noise.measure_vehicle(ROOT, 0.0, 0.0, 1.0, 5.0, Noise(kind="gaussian"))


def test_step_key_is_fold_in_of_stream_then_step() -> None:
    want = jax.random.fold_in(jax.random.fold_in(ROOT, 3), 17)
    np.testing.assert_array_equal(noise.step_key(ROOT, 17, 3), want)
    np.testing.assert_array_equal(jax.jit(noise.step_key)(ROOT, jnp.int32(17), 3), want)
    keys = {tuple(np.asarray(noise.step_key(ROOT, s, c)).tolist()) for s in range(5) for c in range(3)}
    assert len(keys) == 15  # all distinct


def test_deterministic() -> None:
    a = draw(PAPER, 70.0, 0.2, 6.94, 5.0, n=100)
    b = draw(PAPER, 70.0, 0.2, 6.94, 5.0, n=100)
    np.testing.assert_array_equal(a, b)


def test_vmap_batch_does_not_change_episode_draws(assert_batch_equals_loop) -> None:
    """Episode i's measurements are the same computed alone or inside a vmapped batch of 7."""
    episode_keys = jax.vmap(lambda i: jax.random.fold_in(ROOT, i))(jnp.arange(7))
    rng = np.random.default_rng(5)
    truth = rng.uniform([0, -1, 0, 0], [100, 4, 20, 4], (7, 4))  # x, y, v, gap
    steps = jnp.arange(7) * 13

    def measure(key, step, t):
        return jnp.stack(noise.measure_vehicle(noise.step_key(key, step, 0), t[0], t[1], t[2], t[3], PAPER))

    def unit_draws(key, step):
        return jax.random.uniform(noise.step_key(key, step, 0), (3,), minval=-1.0, maxval=1.0)

    batched = np.asarray(jax.jit(jax.vmap(measure))(episode_keys, steps, truth))
    batched_keys = np.asarray(jax.vmap(noise.step_key, in_axes=(0, 0, None))(episode_keys, steps, 0))
    batched_units = np.asarray(jax.jit(jax.vmap(unit_draws))(episode_keys, steps))
    single = jax.jit(measure)
    for i in range(7):
        key_i = jax.random.fold_in(ROOT, i)
        # The random bits are integer arithmetic: identical regardless of the batch.
        np.testing.assert_array_equal(batched_keys[i], noise.step_key(key_i, steps[i], 0))
        np.testing.assert_array_equal(batched_units[i], jax.jit(unit_draws)(key_i, steps[i]))
        alone = np.asarray(single(key_i, steps[i], truth[i]))
        assert_batch_equals_loop(batched[i], alone)
        eager = np.asarray(measure(key_i, steps[i], truth[i]))
        np.testing.assert_allclose(eager, alone, rtol=1e-15, atol=1e-15)
