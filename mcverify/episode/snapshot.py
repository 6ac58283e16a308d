"""Episode snapshots and branches: the full state of one episode after a control step, restored exactly.

A snapshot (:class:`EpisodeSnapshot`) holds everything the closed loop carries from one control step
to the next for one episode: the plant state and its running safety trace, the noise root key in
use, the host-side planner memory (:class:`~mcverify.control.episode_state.EpisodeState`: mode, warm
starts, the held plan, the infeasibility memo, counters), the lane-entry time of the spawn rule, the
last applied input, the settling memory and end state, and the step counter. Restoring it with the
same key and continuing gives exactly the uninterrupted episode (tests/episode/test_snapshot.py).

A *branch* restores a snapshot and continues with fresh noise: its root key is
``fold_in(fold_in(episode key, BRANCH_STREAM), branch_id)``, so the noise at every later step is a
pure function of (episode key, branch id, step) (:func:`mcverify.sim.noise.step_key`), and a branch
replays bit for bit. Without branching the episode's key, and so today's noise, is untouched.

:class:`Branching` is what :func:`mcverify.episode.rollout.run_episodes` takes to start from a
snapshot, take snapshots, and report the running score after every step (for splitting).
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import jax
import numpy as np

from mcverify.control.episode_state import EpisodeState
from mcverify.sim.lanes import LaneGroups
from mcverify.sim.plant import Plant, SafetyTrace

#: fold_in stream of branch keys (apart from the per-step noise streams and the scenario stream).
BRANCH_STREAM = 2_000_000


def branch_key(episode_key: np.ndarray, branch_id: int) -> np.ndarray:
    """The root key of branch ``branch_id`` of the episode with root key ``episode_key``."""
    key = jax.random.fold_in(jax.random.fold_in(np.asarray(episode_key), BRANCH_STREAM), int(branch_id))
    return np.array(key)


@dataclass(frozen=True)
class EpisodeSnapshot:
    """One episode's full state right after control step ``step`` (host copies; see the module
    docstring). ``episode_key``: the episode's own root key; ``key``: the root key in use (the
    episode's, or a branch's)."""

    episode_id: int
    step: int
    plant: Plant
    trace: SafetyTrace
    episode_key: np.ndarray
    key: np.ndarray
    state: EpisodeState
    entered_s: float
    u_last: np.ndarray
    settling: Any  # the rollout's settling memory, or None
    end: Any  # the rollout's EndState once decided, or None

    def score_min_h_front(self) -> float:
        return float(self.trace.min_h_front)


class StepView(NamedTuple):
    """What a :class:`Branching` callback sees after control step ``step``: the episode's running
    safety trace, the planner's count so far of steps at which neither Q1 nor Q2 was solved, and the
    current run of such steps (0 after a step at which one was solved)."""

    step: int
    trace: SafetyTrace
    both_infeasible_steps: int
    both_infeasible_run: int = 0


@dataclass
class Branching:
    """Controls of a one-episode run: ``start`` (restore this snapshot, continue after its step),
    ``branch_id`` (continue with this branch's noise; None: the snapshot's key, i.e. the same noise),
    ``keep(view)`` (take a snapshot after this step?), ``stop(view)`` (end the episode after this
    step, e.g. once a splitting score reached its failure level?), each given the step's
    :class:`StepView`. Filled by the run: ``views`` (a :class:`StepView` after every step it
    simulated), ``snapshots`` (step -> snapshot), ``steps`` (control steps simulated) and
    ``stopped`` (``stop`` ended it)."""

    start: EpisodeSnapshot | None = None
    branch_id: int | None = None
    keep: Callable[[StepView], bool] | None = None
    stop: Callable[[StepView], bool] | None = None
    views: list[StepView] = field(default_factory=list)
    snapshots: dict[int, EpisodeSnapshot] = field(default_factory=dict)
    steps: int = 0
    stopped: bool = False

    def first_step(self) -> int:
        return 0 if self.start is None else self.start.step + 1

    def capture(self, step: int, world: LaneGroups, episode_key: np.ndarray, state: EpisodeState, entered_s: float,
                u_last: np.ndarray, settling: Any, end: Any) -> EpisodeSnapshot:
        plant, trace, key = world.lane_state(0)
        return EpisodeSnapshot(state.episode_id, step, plant, trace, np.array(episode_key), key, copy.deepcopy(state),
                               float(entered_s), np.array(u_last), copy.deepcopy(settling), copy.deepcopy(end))

    def after_step(self, step: int, world: LaneGroups, episode_key: np.ndarray, state: EpisodeState,
                   entered_s: float, u_last: np.ndarray, settling: Any, end: Any) -> None:
        self.steps += 1
        view = StepView(step, world.lane_state(0)[1], int(state.both_infeasible_steps), int(state.both_infeasible_run))
        self.views.append(view)
        if self.keep is not None and self.keep(view):
            self.snapshots[step] = self.capture(step, world, episode_key, state, entered_s, u_last, settling, end)
        self.stopped = self.stop is not None and bool(self.stop(view))

    def restore(self, world: LaneGroups) -> tuple[EpisodeState, float, np.ndarray, Any, Any]:
        """Put the start snapshot into ``world`` (lane 0, with the branch's key when branching) and
        return copies of its host memory: (state, entered_s, u_last, settling, end)."""
        snap = self.start
        assert snap is not None
        key = snap.key if self.branch_id is None else branch_key(snap.episode_key, self.branch_id)
        world.set_lane_state(0, snap.plant, snap.trace, key)
        return (copy.deepcopy(snap.state), snap.entered_s, np.array(snap.u_last), copy.deepcopy(snap.settling),
                copy.deepcopy(snap.end))
