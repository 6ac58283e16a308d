"""A proposal for veh_f's measurement noise (importance sampling): an exponential tilt of the step's
uniform units near veh_f, its likelihood ratio and its cross-entropy refit. Never part of a
campaign's model; the nominal noise is :mod:`mcverify.sim.noise`."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NamedTuple, TypeAlias

import jax
import jax.numpy as jnp
import numpy as np

Array: TypeAlias = jax.Array
ArrayLike: TypeAlias = jax.typing.ArrayLike

#: The bands of a noise tilt, by veh_f's footprint gap as the ego closes in: approach (split_m, gap_max_m],
#: jump (near_threshold_m, split_m] (the last far-noise steps), alongside (<= near_threshold_m, near noise).
TILT_BANDS: tuple[str, ...] = ("approach", "jump", "alongside")
#: The measured quantities of veh_f a noise tilt draws, in the order of :func:`mcverify.sim.noise.unit_draws`.
TILT_UNITS: tuple[str, ...] = ("x", "y", "v")


class TiltParams(NamedTuple):
    """A :class:`NoiseTilt` as the plant's runtime numbers: theta (bands, units) = (3, 3), the rest scalars."""

    theta: Array
    split_m: Array
    gap_max_m: Array
    band_steps: Array
    defensive: Array
    theta_max: Array


class NoiseTilt(NamedTuple):
    """A proposal for veh_f's measurement noise near veh_f, for importance sampling
    (``mcverify estimate --method importance --noise-tilt``); never part of a campaign's model.

    Nominally the units z = [z_x, z_y, z_v] in [-1, 1]^3 of a step (:func:`mcverify.sim.noise.unit_draws`) are
    independent uniforms (density 1/2 each). The proposal is a defensive mixture *per episode* [Hes95]: with
    probability ``defensive`` the episode draws nominally throughout, otherwise its *tilted steps* draw
    from ``prod_c q_theta[b, c]`` with the exponential tilts
    ``q_theta(z) = theta e^(theta z) / (2 sinh theta)``, one theta per band b (:data:`TILT_BANDS`, by
    veh_f's footprint gap: approach (split_m, gap_max_m], jump (near_threshold_m, split_m], alongside
    below near_threshold_m) and unit c (:data:`TILT_UNITS`). The first ``band_steps`` steps of an episode
    in each band are tilted, no others. With theta_y < 0 on the approach and > 0 in the jump band the
    measured veh_f jumps towards the ego at the last far-noise step, the pattern that makes Q1
    infeasible alongside veh_f (docs/rare_events.md). The episode's likelihood ratio (nominal over
    proposal) is ``1 / (defensive + (1 - defensive) R)`` with R the product of the tilted densities
    over the nominal ones at its tilted steps (whichever component drew them), so it never exceeds
    ``1 / defensive``: routes to the event that the tilt makes rarer keep at least that share of their
    nominal rate (a per-step mixture bounds each step only, and such routes then carry heavy weights;
    measured, docs/rare_events.md). Every untilted step draws as always. The tilts are natural
    exponential families in z, so a cross-entropy refit needs only each episode's per-band sums of z
    and step counts (:func:`refit_tilt`).

    [Hes95] T. Hesterberg, Weighted average importance sampling and defensive mixture distributions,
    Technometrics 37 (1995).

    theta: 9 tilts, row-major (band, unit); split_m, gap_max_m: m (gap_max_m 0 turns the tilt off);
    band_steps: count per band; defensive in (0, 1]; theta_max bounds every |theta|.
    """

    theta: tuple[float, ...] = (0.0,) * 9
    split_m: float = 3.0
    gap_max_m: float = 0.0
    band_steps: float = 2.0
    defensive: float = 0.3
    theta_max: float = 6.0

    def params(self) -> TiltParams:
        """The runtime numbers of :func:`mcverify.sim.plant.observe_tilted` (float arrays)."""
        f = lambda v: jnp.asarray(v, dtype=float)  # noqa: E731
        return TiltParams(f(self.theta).reshape(len(TILT_BANDS), len(TILT_UNITS)), f(self.split_m), f(self.gap_max_m),
                          f(self.band_steps), f(self.defensive), f(self.theta_max))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> NoiseTilt:
        """The tilt of its stored form (``_asdict()`` as JSON: theta a list; a missing theta is all 0)."""
        return cls(**{**data, "theta": tuple(data.get("theta", (0.0,) * 9))})

    def max_ratio(self) -> float:
        """The largest likelihood ratio an episode can carry: 1 / defensive."""
        return 1.0 / self.defensive


#: fold_in stream of the episode's mixture choice (apart from the per-step streams, the scenario stream
#: 1_000_000 and the branch stream 2_000_000 of the episode layer).
STREAM_TILT = 3_000_000
#: Below this |theta| the tilt is the uniform itself (the closed forms divide by theta).
_THETA_EPS = 1e-6


def tilted_unit(unit: ArrayLike, theta: ArrayLike) -> Array:
    """Inverse-CDF draw from ``q_theta`` on [-1, 1] given a uniform ``unit`` in [-1, 1]:
    ``z = log(e^-theta + v (e^theta - e^-theta)) / theta`` with v = (unit + 1) / 2, written stably
    for large |theta|; the unit itself when |theta| is tiny. Elementwise."""
    u = jnp.asarray(unit, dtype=float)
    th = jnp.asarray(theta, dtype=float)
    v = 0.5 * (u + 1.0)
    a = jnp.abs(th)
    safe = jnp.where(a < _THETA_EPS, 1.0, a)
    # for theta > 0: z = 1 + log(v + (1 - v) e^(-2 theta)) / theta; theta < 0 mirrors it (z -> -z, v -> 1 - v)
    w = jnp.where(th >= 0, v, 1.0 - v)
    z_pos = 1.0 + jnp.log(w + (1.0 - w) * jnp.exp(-2.0 * safe)) / safe
    z = jnp.where(th >= 0, z_pos, -z_pos)
    return jnp.where(a < _THETA_EPS, u, jnp.clip(z, -1.0, 1.0))


def tilt_density_ratio(z: ArrayLike, theta: ArrayLike) -> Array:
    """q_theta(z) / (1/2): the tilted density over the uniform one at z in [-1, 1] (1 at theta = 0)."""
    z = jnp.asarray(z, dtype=float)
    th = jnp.asarray(theta, dtype=float)
    a = jnp.abs(th)
    safe = jnp.where(a < _THETA_EPS, 1.0, a)
    # theta e^(theta z) / sinh(theta) = 2 a e^(a (s z - 1)) / (1 - e^(-2 a)), s = sign(theta): no overflow
    s = jnp.where(th >= 0, 1.0, -1.0)
    ratio = 2.0 * safe * jnp.exp(safe * (s * z - 1.0)) / -jnp.expm1(-2.0 * safe)
    return jnp.where(a < _THETA_EPS, 1.0, ratio)


def tilt_log_density_ratio(z: ArrayLike, theta: ArrayLike) -> Array:
    """log prod_c q_theta_c(z_c) / (1/2): one tilted step's log density ratio, tilted over nominal;
    z, theta (..., k), summed over the last axis."""
    return jnp.sum(jnp.log(tilt_density_ratio(z, theta)), axis=-1)


def episode_log_lr(log_ratio: ArrayLike, defensive: ArrayLike) -> Array:
    """An episode's log(nominal / proposal) from the sum of its tilted steps' log density ratios:
    ``-log(defensive + (1 - defensive) e^log_ratio)``, at most ``-log(defensive)``; computed stably."""
    lr = jnp.asarray(log_ratio, dtype=float)
    return -jnp.logaddexp(jnp.log(defensive), jnp.log1p(-defensive) + lr)


def tilted_units(raw: ArrayLike, nominal: ArrayLike, theta: ArrayLike) -> tuple[Array, Array]:
    """One tilted step's units (3,) and their log density ratio (tilted over nominal). raw (3,): the
    step's own uniform units (:func:`mcverify.sim.noise.unit_draws`), used as they are in an episode the mixture drew as
    nominal (``nominal`` True), else mapped through the tilts' inverse CDFs; theta (3,)."""
    z = jnp.where(nominal, jnp.asarray(raw, dtype=float), tilted_unit(raw, theta))
    return z, tilt_log_density_ratio(z, theta)


def tilt_mean(theta: np.ndarray) -> np.ndarray:
    """E_q[z] = coth(theta) - 1/theta (the Langevin function), 0 at theta = 0; elementwise."""
    th = np.asarray(theta, dtype=float)
    small = np.abs(th) < 1e-4
    safe = np.where(small, 1.0, th)
    return np.where(small, th / 3.0, 1.0 / np.tanh(safe) - 1.0 / safe)


def tilt_for_mean(mean: np.ndarray, theta_max: float) -> np.ndarray:
    """The theta in [-theta_max, theta_max] whose tilt has this mean (inverse of :func:`tilt_mean`, by
    bisection; monotone), elementwise."""
    m = np.asarray(mean, dtype=float)
    lo, hi = np.full(m.shape, -float(theta_max)), np.full(m.shape, float(theta_max))
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        below = tilt_mean(mid) < m
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    return 0.5 * (lo + hi)


def refit_tilt(tilt: NoiseTilt, sums: np.ndarray, counts: np.ndarray, weights: np.ndarray,
               smoothing: float = 0.7) -> NoiseTilt:
    """The cross-entropy update of a tilt from the elite episodes: per band and unit, the weighted MLE
    of the exponential tilt, whose mean must equal the weighted mean of the drawn units,
    ``sum_i w_i S_ibc / sum_i w_i N_ib``; smoothed with the old theta; a band no elite episode was tilted
    in keeps its theta.

    sums: (m, 9) each episode's per-band sums of its tilted units (row-major (band, unit)); counts:
    (m, 3) its tilted steps per band; weights: (m,) the episodes' likelihood ratios (nominal over the
    proposal they were drawn from)."""
    w = np.asarray(weights, dtype=float)[:, None]
    n = np.repeat(np.asarray(counts, dtype=float), len(TILT_UNITS), axis=1)  # (m, 9)
    total = np.sum(w * n, axis=0)
    mean = np.divide(np.sum(w * np.asarray(sums, dtype=float), axis=0), total, out=np.zeros(total.shape),
                     where=total > 0)
    old = np.asarray(tilt.theta, dtype=float)
    fitted = tilt_for_mean(np.clip(mean, -0.999, 0.999), tilt.theta_max)
    theta = np.where(total > 0, smoothing * fitted + (1.0 - smoothing) * old, old)
    return tilt._replace(theta=tuple(float(t) for t in theta))
