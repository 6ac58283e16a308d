"""Importance sampling with a noise tilt: the score function draws part of each sample from the
band-wise tilts of :class:`mcverify.sim.tilt.NoiseTilt` (two "steps", one in the approach band and
one in the jump band, three units each, as the plant does) and returns
:class:`mcverify.estimate.importance.Scored` with the likelihood ratio of those draws, and refits the
tilts by cross-entropy (``refit_noise``). Failure where theta >= 0.8 and the y unit jumps from below
-0.5 (approach) to above 0.9 (jump): p known exactly."""

from __future__ import annotations

from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mcverify.estimate import importance
from mcverify.sim import noise
from mcverify.sim import tilt as tl

BOUNDS = [(0.0, 1.0)]
# P(theta >= 0.8) * P(y_approach < -0.5) * P(y_jump > 0.9) with uniform units on [-1, 1]
P = 0.2 * 0.25 * 0.05


def tilt_of(y_approach: float, y_jump: float) -> tl.NoiseTilt:
    theta = np.zeros((3, 3))
    theta[0, 1], theta[1, 1] = y_approach, y_jump
    return tl.NoiseTilt(theta=tuple(theta.ravel()), split_m=1.0, gap_max_m=2.0, band_steps=1, defensive=0.3)


def _draw(key: jax.Array, theta: jax.Array, defensive: float):
    """Two tilted steps (bands 0 and 1) as in observe_tilted: units (2, 3), the episode's log ratio
    (nominal over the episode-level mixture) and the sums (9,)."""
    nominal = jax.random.uniform(jax.random.fold_in(key, tl.STREAM_TILT), (), dtype=float) < defensive
    units, log_ratio = [], 0.0
    for band in range(2):
        z, lr = tl.tilted_units(noise.unit_draws(noise.step_key(key, band, 0)), nominal, theta[band])
        units.append(z)
        log_ratio = log_ratio + lr
    sums = jnp.concatenate([units[0], units[1], jnp.zeros(3)])
    return jnp.stack(units), tl.episode_log_lr(log_ratio, defensive), sums


@dataclass
class TiltedScore:
    seed: int
    tilt: tl.NoiseTilt
    calls: int = 0
    last: dict = field(default_factory=dict)

    def __call__(self, theta: np.ndarray) -> importance.Scored:
        keys = jax.vmap(lambda e: jax.random.fold_in(jax.random.PRNGKey(self.seed), e))(
            jnp.arange(theta.shape[0]) + 100_000 * self.calls)
        self.calls += 1
        table = jnp.asarray(self.tilt.theta, dtype=float).reshape(3, 3)
        units, log_lr, sums = (np.asarray(a) for a in jax.vmap(lambda k: _draw(k, table, self.tilt.defensive))(keys))
        self.last = {"sums": sums, "counts": np.tile([1.0, 1.0, 0.0], (theta.shape[0], 1))}
        jump = np.minimum(-0.5 - units[:, 0, 1], units[:, 1, 1] - 0.9)  # >= 0 iff the jump happened
        return importance.Scored(np.minimum(theta[:, 0] - 0.8, jump), log_lr)

    def refit_noise(self, elite: np.ndarray, weights: np.ndarray) -> None:
        self.tilt = tl.refit_tilt(self.tilt, self.last["sums"][elite], self.last["counts"][elite], weights)


def test_a_good_tilt_makes_the_event_common_and_the_estimate_is_close():
    score = TiltedScore(1, tilt_of(-3.0, 5.0))
    est = importance.estimate(score, BOUNDS, samples=2000, seed=1, max_iterations=0,
                              max_extra_ratio=score.tilt.max_ratio())
    assert est.contains(P) and est.failures > 50  # 1 in 50 draws against 1 in 400 nominally
    assert est.anytime_lower <= est.estimate


def test_cross_entropy_finds_the_jump_from_an_untilted_start():
    score = TiltedScore(2, tilt_of(0.0, 0.0))
    est = importance.estimate(score, BOUNDS, samples=1000, seed=2, per_iteration=400, max_iterations=6,
                              max_extra_ratio=score.tilt.max_ratio())
    theta = np.asarray(score.tilt.theta).reshape(3, 3)
    assert theta[0, 1] < -1.0 and theta[1, 1] > 2.0  # y low on the approach, high in the jump band
    assert abs(theta[0, 0]) < 1.0 and abs(theta[1, 2]) < 1.0  # units the event ignores stay near 0
    assert est.contains(P) and est.failures > 100


@pytest.mark.parametrize("reps, floor", [pytest.param(12, 0.75, id="fast"),
                                          pytest.param(100, 0.9, id="large", marks=pytest.mark.slow)])
def test_coverage_with_the_noise_ratio_in_the_weights(reps, floor):
    ests = []
    for r in range(reps):
        score = TiltedScore(50 + r, tilt_of(-3.0, 5.0))
        ests.append(importance.estimate(score, BOUNDS, samples=1000, seed=50 + r, per_iteration=100,
                                        max_iterations=1, max_extra_ratio=score.tilt.max_ratio()))
    values = np.array([e.estimate for e in ests])
    assert np.mean([e.contains(P) for e in ests]) >= floor
    assert abs(values.mean() / P - 1) < 0.1
    assert np.mean([e.anytime_lower > P for e in ests]) <= 0.1


def test_leaving_the_ratio_out_is_biased():
    """The counter-example: the same tilted draws weighted as if nominal overestimate p several times."""
    score = TiltedScore(7, tilt_of(-3.0, 5.0))
    est = importance.estimate(lambda t: score(t).scores, BOUNDS, samples=1000, seed=7, max_iterations=0)
    assert est.estimate > 3 * P


def test_without_cross_entropy_the_scenario_stays_nominal():
    """max_iterations 0 (``--ce-iterations 0``): the scenario is drawn from the nominal, only the tilt acts."""
    score = TiltedScore(3, tilt_of(-3.0, 5.0))
    est = importance.estimate(score, BOUNDS, samples=2000, seed=3, max_iterations=0,
                              max_extra_ratio=score.tilt.max_ratio())
    assert est.ce_iterations == 0 and est.proposal_a == [1.0] and est.proposal_b == [1.0]
    assert est.contains(P) and not any("cross-entropy" in w for w in est.warnings)
    assert score.tilt == tilt_of(-3.0, 5.0)  # no iteration, no refit


def test_the_refit_matches_the_weighted_mean_of_the_drawn_units():
    tilt = tilt_of(0.0, 0.0)
    sums = np.zeros((2, 9))
    sums[:, 1] = [-0.6, -0.8]  # approach y of two elite episodes, one tilted step each
    new = tl.refit_tilt(tilt, sums, np.array([[1.0, 0, 0], [1.0, 0, 0]]), np.array([1.0, 3.0]), smoothing=1.0)
    fitted = new.theta[1]
    assert tl.tilt_mean(np.array(fitted)) == pytest.approx((-0.6 + 3 * -0.8) / 4, abs=1e-9)
    assert new.theta[0] == pytest.approx(0.0, abs=1e-9)  # approach x: drawn, mean 0
    assert new.theta[4] == 0.0  # the jump band had no tilted step: its tilt is kept
