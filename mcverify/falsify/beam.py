"""Sequential search over the per-step perception error: a beam search that branches from episode snapshots.

Adaptive-stress-testing style (issue 49): the adversary acts only in a window of control steps ``[first, last)``
(e.g. around the lane entry and the decision), cut into segments of ``segment_steps``. The episode runs once,
exactly measured, up to the window and is snapshotted (:mod:`mcverify.episode.snapshot`). At each depth every
frontier node gets ``branching`` children, each a draw of the next segment's units (bang-bang signs, signs held
through the segment, or uniform values per chosen channel, from a generator keyed by (seed, restart, depth,
parent rank, child)); a child restores its parent's snapshot and simulates only its own segment, so a node costs
its own control steps. The root has ``max(branching, width)`` children so that the first frontier is full: with
``branching = 1`` the beam is ``width`` independent random schedules sharing the prefix (the random-schedule
baseline at the beam's cost). The ``width`` children with the lowest running score (:data:`SCORES`) form the next
frontier; the others' snapshots are dropped as soon as they fall out, so at most ``2 width + 1`` snapshots are
alive (the old frontier and the new). After the last segment the frontier nodes run, in rank order, to the end of
their episodes with exact measurement, and their rows' robustness of the requirement decides. The best node
always runs; the others run while the caller's allowance of control steps (the budget left) covers another run to
the time limit, so a beam's cost bound (:meth:`BeamSpec.cost_bound`) counts one such run, not ``width`` (episodes
usually end at the goal long before the limit, and a bound that counts every node would leave room for fewer
restarts). The best node's whole schedule (zeros outside the window) is written into an ordinary run folder
(:func:`mcverify.falsify.adversary.run_folder`), re-simulated from step 0, whose episode ``mcverify replay``
re-simulates bit for bit.

A requirement that is a running minimum (:data:`DECIDED_IN_PREFIX`: ``ellipse``, ``collision_front``,
``collision_opp``, ``safe``, ``theorem5_certified``) is violated for good once a node's prefix violates it, so
such a child ends the search at once: it runs to the end of its episode and is the counterexample, and the cost
to it is the search's cost so far (a beam judged only after its last depth would spend the rest for nothing).

Every cost is in control steps simulated. Resume: after each depth the frontier (units, end steps,
scores) and the cost so far go to ``FOLDER/depth-NNN.npz``; a resumed search re-simulates each stored
frontier node from step 0 to rebuild its snapshot (counted apart, as ``rebuild_steps``), checks that the
score comes out equal, and goes on, so it ends exactly where an uninterrupted search ends.

The command line, ``mcverify falsify CAMPAIGN --method beam``, reads the spec from the campaign's
``[falsify.beam]`` table (:mod:`mcverify.campaign.beam_table`, times in seconds: :func:`spec_of`) and writes
the folder, the best run and the report (:mod:`mcverify.falsify.beam_folder`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from mcverify import store
from mcverify.analysis import robustness as rb
from mcverify.campaign import executors
from mcverify.campaign.beam_table import SCORES, UNITS, BeamShape, BeamTable
from mcverify.campaign.spec import Campaign
from mcverify.episode.rollout import run_episodes
from mcverify.episode.snapshot import Branching, EpisodeSnapshot
from mcverify.errors import RunError
from mcverify.files import atomic_write, write_json_atomic
from mcverify.model import Simulation
from mcverify.sim.schedule import CHANNELS, ErrorSchedule, control_steps

__all__ = ["BEAM", "SCORES", "UNITS", "BeamResult", "BeamShape", "BeamSpec", "search", "spec_of", "write_best"]

BEAM = "beam"
FORMAT = 1


@dataclass(frozen=True)
class BeamSpec:
    """What defines a beam search (module docstring); ``first_step``/``last_step`` bound the window
    [first, last) in control steps."""

    first_step: int
    last_step: int
    segment_steps: int
    shape: BeamShape  # branching, width, channels, units, score, shares: as the table gives them
    requirement: str
    seed: int = 0
    restart: int = 0  # a new draw of every child under the same seed (mcverify.falsify.beam_folder's restarts)

    def check(self, steps: int) -> None:
        """ValueError (one line) for a spec that does not fit an episode of ``steps`` control steps."""
        if not 0 <= self.first_step < self.last_step <= steps:
            raise ValueError(f"beam window [{self.first_step}, {self.last_step}) must lie in [0, {steps}) steps")
        shape = self.shape
        if self.segment_steps < 1 or shape.branching < 1 or shape.width < 1:
            raise ValueError("beam segment_steps, branching and width must be positive")
        if shape.units not in UNITS or shape.score not in SCORES:
            raise ValueError(f"beam units must be one of {UNITS} and score one of {SCORES}")
        if not shape.channels or any(c not in CHANNELS for c in shape.channels):
            raise ValueError(f"beam channels must be names among {', '.join(CHANNELS)}")

    @property
    def depths(self) -> int:
        return math.ceil((self.last_step - self.first_step) / self.segment_steps)

    def children_per_depth(self) -> list[int]:
        """Children simulated at each depth when no episode ends inside the window (an ended node is carried
        without children, so these are upper bounds): the root's :attr:`root_children`, then ``branching`` per
        frontier node."""
        out = [self.root_children]
        for _ in range(1, self.depths):
            out.append(min(self.shape.width, out[-1]) * self.shape.branching)
        return out

    @property
    def root_children(self) -> int:
        """The root fills the first frontier: ``max(branching, width)`` children."""
        return max(self.shape.branching, self.shape.width)

    def segment_lengths(self) -> list[int]:
        """Control steps of each depth's segment (the last one may be shorter)."""
        starts = range(self.first_step, self.last_step, self.segment_steps)
        return [min(a + self.segment_steps, self.last_step) - a for a in starts]

    def cost_bound(self, steps: int) -> int:
        """Most control steps the search can simulate on an episode of ``steps`` control steps when its allowance
        is this bound: the prefix up to the window, every child's segment, and the best final node run to the
        time limit (the other final nodes run only within a larger allowance; episodes that end earlier, at the
        goal or inside the window, cost less). A resume's rebuilding is apart."""
        children = self.children_per_depth()
        segments = sum(n * k for n, k in zip(children, self.segment_lengths(), strict=True))
        return self.first_step + segments + self.tail_steps(steps)

    def tail_steps(self, steps: int) -> int:
        """Control steps from the window's end to the time limit: the most one final node's run can cost."""
        return steps - self.last_step

    def to_json(self) -> dict[str, Any]:
        """The flat dict ``beam.json`` and ``result.json`` keep: the shape's fields inline, in the key order
        written before :class:`BeamShape` existed, so stored folders compare and re-read unchanged."""
        shape = {**asdict(self.shape), "channels": list(self.shape.channels)}
        return {"first_step": self.first_step, "last_step": self.last_step, "segment_steps": self.segment_steps,
                "branching": shape.pop("branching"), "width": shape.pop("width"), "requirement": self.requirement,
                **shape, "seed": self.seed, "restart": self.restart}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> BeamSpec:
        """The spec of a flat dict from :meth:`to_json`."""
        names = {f.name for f in fields(BeamShape)}
        shape = BeamShape(**{**{k: v for k, v in data.items() if k in names}, "channels": tuple(data["channels"])})
        return cls(**{k: v for k, v in data.items() if k not in names}, shape=shape)


def spec_of(table: BeamTable, requirement: str, seed: int, sim: Simulation) -> BeamSpec:
    """The spec of a ``[falsify.beam]`` table on an episode of ``sim``: times rounded to the nearest control
    step; ValueError (one line) for a window outside the episode or a segment shorter than half a step."""
    period_s = sim.control_period_s

    def step(t_s: float) -> int:
        return int(math.floor(t_s / period_s + 0.5))

    a, b = table.window_s
    if b > sim.max_time_s + 1e-9:
        raise ValueError(f"[falsify.beam] window_s = [{a:g}, {b:g}] s must lie in the episode, [0, "
                         f"{sim.max_time_s:g}] s (sim.max_time_s)")
    if step(b) <= step(a):
        raise ValueError(f"[falsify.beam] window_s = [{a:g}, {b:g}] s holds no control step of "
                         f"{period_s:g} s")
    if step(table.segment_s) < 1:
        raise ValueError(f"[falsify.beam] segment_s = {table.segment_s:g} s rounds to no control step "
                         f"({period_s:g} s each)")
    spec = BeamSpec(step(a), min(step(b), control_steps(sim)), step(table.segment_s), table.shape, requirement, seed)
    spec.check(control_steps(sim))
    return spec


def _ellipse_crossed(s: EpisodeSnapshot) -> bool:
    return float(s.trace.min_h_front) < 0.0


#: Requirements whose violation a snapshot already decides (running minima over the episode: once violated
#: in a prefix, violated for the whole episode), and how to read it from the snapshot.
DECIDED_IN_PREFIX: dict[str, Callable[[EpisodeSnapshot], bool]] = {
    "ellipse": _ellipse_crossed,
    "collision_front": lambda s: bool(s.trace.collision_front),
    "collision_opp": lambda s: bool(s.trace.collision_opp),
    "safe": lambda s: any(DECIDED_IN_PREFIX[name](s) for name in rb.SAFE_SET),  # the members of the row's safe
    "theorem5_certified": lambda s: s.state.both_certified_infeasible_steps > 0,
}


@dataclass
class Node:
    """A partial schedule: ``units`` (steps, 5), simulated to ``end_step`` (inclusive), with its running
    ``score``; ``snapshot`` after end_step (None once dropped or when the episode already ended)."""

    units: np.ndarray
    end_step: int
    score: float
    snapshot: EpisodeSnapshot | None = None
    row: dict[str, Any] | None = None  # the final row, once the episode has ended


@dataclass
class BeamResult:
    """The finished search: the final frontier (rows and robustness), the best node, and its cost."""

    spec: BeamSpec
    frontier: list[Node]
    robustness: list[float]
    search_steps: int  # control steps the search simulated (prefix, segments, finishes)
    rebuild_steps: int  # control steps a resume spent rebuilding snapshots
    full_episode_steps: int
    peak_snapshots: int
    depth_log: list[dict[str, float]] = field(default_factory=list)
    stopped_at_depth: int | None = None  # a child of this depth violated the requirement in its segment

    @property
    def best(self) -> int:
        return int(np.nanargmin(self.robustness))

    @property
    def min_robustness(self) -> float:
        return float(np.nanmin(self.robustness))

    @property
    def episode_equivalents(self) -> float:
        return self.search_steps / self.full_episode_steps


class _Loop:
    """One episode of a campaign's target cell run in pieces (seed = the campaign's, episode 0)."""

    def __init__(self, campaign: Campaign, spec: BeamSpec) -> None:
        self.cell, self.seed, self.spec = campaign.cells[0], campaign.seed, spec
        self.steps = control_steps(self.cell.params.sim)
        self.planner = executors.solver_for(self.cell.params)

    def run(self, units: np.ndarray, start: EpisodeSnapshot | None, until: int | None) -> tuple[Node, int]:
        """Simulate from ``start`` (None: step 0) to step ``until`` (inclusive; None: the episode's end) under
        ``units``; the node and the control steps it cost."""
        if until is None:
            branching = Branching(start=start)
        else:
            branching = Branching(start=start, keep=lambda v: v.step == until, stop=lambda v: v.step == until)
        schedule = ErrorSchedule.of(units, self.spec.shape.front_share, self.spec.shape.opp_share)
        result = run_episodes(self.cell, [0], self.seed, self.planner, branching=branching, schedules=[schedule])
        snap = None if until is None else branching.snapshots.get(until)
        row = result.rows[0] if snap is None else None
        end = until if snap is not None else branching.first_step() + branching.steps - 1
        return Node(units, end, self._score(snap, row), snap, row), branching.steps

    def _score(self, snap: EpisodeSnapshot | None, row: dict[str, Any] | None) -> float:
        return running_score(self.spec.shape.score, running_row(snap) if snap is not None else row)


def running_row(snap: EpisodeSnapshot) -> dict[str, Any]:
    """The row columns a score reads, as they stand after the snapshot's step (running minima and flags). veh_o's
    gap is +inf until veh_o exists, so an episode without veh_o never ranks on it; ``opposing_kind`` is any value
    but "none" so that the robustness reads that gap rather than assuming no veh_o."""
    tr = snap.trace
    return {"min_h_front": float(tr.min_h_front), "theorem5_margin": float(snap.state.theorem5_margin),
            "min_gap_front_m": float(tr.min_gap_front_m), "collision_front": bool(tr.collision_front),
            "min_gap_opp_any_m": float(tr.min_gap_opp_any_m), "collision_opp": bool(tr.collision_opp),
            "opposing_kind": "running"}


def running_score(score: str, row: dict[str, Any]) -> float:
    """A node's rank (lower ranks first) under ``score`` (:data:`SCORES`): h_ef's running minimum, the lowest
    Theorem 5 margin (+inf before any dual-planner step), or ``safe``'s robustness (veh_f's and veh_o's gaps in
    h_ef's unit beside h_ef, :data:`mcverify.analysis.robustness.SAFE_GAP_SCALE_M`)."""
    if score == "safe":
        value = rb.ROBUSTNESS["safe"](row)
    else:
        value = float(row["min_h_front" if score == "h_front" else "theorem5_margin"])
    return math.inf if math.isnan(value) else value


def _children(spec: BeamSpec, node: Node, depth: int, rank: int, cols: list[int]) -> list[np.ndarray]:
    a = spec.first_step + depth * spec.segment_steps
    b = min(a + spec.segment_steps, spec.last_step)
    out = []
    for j in range(spec.root_children if depth == 0 else spec.shape.branching):
        rng = np.random.default_rng([spec.seed, spec.restart, depth, rank, j])
        size = (b - a, len(cols))
        if spec.shape.units == "held":
            seg = np.repeat(rng.choice([-1.0, 1.0], size=(1, len(cols))), b - a, axis=0)
        elif spec.shape.units == "bang_bang":
            seg = rng.choice([-1.0, 1.0], size=size)
        else:
            seg = rng.uniform(-1.0, 1.0, size)
        units = node.units.copy()
        units[a:b, cols] = seg
        out.append(units)
    return out


def search(campaign: Campaign, spec: BeamSpec, folder: Path, *, allowance_steps: int | None = None,
           stop_after_depths: int | None = None, progress: Callable[[str], None] | None = None) -> BeamResult:
    """Run (or resume, from the depth files in ``folder``) the beam search of ``spec`` on ``campaign``'s
    target; ``allowance_steps``: the control steps it may spend (None: no limit beyond every final node's
    run; the caller checks that it covers :meth:`BeamSpec.cost_bound`); ``stop_after_depths``: raise RunError
    after that many new depths (a test's interruption)."""
    loop = _Loop(campaign, spec)
    try:
        spec.check(loop.steps)
    except ValueError as exc:
        raise RunError(str(exc)) from None
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    _check_config(folder, spec)
    cols = [CHANNELS.index(c) for c in spec.shape.channels]
    depth, frontier, cost, rebuild, log = _restore(loop, folder, spec)
    peak = len(frontier)
    if depth == 0:
        zeros = np.zeros((loop.steps, len(CHANNELS)))
        if spec.first_step == 0:
            root, cost = Node(zeros, -1, math.inf), 0
        else:
            root, cost = loop.run(zeros, None, spec.first_step - 1)
        frontier = [root]
    new = 0
    while depth < spec.depths:
        if stop_after_depths is not None and new >= stop_after_depths:
            raise RunError(f"beam search stopped after {new} depth(s) (test hook); resume {folder}")
        kept: list[tuple[float, int, Node]] = []
        order = 0
        last = min(spec.first_step + (depth + 1) * spec.segment_steps, spec.last_step) - 1
        for rank, node in enumerate(frontier):
            if node.row is not None:  # the episode already ended: carried as it is
                kept.append((node.score, order, node))
                order += 1
                continue
            for units in _children(spec, node, depth, rank, cols):
                child, steps = loop.run(units, node.snapshot, last)
                cost += steps
                if _violated(child, spec.requirement):
                    return _stopped(loop, spec, child, cost, rebuild, peak, log, depth + 1)
                kept.append((child.score, order, child))
                order += 1
                kept.sort(key=lambda t: (t[0], t[1]))
                for _, _, dropped in kept[spec.shape.width:]:
                    dropped.snapshot = None  # memory: only the frontier keeps its snapshot
                kept = kept[:spec.shape.width]
                peak = max(peak, len(frontier) + len(kept) + 1)
        frontier = [n for _, _, n in kept]
        depth += 1
        new += 1
        log.append({"depth": depth, "best_score": frontier[0].score, "control_steps": cost})
        _save(folder, depth, frontier, cost, log)
        if progress is not None:
            progress(f"beam depth {depth}/{spec.depths}: best {spec.shape.score} {frontier[0].score:.4g}, "
                     f"{cost} control steps")
    frontier, cost = _finish(loop, spec, frontier, cost, allowance_steps)
    robs = [rb.robustness(n.row, spec.requirement) for n in frontier]
    return BeamResult(spec, frontier, robs, cost, rebuild, loop.steps, peak, log)


def _finish(loop: _Loop, spec: BeamSpec, frontier: list[Node], cost: int,
            allowance_steps: int | None) -> tuple[list[Node], int]:
    """The final frontier's episodes run to their ends (exactly measured after the window), in rank order: the
    best always, each other while ``allowance_steps`` covers another run to the time limit; the nodes run and
    the cost after them."""
    done: list[Node] = []
    for rank, node in enumerate(frontier):
        if node.row is None:
            if rank and allowance_steps is not None and cost + spec.tail_steps(loop.steps) > allowance_steps:
                break
            finished, steps = loop.run(node.units, node.snapshot, None)
            node.row, node.snapshot = finished.row, None
            cost += steps
        done.append(node)
    return done, cost


def _violated(node: Node, requirement: str) -> bool:
    """Whether ``node`` already violates ``requirement`` for good: its episode ended violating it, or its
    prefix decides it (:data:`DECIDED_IN_PREFIX`)."""
    if node.row is not None:
        return rb.robustness(node.row, requirement) < 0.0
    decided = DECIDED_IN_PREFIX.get(requirement)
    return decided is not None and node.snapshot is not None and decided(node.snapshot)


def _stopped(loop: _Loop, spec: BeamSpec, node: Node, cost: int, rebuild: int, peak: int,
             log: list[dict[str, float]], depth: int) -> BeamResult:
    """The search ended by ``node``, a violation found at ``depth``: the node run to its episode's end."""
    if node.row is None:
        finished, steps = loop.run(node.units, node.snapshot, None)
        node.row, node.snapshot = finished.row, None
        cost += steps
    log = [*log, {"depth": depth, "best_score": node.score, "control_steps": cost}]
    return BeamResult(spec, [node], [rb.robustness(node.row, spec.requirement)], cost, rebuild, loop.steps, peak, log,
                      stopped_at_depth=depth)


def write_best(campaign: Campaign, units: np.ndarray, spec: BeamSpec, run_dir: Path) -> Path:
    """A node's whole schedule ``units`` (a frontier node's, e.g. the best: ``result.frontier[result.best].units``)
    as a one-episode run folder (re-simulated from step 0), which ``mcverify replay RUN_DIR 0`` re-simulates bit
    for bit; returns the folder."""
    from mcverify.falsify import adversary  # noqa: PLC0415 - the run layer only when writing

    if sum(c.episodes for c in campaign.cells) != 1:
        raise RunError("the beam's best schedule is written as one episode: give a one-episode target campaign")
    schedule = ErrorSchedule.of(units, spec.shape.front_share, spec.shape.opp_share)
    adversary.run_folder(campaign, {0: schedule}, Path(run_dir))
    return Path(run_dir)


def _check_config(folder: Path, spec: BeamSpec) -> None:
    path = folder / "beam.json"
    recorded = {**spec.to_json(), "format": FORMAT}
    if path.is_file():
        if store.read_json(path) != recorded:
            raise RunError(f"{folder}: holds a beam search of another specification; choose another folder")
        return
    write_json_atomic(path, recorded)


def _save(folder: Path, depth: int, frontier: list[Node], cost: int, log: list[dict[str, float]]) -> None:
    def write(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            np.savez(fh, units=np.stack([n.units for n in frontier]), end_step=np.array([n.end_step for n in frontier]),
                     score=np.array([n.score for n in frontier]), ended=np.array([n.row is not None for n in frontier]),
                     cost=np.array(cost), log=np.array(json.dumps(log)))
    atomic_write(folder / f"depth-{depth:03d}.npz", write)


def _restore(loop: _Loop, folder: Path, spec: BeamSpec) -> tuple[int, list[Node], int, int, list[dict[str, float]]]:
    """(depth, frontier with snapshots rebuilt, cost so far, rebuild cost, log) from the last depth file."""
    files = sorted(folder.glob("depth-[0-9][0-9][0-9].npz"))
    if not files:
        return 0, [], 0, 0, []
    with np.load(files[-1], allow_pickle=False) as data:
        units, ends, scores, ended = data["units"], data["end_step"], data["score"], data["ended"]
        cost, log = int(data["cost"]), json.loads(str(data["log"]))
    frontier, rebuild = [], 0
    for u, end, score, done in zip(units, ends, scores, ended, strict=True):
        node, steps = loop.run(u, None, None if done else int(end))
        rebuild += steps
        if node.score != score:
            raise RunError(f"{files[-1]}: a frontier node re-simulated to score {node.score!r}, stored {score!r}; "
                           "the folder was made by other code")
        frontier.append(node)
    return int(files[-1].stem.split("-")[1]), frontier, cost, rebuild, log
