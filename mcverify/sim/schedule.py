"""The perception error as an input (issue 49): an error schedule replaces the random measurement noise.

An episode run with a schedule draws nothing: at control step k the planner's measurement of each
other vehicle is

    measured = true + half_width * share * u_k[channel]

with ``u_k`` the step's units in [-1, 1] for the channels :data:`CHANNELS` (veh_f x, y, v; veh_o x, v),
``share`` the vehicle's share in [0, 1] (``front_share`` for veh_f's three channels, ``opp_share`` for
veh_o's two), and ``half_width`` exactly :func:`mcverify.sim.noise.measure`'s: position
``scale * pos_far_m`` beyond ``near_threshold_m`` of footprint gap to that vehicle, else
``scale * pos_near_m``; speed ``scale * speed_rel * |true speed|`` (``scale`` 0 for the noise kind "none":
then every schedule measures exactly). So share 0 keeps a vehicle exact, share 1 hands it to the
adversary, independently per vehicle; all-zero units are exact measurement. The structured
disturbances of :class:`~mcverify.model.Noise` (biases, drifts, segments, shares) are not applied: the
schedule is the whole error.

Two forms, one concept:

* :class:`ErrorSchedule`: units in time, (steps, 5). A step at or beyond ``steps`` measures exactly (unit
  0): a schedule shorter than the episode ends its adversary early, a longer one is cut. This is the form
  stored for replay and the one sequential search edits step by step.
* :class:`GapBandSchedule`: a feedback form, a constant unit per channel in each band of veh_f's true
  footprint gap (:data:`BANDS`, the noise tilt's bands: alongside, jump, approach); beyond the outermost
  edge, unit 0. The gap depends on the errors already applied, so it is evaluated inside the plant at each
  step; the units it applied come back as an :class:`ErrorSchedule` (the rollout's ``realised``), which
  re-simulates the same episode bit for bit (the same unit values enter the same operations).

Both are NamedTuples (JAX pytrees) of float64 numpy arrays, validated on construction by :meth:`of`
(one-line ``ValueError``).
"""

from __future__ import annotations

import math
from typing import NamedTuple, TypeAlias

import jax
import jax.numpy as jnp
import numpy as np

from mcverify.model import Simulation

#: The measured channels a schedule drives, in the column order of its units.
CHANNELS: tuple[str, ...] = ("front_x", "front_y", "front_v", "opp_x", "opp_v")
#: veh_f's channels (scaled by ``front_share``) and veh_o's (``opp_share``), as column indices.
FRONT_CHANNELS, OPP_CHANNELS = (0, 1, 2), (3, 4)
#: The bands of a :class:`GapBandSchedule` by veh_f's true footprint gap, nearest first: alongside
#: (gap <= edges_m[0]), jump (edges_m[0] < gap <= edges_m[1]), approach (edges_m[1] < gap <= edges_m[2]).
BANDS: tuple[str, ...] = ("alongside", "jump", "approach")

Array: TypeAlias = jax.Array


def control_steps(sim: Simulation) -> int:
    """Control steps of an episode (the rollout's ``ceil(max_time_s / control_period_s)``)."""
    return int(math.ceil(sim.max_time_s / sim.control_period_s - 1e-9))


def _share(value: float, name: str) -> float:
    try:
        share = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"error schedule: {name} must be a number in [0, 1], got {value!r}") from None
    if not 0.0 <= share <= 1.0:  # NaN fails too
        raise ValueError(f"error schedule: {name} must lie in [0, 1], got {share!r}")
    return share


def _units(units: object, shape_text: str, rows: int | None) -> np.ndarray:
    """Units as a float64 array of shape (rows or any >= 1, 5), finite, in [-1, 1]; else ValueError."""
    try:
        arr = np.array(units, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"error schedule: units must be numbers of shape {shape_text}") from None
    wrong_rows = arr.ndim == 2 and (arr.shape[0] < 1 or (rows is not None and arr.shape[0] != rows))
    if arr.ndim != 2 or arr.shape[1] != len(CHANNELS) or wrong_rows:
        raise ValueError(f"error schedule: units must have shape {shape_text} (channels {', '.join(CHANNELS)}), "
                         f"got {arr.shape}")
    bad = ~np.isfinite(arr)
    if bad.any():
        step, ch = (int(i) for i in np.argwhere(bad)[0])
        raise ValueError(f"error schedule: unit {CHANNELS[ch]} at row {step} is {float(arr[step, ch])!r}, "
                         "not a number in [-1, 1]")
    out = np.abs(arr) > 1.0
    if out.any():
        step, ch = (int(i) for i in np.argwhere(out)[0])
        raise ValueError(f"error schedule: unit {CHANNELS[ch]} at row {step} is {float(arr[step, ch])!r}, "
                         "outside [-1, 1]")
    arr.setflags(write=False)
    return arr


class ErrorSchedule(NamedTuple):
    """Per-control-step units (steps, 5) in [-1, 1] for :data:`CHANNELS`, and each vehicle's share in
    [0, 1] (module docstring). Build it with :meth:`of` (validated); step ``k >= steps`` measures exactly."""

    units: np.ndarray
    front_share: float = 1.0
    opp_share: float = 1.0

    @classmethod
    def of(cls, units: object, front_share: float = 1.0, opp_share: float = 1.0) -> ErrorSchedule:
        """The validated schedule; ``ValueError`` (one line) for a wrong shape, a NaN or inf, a unit outside
        [-1, 1], or a share outside [0, 1]."""
        return cls(_units(units, "(steps >= 1, 5)", None), _share(front_share, "front_share"),
                   _share(opp_share, "opp_share"))

    @classmethod
    def exact(cls, steps: int) -> ErrorSchedule:
        """All-zero units: exact measurement of both vehicles."""
        return cls.of(np.zeros((max(int(steps), 1), len(CHANNELS))))

    @property
    def steps(self) -> int:
        return int(self.units.shape[0])

    def padded(self, steps: int) -> np.ndarray:
        """Units for steps 0 .. steps - 1: zero beyond this schedule's length, cut beyond ``steps``."""
        out = np.zeros((int(steps), len(CHANNELS)))
        n = min(self.steps, int(steps))
        out[:n] = self.units[:n]
        return out


class GapBandSchedule(NamedTuple):
    """A constant unit per channel in each band of veh_f's true footprint gap: ``units`` (3, 5), row b
    for :data:`BANDS` [b]; ``edges_m`` (3,) the bands' outer gaps (m), non-decreasing (beyond the last,
    unit 0); the shares as in :class:`ErrorSchedule`."""

    units: np.ndarray
    edges_m: np.ndarray
    front_share: float = 1.0
    opp_share: float = 1.0

    @classmethod
    def of(cls, units: object, edges_m: object, front_share: float = 1.0, opp_share: float = 1.0) -> GapBandSchedule:
        """The validated schedule; ``ValueError`` (one line) as :meth:`ErrorSchedule.of`, and for edges that
        are not three finite non-decreasing gaps (m)."""
        try:
            edges = np.array(edges_m, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError("gap-band schedule: edges_m must be three gaps (m)") from None
        if edges.shape != (len(BANDS),) or not np.isfinite(edges).all() or (np.diff(edges) < 0).any():
            raise ValueError(f"gap-band schedule: edges_m must be {len(BANDS)} finite non-decreasing gaps (m) for "
                             f"the bands {', '.join(BANDS)}, got {edges_m!r}")
        edges.setflags(write=False)
        return cls(_units(units, f"({len(BANDS)}, 5)", len(BANDS)), edges, _share(front_share, "front_share"),
                   _share(opp_share, "opp_share"))


#: What a rollout takes per episode: a schedule in time, or the feedback form by veh_f's gap.
ErrorInput: TypeAlias = ErrorSchedule | GapBandSchedule


class ScheduleStep(NamedTuple):
    """One step of one episode's error input as the plant's runtime numbers (batched by the lane
    groups): ``units`` (5,) the time schedule's units at this step; ``band_units`` (3, 5), ``edges_m``
    (3,) and ``banded`` () the gap-band form (used instead of ``units`` where ``banded``); ``shares``
    (2,) [front_share, opp_share]."""

    units: Array
    band_units: Array
    edges_m: Array
    banded: Array
    shares: Array


def step_units(step: ScheduleStep, gap_front_m: Array) -> Array:
    """The units (5,) applied at this step: the gap band's (0 beyond the outermost edge) or the time
    schedule's. Selected with ``where``, so the values are copied exactly (a realised schedule replays)."""
    band = jnp.where(gap_front_m <= step.edges_m[0], 0, jnp.where(gap_front_m <= step.edges_m[1], 1, 2))
    banded = jnp.where(gap_front_m <= step.edges_m[2], step.band_units[band], jnp.zeros(len(CHANNELS)))
    return jnp.where(step.banded, banded, step.units)


def units_from_normals(x: object) -> np.ndarray:
    """Standard normals to units in [-1, 1]: ``2 Phi(x) - 1 = erf(x / sqrt 2)`` (elementwise; for subset
    simulation, whose inputs are standard normals)."""
    return np.asarray(jax.scipy.special.erf(jnp.asarray(x, dtype=float) / math.sqrt(2.0)))
