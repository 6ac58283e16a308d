"""The real closed loop as a branching process for adaptive multilevel splitting.

A fresh particle is episode ``branch_id`` of the cell (its own scenario draw and perception noise);
a branch restores a snapshot of its parent (:mod:`mcverify.episode.snapshot`) after the step at
which the parent's score first exceeded the current level and continues with the noise of its own
branch id. Every particle therefore replays from (campaign seed, cell, episode id, branch id).

Scores (non-decreasing along an episode, the target event is score >= 0):

- ``"h_ef"``: minus the running minimum of h_ef; >= 0 means the ego c.g. reached the safety ellipse
  (target ``ellipse``, up to the measure-zero h_ef = 0);
- ``"gap"``: minus the running minimum footprint gap to veh_f and veh_o (gaps are 0 on contact);
  >= 0 means a collision (target ``collision``);
- ``"h_ef_held"``: the h_ef score brought forward by the planner's trouble. With m the running
  minimum of h_ef and B the steps so far at which neither Q1 nor Q2 was solved (the ego then holds
  its last plan), the score is -m c^B while m > 0 and -m once m <= 0, c = ``HELD_FACTOR`` (so it is
  >= 0 exactly at the ellipse event, as "h_ef"; target ``ellipse``). Why: on the validation cell
  (campaigns/rare_validation_10hz.toml, 1,416 crude episodes) the episodes that cross the ellipse
  are not the tail of the ordinary approach (their min h_ef is about -0.5, the others' about +0.38)
  but exactly those whose planner lost both problems for 4 steps or more (none of the 1,322 with 3
  or fewer did; 61 of the 68 with 5 or more did), from about 5 s; 35 % of the episodes have one
  such step, and of those with k steps 44-72 % go on to k + 1. The plain h_ef score reaches its levels at the
  closest approach (about 6.5-7 s), when the outcome is already decided, so its branches tie with
  their parent and most 4-particle runs go extinct. With c = 0.3 one more unsolved step outranks any
  difference in min h_ef between ordinary approaches (within a factor of about 1.3), so the levels
  climb the ladder of unsolved steps and branches restart where that ladder is climbed. Any such
  score keeps AMS unbiased (it is a function of the episode's state, which the branch restores);
  only the variance depends on it.
- ``"h_ef_run"``: as ``"h_ef_held"`` with the *current* run r of consecutive steps with neither
  problem solved in place of the count B of all of them: -m c^r while m > 0 (the running maximum
  over the steps is the path's score). Why: B never decreases, so an episode that had its trouble
  and recovered (a turn-back with runs of 3-4, B up to 11, no violation) keeps a score within 1e-6
  of 0 and AMS then clones it for dozens of levels that lead nowhere: 11 of 44 ``h_ef_held`` runs of
  20 particles went 100-154 iterations deep into such a trap and read p at 1e-4 to 3e-3 against the
  reference's 0.05 (the estimator stays unbiased, but its distribution is so skewed that a mean of
  44 runs reads 27 % low with a t interval that misses). In the reference the longest run, not B,
  decides the event: 1 violation in 80 episodes with a longest run of 3, 24 in 57 with 4, 34 in 39
  with 5; a run that ends takes its score back down to -m.
- ``"gap_run"``: the same construction on the footprint gap (target ``collision``): -g c^r while
  g > 0, g the running minimum footprint gap to veh_f and veh_o, r the current run; >= 0 exactly at
  a contact: the construction of ``"h_ef_run"`` for the collision target, for cells where the
  planner loses both problems for runs of steps (the 10 Hz cell at twice the paper's noise). Not yet
  shown to help: on the 10 Hz cell at the paper's noise and eps = 0.3 the planner had no such runs,
  and two 20-particle runs went extinct with either score (31-46 iterations, the clones tied at
  their parents' minimum gap, 0.15-0.97 m).

Cost: control steps simulated (settling steps included) and the CPU seconds of this process.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mcverify.analysis.robustness import RUN_FACTOR
from mcverify.cell import Cell
from mcverify.control.planner import Planner
from mcverify.episode.rollout import run_episodes
from mcverify.episode.snapshot import Branching, EpisodeSnapshot, StepView
from mcverify.requirements import H_EF_SCORES, SCORE_REGISTRY, SCORES

__all__ = ["H_EF_SCORES", "HELD_FACTOR", "SCORES", "BranchPoint", "ClosedLoopPath", "ClosedLoopProcess", "gap_score",
           "h_ef_score", "score_of"]

#: "h_ef_held", "h_ef_run": the factor on the remaining min h_ef per step with neither problem solved
#: (the falsifier's ``"<r>@run"`` guides use the same one).
HELD_FACTOR = RUN_FACTOR


def h_ef_score(score: str, min_h_front: float, unsolved_steps: int) -> float:
    """The ``"h_ef"``, ``"h_ef_held"`` or ``"h_ef_run"`` value of a running min h_ef and a number of
    steps with neither problem solved (all of them for ``h_ef_held``, the current run for
    ``h_ef_run``; see the module docstring); >= 0 exactly at the ellipse event."""
    m = float(min_h_front)
    if not SCORE_REGISTRY[score].unsolved or m <= 0.0:
        return -m
    return -m * HELD_FACTOR ** int(unsolved_steps)


def gap_score(score: str, min_gap_m: float, unsolved_run: int) -> float:
    """The ``"gap"`` or ``"gap_run"`` value of a running minimum footprint gap (m; inf when no gap was
    measured) and the current run of steps with neither problem solved; >= 0 exactly at a contact."""
    g = float(min_gap_m)
    if not np.isfinite(g):
        return -np.inf
    if not SCORE_REGISTRY[score].unsolved or g <= 0.0:
        return -g
    return -g * HELD_FACTOR ** int(unsolved_run)


def score_of(view: StepView, score: str) -> float:
    """The score of the state after one control step (see the module docstring); the path's score
    is its running maximum."""
    trace = view.trace
    if score in H_EF_SCORES:
        run = SCORE_REGISTRY[score].unsolved == "run"
        unsolved = view.both_infeasible_run if run else view.both_infeasible_steps
        return h_ef_score(score, trace.min_h_front, unsolved)
    gaps = [float(g) for g in (trace.min_gap_front_m, trace.min_gap_opp_any_m) if np.isfinite(g)]
    return gap_score(score, min(gaps) if gaps else np.inf, view.both_infeasible_run)


@dataclass(frozen=True)
class BranchPoint:
    """Where a branch starts: the parent's snapshot after ``snapshot.step``, its scores up to there and
    its earlier snapshots (a branch can be branched again before that step)."""

    snapshot: EpisodeSnapshot
    scores: np.ndarray
    snapshots: dict[int, EpisodeSnapshot]
    lineage: tuple[tuple[int, int], ...] = ()  # the parent's noise branches before the snapshot's step


@dataclass
class ClosedLoopPath:
    """A particle: running score after each control step from step 0, its snapshots at the steps
    where the score rose (inherited from the parent up to the branch step), its cost, and its
    noise lineage: (control step, branch id) pairs, after each of which its noise came from that
    branch of the episode key, which is what ``noise.branch_after_steps`` / ``noise.branch_ids``
    re-simulate from step 0."""

    episode_id: int
    scores: np.ndarray
    snapshots: dict[int, EpisodeSnapshot]
    steps: int
    cpu_s: float
    lineage: tuple[tuple[int, int], ...] = ()

    def snapshot(self, step: int) -> BranchPoint:
        return BranchPoint(self.snapshots[step], self.scores[: step + 1],
                           {s: v for s, v in self.snapshots.items() if s <= step},
                           tuple((s, b) for s, b in self.lineage if s < step))

    def replay_record(self) -> dict[str, Any]:
        """What re-simulates this particle as an ordinary episode (:mod:`mcverify.estimate.replay`): the
        episode id, its noise branches, and the running score after its last step, to check."""
        return {"episode_id": int(self.episode_id), "branch_after_steps": [s for s, _ in self.lineage],
                "branch_ids": [b for _, b in self.lineage], "end_step": int(self.scores.size - 1),
                "score": float(self.scores[-1])}


@dataclass
class ClosedLoopProcess:
    """Episodes of ``cell`` (seed ``seed``) run one at a time with ``planner``, scored by ``score``;
    ``cpu_s`` and ``steps`` add up the cost of every run."""

    cell: Cell
    seed: int
    planner: Planner
    score: str = "h_ef"
    cpu_s: float = 0.0
    steps: int = 0
    fresh_steps: list[int] = field(default_factory=list)  # control steps of each fresh (unbranched) episode

    def __post_init__(self) -> None:
        if self.score not in SCORES:
            raise ValueError(f"unknown score {self.score!r}; valid: {', '.join(SCORES)}")

    def run(self, start: BranchPoint | None, branch_id: int, stop_level: float) -> ClosedLoopPath:
        """A fresh episode ``branch_id`` (start None) or a branch from ``start`` with the noise of
        ``branch_id``. Ends the episode after the first step at which the score reaches ``stop_level``
        (the failure set is absorbing: the rest of the episode cannot change the estimate)."""
        def reached(view: StepView) -> bool:
            return score_of(view, self.score) >= stop_level

        if start is None:
            episode, prefix, snaps, lineage = int(branch_id), np.zeros(0), {}, ()
            branching = Branching(keep=self._rose(-np.inf), stop=reached)
        else:
            episode, prefix, snaps = start.snapshot.episode_id, start.scores, dict(start.snapshots)
            lineage = (*start.lineage, (int(start.snapshot.step), int(branch_id)))
            branching = Branching(start=start.snapshot, branch_id=int(branch_id), keep=self._rose(float(prefix[-1])),
                                  stop=reached)
        t0 = time.process_time()
        run_episodes(self.cell, [episode], self.seed, self.planner, branching=branching)
        cpu = time.process_time() - t0
        raw = np.array([score_of(view, self.score) for view in branching.views])
        scores = np.maximum.accumulate(np.concatenate([prefix, raw])) if raw.size or prefix.size else np.zeros(1)
        snaps.update(branching.snapshots)
        self.cpu_s += cpu
        self.steps += branching.steps
        if start is None:
            self.fresh_steps.append(branching.steps)
        return ClosedLoopPath(episode, scores, snaps, branching.steps, cpu, lineage)

    @staticmethod
    def _keep_rule(score: str, best: float):
        state = {"best": best}

        def keep(view: StepView) -> bool:
            value = score_of(view, score)
            if value > state["best"]:
                state["best"] = value
                return True
            return False

        return keep

    def _rose(self, best: float):
        """keep(step, trace): a snapshot after every step at which the running score rose above ``best``."""
        return self._keep_rule(self.score, best)
