"""Low-dimensional parametrisations of the perception error, and the random baselines.

Each parametrisation is a small frozen dataclass with a ``dimension`` d and a map
``schedule(theta) -> ErrorInput`` (:mod:`mcverify.sim.schedule`), for population searches (CMA-ES,
cross-entropy) over theta:

* :class:`GapBands`: theta in [-1, 1]^d, a constant unit per chosen channel in each band of veh_f's
  footprint gap (alongside, jump, approach). The band depends on the gap at run time, which depends on
  the errors already applied, so this maps to the feedback form
  :class:`~mcverify.sim.schedule.GapBandSchedule`, evaluated in the plant at every step (a fixed schedule
  in time could not follow the gap); the rollout returns the realised time schedule for storage.
* :class:`Windows`: theta in [-1, 1]^d, short windows (start step, length, a unit per chosen channel),
  each start within its own range of steps, e.g. around the lane entry and the decision instant of the
  cell (:meth:`Windows.around`); 0 outside the windows.
* :class:`BangBang`: theta in R^d, units in {-1, +1} (the sign of theta, +1 at 0) per chosen channel on
  equal segments of the episode.
* :class:`FullSequence`: theta in [-1, 1]^d, the whole per-step sequence (sequential search, subset
  simulation after :func:`~mcverify.sim.schedule.units_from_normals`).

:func:`parametrisation` builds the one a campaign's ``[falsify.adversary]`` table names
(:class:`~mcverify.campaign.search_space.AdversarySpec`) for its episode's control steps.

Box parametrisations clip theta to [-1, 1] (a search that steps outside the box stays valid); a theta
of the wrong length or with a NaN is a ``ValueError``. Channels not chosen stay 0 (exact). Baselines:
:func:`random_uniform` and :func:`random_bang_bang`, deterministic from a seed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from mcverify.campaign.search_space import AdversarySpec
from mcverify.model import Simulation
from mcverify.sim.schedule import BANDS, CHANNELS, ErrorSchedule, GapBandSchedule, control_steps

#: veh_f's footprint gap (m) below which the far noise becomes the near one in the paper's model; the
#: bands' default edges: alongside within it, jump up to the noise tilt's split (3 m), approach up to 15 m.
DEFAULT_BAND_EDGES_M: tuple[float, float, float] = (2.0, 3.0, 15.0)


def _channel_columns(channels: Sequence[str]) -> list[int]:
    unknown = [c for c in channels if c not in CHANNELS]
    if unknown or not channels or len(set(channels)) != len(channels):
        raise ValueError(f"channels must be distinct names among {', '.join(CHANNELS)}, got {list(channels)}")
    return [CHANNELS.index(c) for c in channels]


def _theta(theta: object, dimension: int, *, box: bool) -> np.ndarray:
    t = np.asarray(theta, dtype=float).reshape(-1)
    if t.size != dimension or np.isnan(t).any():
        raise ValueError(f"theta must be {dimension} numbers (no NaN), got {t.size}")
    return np.clip(t, -1.0, 1.0) if box else t


def _to_step(t: float, lo: int, hi: int) -> int:
    """[-1, 1] -> an integer in [lo, hi], evenly."""
    return lo + min(int(math.floor((t + 1.0) / 2.0 * (hi - lo + 1))), hi - lo)


@dataclass(frozen=True)
class GapBands:
    """A constant unit per channel in each of the :data:`~mcverify.sim.schedule.BANDS` of veh_f's gap;
    theta row-major (band, channel)."""

    channels: tuple[str, ...] = CHANNELS
    edges_m: tuple[float, float, float] = DEFAULT_BAND_EDGES_M
    front_share: float = 1.0
    opp_share: float = 1.0

    @property
    def dimension(self) -> int:
        return len(BANDS) * len(self.channels)

    def schedule(self, theta: object) -> GapBandSchedule:
        units = np.zeros((len(BANDS), len(CHANNELS)))
        units[:, _channel_columns(self.channels)] = _theta(theta, self.dimension, box=True).reshape(len(BANDS), -1)
        return GapBandSchedule.of(units, self.edges_m, self.front_share, self.opp_share)


@dataclass(frozen=True)
class Windows:
    """Short windows of constant units: per window, theta = [start, length, unit per channel]; window w
    starts in ``start_ranges[w]`` (control steps, inclusive) and lasts 1 to ``max_steps`` steps; a later
    window overrides an earlier one where they overlap; 0 elsewhere."""

    steps: int
    start_ranges: tuple[tuple[int, int], ...]
    max_steps: int = 10
    channels: tuple[str, ...] = CHANNELS
    front_share: float = 1.0
    opp_share: float = 1.0

    @classmethod
    def around(cls, steps: int, centres_s: Sequence[float], half_width_s: float, control_period_s: float,
               **kw) -> Windows:
        """One window per centre (s; e.g. a nominal episode's lane entry and decision instant), its start
        within ``half_width_s`` of it."""
        def clamp(k: float) -> int:
            return max(0, min(int(round(k)), steps - 1))
        ranges = tuple((clamp((c - half_width_s) / control_period_s), clamp((c + half_width_s) / control_period_s))
                       for c in centres_s)
        return cls(steps, ranges, **kw)

    @property
    def dimension(self) -> int:
        return len(self.start_ranges) * (2 + len(self.channels))

    def schedule(self, theta: object) -> ErrorSchedule:
        cols = _channel_columns(self.channels)
        t = _theta(theta, self.dimension, box=True).reshape(len(self.start_ranges), -1)
        units = np.zeros((self.steps, len(CHANNELS)))
        for (lo, hi), w in zip(self.start_ranges, t, strict=True):
            start = _to_step(w[0], lo, hi)
            length = _to_step(w[1], 1, self.max_steps)
            units[start:start + length, cols] = w[2:]
        return ErrorSchedule.of(units, self.front_share, self.opp_share)


@dataclass(frozen=True)
class BangBang:
    """Units in {-1, +1} per chosen channel on ``segments`` equal segments of ``steps`` control steps;
    theta in R^d row-major (segment, channel), its sign taken (+1 at 0)."""

    steps: int
    segments: int
    channels: tuple[str, ...] = CHANNELS
    front_share: float = 1.0
    opp_share: float = 1.0

    @property
    def dimension(self) -> int:
        return self.segments * len(self.channels)

    def schedule(self, theta: object) -> ErrorSchedule:
        signs = np.where(_theta(theta, self.dimension, box=False) >= 0, 1.0, -1.0).reshape(self.segments, -1)
        return ErrorSchedule.of(_segments(signs, self.steps, _channel_columns(self.channels)), self.front_share,
                                self.opp_share)


@dataclass(frozen=True)
class FullSequence:
    """Every step's unit for the chosen channels; theta row-major (step, channel)."""

    steps: int
    channels: tuple[str, ...] = CHANNELS
    front_share: float = 1.0
    opp_share: float = 1.0

    @property
    def dimension(self) -> int:
        return self.steps * len(self.channels)

    def schedule(self, theta: object) -> ErrorSchedule:
        units = np.zeros((self.steps, len(CHANNELS)))
        units[:, _channel_columns(self.channels)] = _theta(theta, self.dimension, box=True).reshape(self.steps, -1)
        return ErrorSchedule.of(units, self.front_share, self.opp_share)


def _segments(values: np.ndarray, steps: int, cols: list[int]) -> np.ndarray:
    """(steps, 5) units: row k of ``values`` (segments, len(cols)) on steps [k steps / S, (k + 1) steps / S)."""
    segments = values.shape[0]
    which = np.minimum(np.arange(steps) * segments // steps, segments - 1)
    units = np.zeros((steps, len(CHANNELS)))
    units[:, cols] = values[which]
    return units


def random_uniform(steps: int, seed: int, channels: tuple[str, ...] = CHANNELS, front_share: float = 1.0,
                   opp_share: float = 1.0) -> ErrorSchedule:
    """The baseline: independent uniform units in [-1, 1] at every step, from ``numpy`` with ``seed``."""
    cols = _channel_columns(channels)
    units = np.zeros((steps, len(CHANNELS)))
    units[:, cols] = np.random.default_rng(seed).uniform(-1.0, 1.0, (steps, len(cols)))
    return ErrorSchedule.of(units, front_share, opp_share)


def random_bang_bang(steps: int, segments: int, seed: int, channels: tuple[str, ...] = CHANNELS,
                     front_share: float = 1.0, opp_share: float = 1.0) -> ErrorSchedule:
    """The bang-bang baseline: a fair random sign per segment and channel, from ``numpy`` with ``seed``."""
    theta = np.random.default_rng(seed).choice([-1.0, 1.0], size=segments * len(channels))
    return BangBang(steps, segments, channels, front_share, opp_share).schedule(theta)


#: A parametrisation of the perception error: ``dimension`` and ``schedule(theta)``.
Parametrisation = GapBands | Windows | BangBang | FullSequence


def parametrisation(spec: AdversarySpec, sim: Simulation) -> Parametrisation:
    """The parametrisation ``spec`` names, for episodes of ``sim`` (its control steps and period)."""
    steps = control_steps(sim)
    common = {"channels": spec.channels or CHANNELS, "front_share": spec.front_share, "opp_share": spec.opp_share}
    if spec.kind == "gap_bands":
        return GapBands(edges_m=tuple(spec.edges_m), **common)  # type: ignore[arg-type]
    if spec.kind == "windows":
        return Windows.around(steps, spec.centres_s, spec.half_width_s, sim.control_period_s,
                              max_steps=spec.max_steps, **common)
    if spec.kind == "bang_bang":
        return BangBang(steps, spec.segments, **common)
    if spec.kind == "full":
        return FullSequence(steps, **common)
    raise ValueError(f"unknown adversary kind {spec.kind!r}")


def theta_of_unit(u: object) -> np.ndarray:
    """A search's unit-cube coordinates to theta in [-1, 1] (``2 u - 1``; for :class:`BangBang`, u >= 1/2 is +1)."""
    return 2.0 * np.asarray(u, dtype=float) - 1.0
