"""Perception noise of the paper's Sec. VI-A and the per-step random keys that drive it.

Key discipline: every draw is a pure function of (episode key, step index, stream), obtained with
``jax.random.fold_in`` (:func:`step_key`). It never depends on which other episodes share a
batch, on the batch size, or on how many draws earlier steps made, so replaying one episode alone
reproduces its noise exactly. Streams separate independent uses within a step (e.g. stream 0 for
the front vehicle's measurement); callers own the stream numbering.
"""

from __future__ import annotations

from typing import NamedTuple, TypeAlias

import jax
import jax.numpy as jnp

from mcverify.model import MAX_SEGMENTS, Noise
from mcverify.sim.tilt import TILT_BANDS, TILT_UNITS, NoiseTilt

#: The noise tilt of importance sampling lives in :mod:`mcverify.sim.tilt`; these names stay importable
#: from here for the command line's ``--noise-tilt``.
__all__ = ["NOISE_KINDS", "TILT_BANDS", "TILT_UNITS", "Disturbance", "LateralDisturbance", "NoiseBounds", "NoiseParams",
           "NoiseTilt", "gap_segment_offset", "lateral_offset", "measure", "measure_vehicle", "segment_offset",
           "step_key", "structured_offsets", "unit_draws"]

Array: TypeAlias = jax.Array
ArrayLike: TypeAlias = jax.typing.ArrayLike

#: The noise models :func:`measure_vehicle` knows.
NOISE_KINDS: tuple[str, ...] = ("paper", "none")


def step_key(episode_key: Array, step_index: ArrayLike, stream: ArrayLike) -> Array:
    """The key for draw ``stream`` at control step ``step_index`` of one episode.

    ``fold_in(fold_in(episode_key, stream), step_index)``: a pure function of its three
    arguments (each may be traced), independent of batch composition.

    Args:
        episode_key: the episode's root PRNG key (as from ``jax.random.PRNGKey``/``fold_in``).
        step_index: control step, integer scalar >= 0.
        stream: which independent use within the step, integer scalar >= 0.
    """
    return jax.random.fold_in(jax.random.fold_in(episode_key, stream), step_index)


class NoiseBounds(NamedTuple):
    """The paper's noise bounds (Sec. VI-A) as runtime numbers of :func:`measure`: position half-widths
    beyond and within ``near_threshold_m`` of footprint gap (m), the speed half-width relative to the true
    speed, and ``scale`` on all three (0 for the kind "none": the true values)."""

    pos_far_m: ArrayLike
    pos_near_m: ArrayLike
    near_threshold_m: ArrayLike
    speed_rel: ArrayLike
    scale: ArrayLike

    @classmethod
    def of(cls, noise: Noise) -> NoiseBounds:
        return cls(noise.pos_far_m, noise.pos_near_m, noise.near_threshold_m, noise.speed_rel,
                   noise.scale if noise.kind == "paper" else 0.0)


class Disturbance(NamedTuple):
    """One vehicle's structured disturbance of its measured x and speed (:class:`~mcverify.model.Noise`):
    ``bias_drift`` (4,) [x bias, x drift (1/s), v bias, v drift (1/s)]; ``segments`` (2, MAX_SEGMENTS) the
    piecewise-constant offsets of [x, speed], zero padded (one array shape, one compiled plant, whatever
    the number K of segments); ``segment_counts`` (2,) the K of each (0: none)."""

    bias_drift: ArrayLike
    segments: ArrayLike
    segment_counts: ArrayLike

    def offsets(self, t_s: ArrayLike, episode_s: ArrayLike) -> tuple[Array, Array]:
        """s(t) for x and speed at episode time ``t_s`` (:func:`structured_offsets`)."""
        return structured_offsets(self.bias_drift, t_s, self.segments, self.segment_counts, episode_s)


class LateralDisturbance(NamedTuple):
    """veh_f's structured lateral disturbance: ``bias_drift`` (2,) [y bias, y drift (1/s)], ``segments``
    (MAX_SEGMENTS,) time offsets and ``gap_segments`` (MAX_SEGMENTS,) offsets by footprint gap band, zero
    padded, with their counts, and ``gap_window_m`` (m) the gap the bands divide."""

    bias_drift: ArrayLike
    segments: ArrayLike
    segment_count: ArrayLike
    gap_segments: ArrayLike
    gap_segment_count: ArrayLike
    gap_window_m: ArrayLike

    def offset(self, t_s: ArrayLike, gap_m: ArrayLike, episode_s: ArrayLike) -> Array:
        """s_y at episode time ``t_s`` and veh_f's true footprint gap ``gap_m`` (:func:`lateral_offset`)."""
        return lateral_offset(self.bias_drift, t_s, gap_m, self.segments, self.segment_count, self.gap_segments,
                              self.gap_segment_count, self.gap_window_m, episode_s)


class NoiseParams(NamedTuple):
    """The noise model of :class:`~mcverify.model.Noise` as one pytree of runtime numbers (traced, not
    compiled in: one compiled plant serves every noise of a campaign): the bounds, the share of the x
    and speed errors taken by each vehicle's structured disturbance, veh_f's lateral share and
    disturbance, and the episode duration ``episode_s`` (s) that the time segments divide."""

    bounds: NoiseBounds
    share: ArrayLike
    front: Disturbance
    opp: Disturbance
    lateral_share: ArrayLike
    lateral: LateralDisturbance
    episode_s: ArrayLike

    @classmethod
    def of(cls, noise: Noise, episode_s: float) -> NoiseParams:
        """The runtime numbers of ``noise`` (float arrays) for episodes of ``episode_s`` seconds."""
        f = lambda v: jnp.asarray(v, dtype=float)  # noqa: E731

        def vehicle(x_bias, x_drift, v_bias, v_drift, x_segments, v_segments) -> Disturbance:
            return Disturbance(f([x_bias, x_drift, v_bias, v_drift]),
                               f([_pad_segments(x_segments), _pad_segments(v_segments)]),
                               f([float(len(x_segments)), float(len(v_segments))]))

        n = noise
        return cls(
            bounds=NoiseBounds(*(f(v) for v in NoiseBounds.of(n))),
            share=f(n.structured_share),
            front=vehicle(n.front_x_bias, n.front_x_drift_per_s, n.front_v_bias, n.front_v_drift_per_s,
                          n.front_x_segments, n.front_v_segments),
            opp=vehicle(n.opp_x_bias, n.opp_x_drift_per_s, n.opp_v_bias, n.opp_v_drift_per_s,
                        n.opp_x_segments, n.opp_v_segments),
            lateral_share=f(n.lateral_share),
            lateral=LateralDisturbance(f([n.front_y_bias, n.front_y_drift_per_s]), f(_pad_segments(n.front_y_segments)),
                                       f(float(len(n.front_y_segments))), f(_pad_segments(n.front_y_gap_segments)),
                                       f(float(len(n.front_y_gap_segments))), f(n.front_y_gap_window_m)),
            episode_s=f(episode_s),
        )


def measure_vehicle(
    key: Array,
    true_x_m: ArrayLike,
    true_y_m: ArrayLike,
    true_speed_mps: ArrayLike,
    gap_m: ArrayLike,
    noise: Noise,
) -> tuple[Array, Array, Array]:
    """What the planner measures of another vehicle (paper Sec. VI-A).

    kind "paper": x and y each get independent uniform noise in +-pos_far_m when ``gap_m`` (the
    footprint gap to that vehicle, m) exceeds ``near_threshold_m``, else +-pos_near_m; the speed
    gets uniform noise in +-speed_rel * |true speed|. ``noise.scale`` multiplies all three
    half-widths. kind "none": the true values, exactly.

    Args:
        key: this draw's key (see :func:`step_key`).
        true_x_m, true_y_m, true_speed_mps, gap_m: scalars (m, m, m/s, m).
        noise: the noise model; static (the kind selects the code path at trace time).

    Returns:
        (x_m, y_m, speed_mps) measured, scalars.

    Raises:
        ValueError: for a kind not in :data:`NOISE_KINDS`.
    """
    if noise.kind not in NOISE_KINDS:
        raise ValueError(f"unknown noise kind {noise.kind!r}; valid kinds: {', '.join(NOISE_KINDS)}")
    if noise.kind == "none":
        x, y, v = (jnp.asarray(a, dtype=float) for a in (true_x_m, true_y_m, true_speed_mps))
        return x, y, v
    return measure(key, true_x_m, true_y_m, true_speed_mps, gap_m, NoiseBounds.of(noise))


def _pad_segments(values: tuple[float, ...]) -> list[float]:
    """Segment values zero padded to MAX_SEGMENTS (one array shape, one compiled plant)."""
    return [*values, *([0.0] * (MAX_SEGMENTS - len(values)))]


def gap_segment_offset(values: ArrayLike, count: ArrayLike, gap_m: ArrayLike, window_m: ArrayLike) -> Array:
    """The offset by footprint gap: ``values[j]`` while ``gap_m`` lies in the j-th of ``count`` equal bands
    of [0, window_m] (band 0 the nearest; a gap below 0, overlap, counts as band 0), 0 beyond the window
    or when ``count`` is 0. values: (MAX_SEGMENTS,); count, gap_m (m), window_m (m): scalars."""
    j = jnp.clip(jnp.floor(gap_m / window_m * count), 0.0, jnp.maximum(count - 1.0, 0.0)).astype(jnp.int32)
    return jnp.where((count > 0) & (gap_m <= window_m), jnp.asarray(values, dtype=float)[j], 0.0)


def lateral_offset(
    disturbance: ArrayLike,
    t_s: ArrayLike,
    gap_m: ArrayLike,
    segments: ArrayLike,
    segment_count: ArrayLike,
    gap_segments: ArrayLike,
    gap_segment_count: ArrayLike,
    gap_window_m: ArrayLike,
    episode_s: ArrayLike,
) -> Array:
    """s_y for veh_f's measured y: ``clip(bias + drift * t + offset(t) + gap_offset(gap), -1, 1)``.
    disturbance (2,) [bias, drift (1/s)] as in :class:`LateralDisturbance`; t_s, episode_s (s); gap_m: veh_f's
    true footprint gap (m); the time offsets as :func:`segment_offset`, the gap offsets as
    :func:`gap_segment_offset`."""
    d = jnp.asarray(disturbance, dtype=float)
    raw = (d[0] + d[1] * t_s + segment_offset(segments, segment_count, t_s, episode_s)
           + gap_segment_offset(gap_segments, gap_segment_count, gap_m, gap_window_m))
    return jnp.clip(raw, -1.0, 1.0)


def segment_offset(values: ArrayLike, count: ArrayLike, t_s: ArrayLike, episode_s: ArrayLike) -> Array:
    """The piecewise-constant offset at episode time ``t_s``: ``values[k]`` on the k-th of ``count``
    equal segments of [0, episode_s] (the last one closed), 0 when ``count`` is 0.
    values: (MAX_SEGMENTS,); count, t_s (s), episode_s (s): scalars."""
    k = jnp.clip(jnp.floor(t_s / episode_s * count), 0.0, jnp.maximum(count - 1.0, 0.0)).astype(jnp.int32)
    return jnp.where(count > 0, jnp.asarray(values, dtype=float)[k], 0.0)


def structured_offsets(
    disturbance: ArrayLike,
    t_s: ArrayLike,
    segments: ArrayLike | None = None,
    counts: ArrayLike | None = None,
    episode_s: ArrayLike = 1.0,
) -> tuple[Array, Array]:
    """s(t) for x and speed: ``clip(bias + drift * t + offset(t), -1, 1)``; disturbance (4,) as in
    :class:`Disturbance`, t_s the episode time (s); segments (2, MAX_SEGMENTS) and counts (2,)
    as there over the episode duration ``episode_s`` (s), or None for none.
    Without segments (count 0) the sum is not formed at all, so s(t) is bit for bit the old one."""
    d = jnp.asarray(disturbance, dtype=float)
    raw = [d[0] + d[1] * t_s, d[2] + d[3] * t_s]
    if segments is not None and counts is not None:
        seg, cnt = jnp.asarray(segments, dtype=float), jnp.asarray(counts, dtype=float)
        raw = [jnp.where(cnt[i] > 0, r + segment_offset(seg[i], cnt[i], t_s, episode_s), r) for i, r in enumerate(raw)]
    return jnp.clip(raw[0], -1.0, 1.0), jnp.clip(raw[1], -1.0, 1.0)


def unit_draws(key: Array) -> Array:
    """The step's three uniform units in [-1, 1] for [x, y, speed] (what :func:`measure` scales)."""
    return jax.random.uniform(key, (3,), dtype=float, minval=-1.0, maxval=1.0)


def measure(
    key: Array,
    true_x_m: ArrayLike,
    true_y_m: ArrayLike,
    true_speed_mps: ArrayLike,
    gap_m: ArrayLike,
    bounds: NoiseBounds,
    *,
    share: ArrayLike = 0.0,
    x_offset: ArrayLike = 0.0,
    v_offset: ArrayLike = 0.0,
    unit: ArrayLike | None = None,
    y_share: ArrayLike = 0.0,
    y_offset: ArrayLike = 0.0,
) -> tuple[Array, Array, Array]:
    """The paper's noise model with every number a runtime argument (traced, not compiled in): the
    half-widths of ``bounds``.

    Same draws as :func:`measure_vehicle` with kind "paper"; ``scale`` 0 returns the true values
    exactly (x + 0.0). One compiled plant then serves every noise level of a campaign.
    ``share`` of the x and speed errors is taken by the structured offsets ``x_offset``,
    ``v_offset`` in [-1, 1] (:func:`structured_offsets`); with share 0 the draws are used as before,
    bit for bit ((1 - 0) * u + 0 * s == u). ``unit`` (3,) in [-1, 1]: the draws to use instead of
    the key's (a noise tilt's, :func:`tilted_units`); None: the key's. ``y_share`` of the y error is
    taken by ``y_offset`` in [-1, 1] (:func:`lateral_offset`) the same way; with ``y_share`` 0, y is as
    before, bit for bit.
    """
    x = jnp.asarray(true_x_m, dtype=float)
    y = jnp.asarray(true_y_m, dtype=float)
    v = jnp.asarray(true_speed_mps, dtype=float)
    if unit is None:
        unit = unit_draws(key)
    pos_half_m = bounds.scale * jnp.where(gap_m > bounds.near_threshold_m, bounds.pos_far_m, bounds.pos_near_m)
    speed_half_mps = bounds.scale * bounds.speed_rel * jnp.abs(v)
    wx = (1.0 - share) * unit[0] + share * x_offset
    wv = (1.0 - share) * unit[2] + share * v_offset
    wy = (1.0 - y_share) * unit[1] + y_share * y_offset
    return x + pos_half_m * wx, y + pos_half_m * wy, v + speed_half_mps * wv
