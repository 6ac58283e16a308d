"""Perception noise of the paper's Sec. VI-A and the per-step random keys that drive it.

Key discipline: every draw is a pure function of (episode key, step index, stream), obtained with
``jax.random.fold_in`` (:func:`step_key`). It never depends on which other episodes share a
batch, on the batch size, or on how many draws earlier steps made, so replaying one episode alone
reproduces its noise exactly. Streams separate independent uses within a step (e.g. stream 0 for
the front vehicle's measurement); callers own the stream numbering.
"""

from __future__ import annotations

from typing import TypeAlias

import jax
import jax.numpy as jnp

from mcverify.model import MAX_SEGMENTS, Noise

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
    return measure(key, true_x_m, true_y_m, true_speed_mps, gap_m, **noise_arrays(noise))


def noise_arrays(noise: Noise) -> dict[str, float]:
    """The noise model as runtime numbers for :func:`measure` ("none" is scale 0)."""
    return {
        "pos_far_m": noise.pos_far_m,
        "pos_near_m": noise.pos_near_m,
        "near_threshold_m": noise.near_threshold_m,
        "speed_rel": noise.speed_rel,
        "scale": noise.scale if noise.kind == "paper" else 0.0,
    }


def disturbance_arrays(noise: Noise) -> dict[str, list[float]]:
    """The structured disturbance per vehicle as [x bias, x drift (1/s), v bias, v drift (1/s)]."""
    return {
        "front": [noise.front_x_bias, noise.front_x_drift_per_s, noise.front_v_bias, noise.front_v_drift_per_s],
        "opp": [noise.opp_x_bias, noise.opp_x_drift_per_s, noise.opp_v_bias, noise.opp_v_drift_per_s],
    }


def segment_arrays(noise: Noise) -> dict[str, tuple[list[list[float]], list[float]]]:
    """The piecewise-constant offsets per vehicle: (values (2, MAX_SEGMENTS) for [x, speed], zero
    padded; counts (2,) the number K of segments of each, 0 for none). Padding keeps one array shape
    (one compiled plant) whatever K."""
    def pad(v: tuple[float, ...]) -> list[float]:
        return [*v, *([0.0] * (MAX_SEGMENTS - len(v)))]

    return {
        "front": ([pad(noise.front_x_segments), pad(noise.front_v_segments)],
                  [float(len(noise.front_x_segments)), float(len(noise.front_v_segments))]),
        "opp": ([pad(noise.opp_x_segments), pad(noise.opp_v_segments)],
                [float(len(noise.opp_x_segments)), float(len(noise.opp_v_segments))]),
    }


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
    :func:`disturbance_arrays`, t_s the episode time (s); segments (2, MAX_SEGMENTS) and counts (2,)
    as in :func:`segment_arrays` over the episode duration ``episode_s`` (s), or None for none.
    Without segments (count 0) the sum is not formed at all, so s(t) is bit for bit the old one."""
    d = jnp.asarray(disturbance, dtype=float)
    raw = [d[0] + d[1] * t_s, d[2] + d[3] * t_s]
    if segments is not None and counts is not None:
        seg, cnt = jnp.asarray(segments, dtype=float), jnp.asarray(counts, dtype=float)
        raw = [jnp.where(cnt[i] > 0, r + segment_offset(seg[i], cnt[i], t_s, episode_s), r) for i, r in enumerate(raw)]
    return jnp.clip(raw[0], -1.0, 1.0), jnp.clip(raw[1], -1.0, 1.0)


def measure(
    key: Array,
    true_x_m: ArrayLike,
    true_y_m: ArrayLike,
    true_speed_mps: ArrayLike,
    gap_m: ArrayLike,
    *,
    pos_far_m: ArrayLike,
    pos_near_m: ArrayLike,
    near_threshold_m: ArrayLike,
    speed_rel: ArrayLike,
    scale: ArrayLike,
    share: ArrayLike = 0.0,
    x_offset: ArrayLike = 0.0,
    v_offset: ArrayLike = 0.0,
) -> tuple[Array, Array, Array]:
    """The paper's noise model with every number a runtime argument (traced, not compiled in).

    Same draws as :func:`measure_vehicle` with kind "paper"; ``scale`` 0 returns the true values
    exactly (x + 0.0). One compiled plant then serves every noise level of a campaign.
    ``share`` of the x and speed errors is taken by the structured offsets ``x_offset``,
    ``v_offset`` in [-1, 1] (:func:`structured_offsets`); with share 0 the draws are used as before,
    bit for bit ((1 - 0) * u + 0 * s == u).
    """
    x = jnp.asarray(true_x_m, dtype=float)
    y = jnp.asarray(true_y_m, dtype=float)
    v = jnp.asarray(true_speed_mps, dtype=float)
    unit = jax.random.uniform(key, (3,), dtype=float, minval=-1.0, maxval=1.0)
    pos_half_m = scale * jnp.where(gap_m > near_threshold_m, pos_far_m, pos_near_m)
    speed_half_mps = scale * speed_rel * jnp.abs(v)
    wx = (1.0 - share) * unit[0] + share * x_offset
    wv = (1.0 - share) * unit[2] + share * v_offset
    return x + pos_half_m * wx, y + pos_half_m * unit[1], v + speed_half_mps * wv
