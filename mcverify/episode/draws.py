"""An episode's random inputs: its root key, its scheduled noise branches and its scenario draws
(the registry :data:`mcverify.draws.DRAWS`, each from its own stream of the episode key)."""

from __future__ import annotations

import math
import statistics

import jax

from mcverify.draws import DRAWS, SCENARIO_STREAM, Draw
from mcverify.model import normal_masses

__all__ = ["SCENARIO_STREAM", "episode_key", "noise_branches", "sample_scenario", "truncated_normal",
           "value_of_unit"]

Array = jax.Array


def episode_key(seed: int, cell_index: int | None, episode_id: int, key_seed: int = -1) -> Array:
    """The root key of one episode: (seed, cell, episode id), or (seed, episode id) for common
    random numbers across cells (paired comparisons); with ``key_seed`` >= 0 (``noise.key_seed``)
    (key_seed, episode id) whatever the campaign seed and cell."""
    if key_seed >= 0:
        return jax.random.fold_in(jax.random.PRNGKey(key_seed), episode_id)
    key = jax.random.PRNGKey(seed)
    if cell_index is not None:
        key = jax.random.fold_in(key, cell_index)
    return jax.random.fold_in(key, episode_id)


def noise_branches(params) -> dict[int, int]:
    """``noise.branch_after_steps`` / ``noise.branch_ids`` as {control step: branch id}: after that
    step the episode's noise comes from that branch of its root key
    (:func:`mcverify.episode.snapshot.branch_key`)."""
    n = params.noise
    return {int(s): int(b) for s, b in zip(n.branch_after_steps, n.branch_ids, strict=True)}


def sample_scenario(key: Array, params) -> dict[str, float]:
    """Per-episode scenario values drawn from the episode key, each draw of :data:`~mcverify.draws.DRAWS`
    from its own stream: uniform in (lo, hi] of its range (the paper's Table III ranges are left-open),
    a truncated normal where its ``sd_field`` is > 0, its fixed value without a range, NaN where the cell
    does not draw it (no veh_o; no spawn gap or delay with ``opposing.spawn = "start"``)."""
    return {d.name: _draw(key, d, params) if d.applies(params) else math.nan for d in DRAWS}


def _draw(key: Array, draw: Draw, params) -> float:
    """The draw's value from its stream of ``key`` (:func:`value_of_unit`)."""
    if not draw.range_of(params):
        return draw.fixed(params)
    unit = float(jax.random.uniform(jax.random.fold_in(key, SCENARIO_STREAM + draw.stream), (), dtype=float))  # [0, 1)
    return value_of_unit(draw, params, unit)


def value_of_unit(draw: Draw, params, unit: float) -> float:
    """The draw's value for a uniform ``unit`` in [0, 1): uniform in (lo, hi] of its range; its fixed value
    without a range. With a standard deviation > 0: a normal around the fixed value truncated to the range
    (:func:`truncated_normal`), from the same unit. Any unit law in [0, 1) other than the uniform (subset
    simulation's Phi of a normal, a proposal's) goes through here, so the transform is the rollout's own."""
    rng, fixed, sd = draw.range_of(params), draw.fixed(params), draw.sd(params)
    if not rng:
        return fixed
    lo, hi = rng
    if sd > 0:
        return truncated_normal(1.0 - unit, fixed, sd, float(lo), float(hi))
    return float(hi - (hi - lo) * unit)


def truncated_normal(u: float, mean: float, sd: float, lo: float, hi: float) -> float:
    """The ``u``-quantile (0 < u <= 1) of a normal (``mean``, ``sd``) truncated to [lo, hi], by inverting its
    distribution function. The upper tail is inverted through the survival function, so a value 4-8 sd
    above the mean keeps its precision (where a rare event of the scenario lives)."""
    norm = statistics.NormalDist(mean, sd)
    below, mass, above = normal_masses(mean, sd, lo, hi)
    tail = (1.0 - u) * mass  # the probability above the value, within the range
    if tail + above <= 0.0:  # u = 1 (or a range beyond the normal's double precision): the top
        return hi
    if tail + above < 0.5:  # upper half: invert the survival function (by symmetry)
        x = 2.0 * mean - norm.inv_cdf(tail + above)
    else:
        x = norm.inv_cdf(min(max(below + u * mass, 1e-300), 1.0 - 1e-16))
    return min(max(x, lo), hi)
