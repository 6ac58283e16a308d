"""A batch of episodes on the compiled plant: fixed-width lane groups (host side).

Every call runs exactly one compiled executable of width :data:`~mcverify.sim.plant.LANES` (see
:mod:`mcverify.sim.plant` for why): :class:`LaneGroups` pads the batch, splits it into groups, and
gathers the results, so that an episode's numbers depend neither on the chunk size nor on its
position in the chunk.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mcverify.model import ModelParams
from mcverify.sim import schedule as schedule_mod
from mcverify.sim import tilt as tilt_mod
from mcverify.sim.plant import (
    LANES,
    Plant,
    SafetyTrace,
    Substep,
    compiled,
    compiled_scheduled,
    compiled_tilted,
    plant_params,
)

Array = jax.Array


class LaneGroups:
    """A batch of n episodes run as ceil(n / LANES) fixed-width groups (see the module docstring).

    Padding lanes repeat the last episode, are never active and are dropped from every output.
    """

    def __init__(self, plant: Plant, keys: Array, params: ModelParams, tilt: tilt_mod.NoiseTilt | None = None,
                 schedules: Sequence[schedule_mod.ErrorInput] | None = None) -> None:
        self.n = int(plant.t_s.shape[0])
        if schedules is not None and tilt is not None:
            raise ValueError("an error schedule replaces the random noise: it cannot be combined with a noise tilt")
        if schedules is not None and len(schedules) != self.n:
            raise ValueError(f"{len(schedules)} error schedules for {self.n} episodes: give one per episode")
        self.pp = plant_params(params)
        # a noise tilt (importance sampling) with an empty window is no tilt: the plain executable runs
        self.tilt = tilt.params() if tilt is not None and tilt.gap_max_m > 0 else None
        self.substeps = params.sim.substeps
        self._obs, self._adv, self._ini = compiled(self.substeps)
        pad = (-self.n) % LANES
        self.groups = math.ceil(self.n / LANES) if self.n else 0
        padded = jax.tree.map(lambda a: jnp.concatenate([a, jnp.repeat(a[-1:], pad, axis=0)]), plant)
        keys = jnp.concatenate([keys, jnp.repeat(keys[-1:], pad, axis=0)])
        split = lambda a: [a[g * LANES:(g + 1) * LANES] for g in range(self.groups)]  # noqa: E731
        self.plants = [jax.tree.map(lambda a, g=g: a[g * LANES:(g + 1) * LANES], padded) for g in range(self.groups)]
        self.keys = split(keys)
        self.traces = [self._ini(pl, self.pp) for pl in self.plants]
        self.schedule = None if schedules is None else _ScheduleTable.of(schedules, self.groups * LANES,
                                                                          schedule_mod.control_steps(params.sim))
        #: control step -> (n, 5) the units each episode's schedule applied there (error schedules only)
        self.applied: dict[int, np.ndarray] = {}

    def _gather(self, parts: list) -> np.ndarray:
        return np.concatenate([np.asarray(a) for a in parts])[: self.n]

    def ego(self) -> np.ndarray:
        """(n, 4) true ego states."""
        return self._gather([pl.ego for pl in self.plants])

    def observe(self, step: int, live: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Measured (front (n, 3), opp (n, 2)) at control step ``step``; ``live`` (n,) bool: the episodes
        that still use their measurements (read only under a noise tilt; default all)."""
        outs = self.observe_on_device(step, live)
        return self._gather([o[0] for o in outs]), self._gather([o[1] for o in outs])

    def observe_on_device(self, step: int, live: np.ndarray | None = None) -> list[tuple[Array, Array]]:
        """Per lane group, the (front, opp) measurements as JAX arrays, not yet copied to the host
        (under a noise tilt the plants' noise memory is updated too; under error schedules the units applied
        are kept in :attr:`applied`)."""
        if self.schedule is not None:
            return self._observe_scheduled(step)
        if self.tilt is None:
            return [self._obs(pl, k, jnp.asarray(step), self.pp) for pl, k in zip(self.plants, self.keys, strict=True)]
        live = np.ones(self.n, dtype=bool) if live is None else np.asarray(live, dtype=bool)
        live = np.concatenate([live, np.zeros(self.groups * LANES - self.n, dtype=bool)])
        outs = []
        for g in range(self.groups):
            front, opp, self.plants[g] = compiled_tilted()(self.plants[g], self.keys[g], jnp.asarray(step), self.pp,
                                                           self.tilt, jnp.asarray(live[g * LANES:(g + 1) * LANES]))
            outs.append((front, opp))
        return outs

    def _observe_scheduled(self, step: int) -> list[tuple[Array, Array]]:
        outs, applied = [], []
        for g in range(self.groups):
            front, opp, units = compiled_scheduled()(self.plants[g], self.keys[g], self.schedule.step(g, step), self.pp)
            outs.append((front, opp))
            applied.append(units)
        self.applied[step] = self._gather(applied)
        return outs

    def realised(self, b: int) -> schedule_mod.ErrorSchedule:
        """Episode ``b``'s error as an :class:`~mcverify.sim.schedule.ErrorSchedule` in time: the units it
        applied at every step observed so far (0 at steps not observed, e.g. before a restored snapshot),
        with its shares; re-simulates the episode bit for bit."""
        if self.schedule is None:
            raise ValueError("this batch runs without error schedules")
        last = max(self.applied, default=0)
        units = np.zeros((last + 1, len(schedule_mod.CHANNELS)))
        for k, u in self.applied.items():
            units[k] = u[b]
        return schedule_mod.ErrorSchedule.of(units, *(float(v) for v in self.schedule.shares[b]))

    def noise_log_lr(self) -> np.ndarray:
        """(n,) log(nominal / proposal) of each episode's noise so far (0 without a noise tilt)."""
        if self.tilt is None:
            return np.zeros(self.n)
        ratio = self._gather([pl.tilt_log_ratio for pl in self.plants])
        return np.asarray(tilt_mod.episode_log_lr(ratio, self.tilt.defensive))

    def tilt_statistics(self) -> tuple[np.ndarray, np.ndarray]:
        """((n, 9) sums of the tilted units per (band, unit), (n, 3) tilted steps per band)."""
        return self._gather([pl.tilt_sums for pl in self.plants]), self._gather([pl.tilt_counts for pl in self.plants])

    def advance(self, u: np.ndarray, active: np.ndarray) -> list[Substep]:
        """One control period for every episode; returns the per-group sub-step outputs."""
        pad = self.groups * LANES - self.n
        u = np.concatenate([u, np.zeros((pad, 2))])
        active = np.concatenate([active, np.zeros(pad, dtype=bool)])
        subs = []
        for g in range(self.groups):
            sl = slice(g * LANES, (g + 1) * LANES)
            self.plants[g], self.traces[g], sub = self._adv(
                self.plants[g], self.traces[g], jnp.asarray(u[sl]), jnp.asarray(active[sl]), self.pp
            )
            subs.append(sub)
        return subs

    def substeps_of(self, subs: list[Substep]) -> Substep:
        """Concatenate per-group sub-step outputs to (n, substeps, ...) numpy arrays."""
        return Substep(*(self._gather([getattr(s, f) for s in subs]) for f in Substep._fields))

    def place_opposing(self, b: int, x_m: float, v_mps: float) -> None:
        """Put veh_o of episode ``b`` at ``x_m`` with road-frame velocity ``v_mps`` (< 0: towards the
        ego) now, between two control periods (the spawn rule of ``opposing.spawn``)."""
        g, lane = divmod(b, LANES)
        pl = self.plants[g]
        self.plants[g] = pl._replace(opp=pl.opp.at[lane].set(jnp.array([x_m, v_mps], dtype=float)))

    def lane_state(self, b: int) -> tuple[Plant, SafetyTrace, np.ndarray]:
        """Episode ``b``'s plant state, running safety trace and noise root key, as host copies
        (a snapshot: :meth:`set_lane_state` puts them back exactly)."""
        g, lane = divmod(b, LANES)
        # the whole lane group to the host first, then numpy indexing: indexing the JAX array itself
        # dispatches one device op per field (about 0.25 ms each, 5 ms a control step for splitting's
        # per-step snapshots); np.array copies, so nothing views a device buffer
        take = lambda a: np.array(np.asarray(a)[lane])  # noqa: E731
        return (Plant(*(take(a) for a in self.plants[g])), SafetyTrace(*(take(a) for a in self.traces[g])),
                take(self.keys[g]))

    def set_lane_state(self, b: int, plant: Plant, trace: SafetyTrace, key: np.ndarray) -> None:
        """Overwrite episode ``b``'s plant state, safety trace and noise root key (restore a snapshot,
        or switch the noise of the steps to come to a branch's key)."""
        g, lane = divmod(b, LANES)

        def put(a: Array, v: np.ndarray) -> Array:  # on the host, then one transfer (no per-field device op)
            host = np.array(a)
            host[lane] = np.asarray(v, dtype=host.dtype)
            return jnp.asarray(host)

        self.plants[g] = Plant(*(put(a, v) for a, v in zip(self.plants[g], plant, strict=True)))
        self.traces[g] = SafetyTrace(*(put(a, v) for a, v in zip(self.traces[g], trace, strict=True)))
        self.keys[g] = put(self.keys[g], key)

    def set_lane_key(self, b: int, key: np.ndarray) -> None:
        """Switch episode ``b``'s noise root key for the steps to come (a scheduled noise branch)."""
        g, lane = divmod(b, LANES)
        self.keys[g] = self.keys[g].at[lane].set(jnp.asarray(key, dtype=self.keys[g].dtype))

    def trace(self) -> SafetyTrace:
        """(n,) final safety metrics as numpy arrays."""
        return SafetyTrace(*(self._gather([getattr(t, f) for t in self.traces]) for f in SafetyTrace._fields))


class _ScheduleTable(NamedTuple):
    """A padded batch's error inputs as host arrays (lanes first): time units (lanes, steps, 5), zero
    beyond each schedule; the gap-band form's units (lanes, 3, 5), edges (lanes, 3) and flag (lanes,);
    shares (lanes, 2). Padding lanes repeat the last episode's."""

    units: np.ndarray
    band_units: np.ndarray
    edges_m: np.ndarray
    banded: np.ndarray
    shares: np.ndarray

    @classmethod
    def of(cls, schedules: Sequence[schedule_mod.ErrorInput], lanes: int, steps: int) -> _ScheduleTable:
        full = [*schedules, *([schedules[-1]] * (lanes - len(schedules)))]
        c = len(schedule_mod.CHANNELS)
        units, band_units = np.zeros((lanes, steps, c)), np.zeros((lanes, len(schedule_mod.BANDS), c))
        edges, banded = np.zeros((lanes, len(schedule_mod.BANDS))), np.zeros(lanes, dtype=bool)
        for b, s in enumerate(full):
            if isinstance(s, (schedule_mod.ErrorSchedule, schedule_mod.GapBandSchedule)):
                s = type(s).of(*s)  # validated, also when built without ``of``
            if isinstance(s, schedule_mod.GapBandSchedule):
                band_units[b], edges[b], banded[b] = s.units, s.edges_m, True
            elif isinstance(s, schedule_mod.ErrorSchedule):
                units[b] = s.padded(steps)
            else:
                raise TypeError(f"episode {b}: an error schedule must be an ErrorSchedule or a GapBandSchedule, "
                                f"got {type(s).__name__}")
        shares = np.array([[s.front_share, s.opp_share] for s in full], dtype=float)
        return cls(units, band_units, edges, banded, shares)

    def step(self, group: int, step: int) -> schedule_mod.ScheduleStep:
        """Lane group ``group``'s runtime numbers at control step ``step`` (0 beyond the table)."""
        sl = slice(group * LANES, (group + 1) * LANES)
        units = self.units[sl, step] if step < self.units.shape[1] else np.zeros((LANES, self.units.shape[2]))
        return schedule_mod.ScheduleStep(jnp.asarray(units), jnp.asarray(self.band_units[sl]),
                                         jnp.asarray(self.edges_m[sl]), jnp.asarray(self.banded[sl]),
                                         jnp.asarray(self.shares[sl]))
