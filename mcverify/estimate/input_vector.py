"""A campaign cell's closed loop as a function of one vector of independent standard normals.

Subset simulation (:mod:`mcverify.estimate.subset`) needs every random input of an episode in one
vector x, each coordinate a standard normal. Here x is laid out as

- ``x[:s]``: the cell's random scenario draws (those of :data:`mcverify.draws.DRAWS` with a range),
  each turned into its value by the rollout's own transform of a uniform unit
  (:func:`mcverify.episode.draws.value_of_unit` of Phi(x_i));
- ``x[s + k * c + j]``: the perception error of control step k on measured channel j (veh_f x, y, v;
  and veh_o x, v where the cell has an opposing vehicle), the unit 2 Phi(x) - 1 in [-1, 1] of an
  :class:`~mcverify.sim.schedule.ErrorSchedule` with both vehicles' shares 1.

Why this is the campaign's own law: Phi of a standard normal is uniform, so each scenario value has the
law the rollout draws it with, and each error unit is uniform in [-1, 1], the paper's noise
(:func:`mcverify.sim.noise.measure` with no structured share) scaled by the same half-widths. A cell
whose noise has structured disturbances, a fixed key or noise branches has another law and is refused.

The performance function g of a row is one of :data:`mcverify.requirements.PERFORMANCES`, each <= 0
exactly when the target event occurred, so the event and its probability do not depend on the choice,
only the intermediate levels subset simulation climbs:

- ``robustness`` (the default): the target's robustness (:mod:`mcverify.analysis.robustness`, the
  minimum over the target's requirements; a collision reads as a negative robustness; h_ef = 0
  exactly has probability 0);
- ``precursor-ladder``: the robustness divided by 1 + the longest run of consecutive control steps in
  which neither Q1 nor Q2 was solved. Where the event comes from the ego holding its last plan through
  such a run, the runs of 1, 2, 4, ... unsolved steps are its precursors, each about a tenth as common
  as the one before, and this g puts the intermediate levels on them instead of on the tail of the
  episodes that never hold a plan (the measurement: docs/rare_events.md, "the precursor ladder");
- ``margin-ladder``: the robustness divided by 1 + ``MARGIN_FACTOR`` times the depth of the row's
  ``theorem5_margin`` below 0 (0 where it is not negative or not measured). Why: the run of unsolved
  steps after a certified infeasible one is decided by whether the fast path converges on a barely
  infeasible problem (the steps in between are presumed infeasible), a knife edge a Markov chain cannot
  walk along; the margin is a real number of the solves, and its depth ranks the episodes that go on to
  the event (docs/rare_events.md, "the margin ladder").

Cost: the control steps each episode ran (``steps`` of its row).
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.special import ndtr

from mcverify.analysis.robustness import robustness
from mcverify.cell import Cell
from mcverify.draws import DRAWS, Draw
from mcverify.episode.draws import value_of_unit
from mcverify.episode.rollout import ChunkResult, run_episodes
from mcverify.errors import RunError
from mcverify.requirements import MARGIN_LADDER, PERFORMANCES, PRECURSOR_LADDER, TARGETS, margin_ladder
from mcverify.sim.schedule import CHANNELS, FRONT_CHANNELS, OPP_CHANNELS, ErrorSchedule, control_steps


def random_draws(cell: Cell) -> tuple[Draw, ...]:
    """The cell's scenario draws that are random (they apply and have a range), in registry order."""
    p = cell.params
    return tuple(d for d in DRAWS if d.applies(p) and d.range_of(p))


def measured_channels(cell: Cell) -> tuple[int, ...]:
    """The schedule columns the cell's planner measures: veh_f's, and veh_o's where there is one."""
    has_opp = cell.params.opposing.kind != "none"
    return FRONT_CHANNELS + (OPP_CHANNELS if has_opp else ())


def check_law(cell: Cell) -> None:
    """Refuse (one line) a cell whose perception error is not i.i.d. uniform units per step and channel."""
    n = cell.params.noise
    if n.kind not in ("paper", "none"):
        raise RunError(f"cell {cell.name}: subset simulation knows the noise kinds paper and none, not {n.kind!r}")
    for name, value in (("noise.structured_share", n.structured_share), ("noise.lateral_share", n.lateral_share)):
        if value:
            raise RunError(f"cell {cell.name} sets {name} = {value}: subset simulation draws the perception error as "
                           "i.i.d. uniform units, the paper's noise without structured disturbances")
    if n.key_seed >= 0 or n.branch_after_steps:
        raise RunError(f"cell {cell.name} fixes its noise (noise.key_seed or noise.branch_after_steps): subset "
                       "simulation draws every input itself")


@dataclass
class ClosedLoopProblem:
    """One cell's closed loop for :func:`mcverify.estimate.subset.run`: ``dimension``, ``evaluate(x)``
    (performance, control steps per row; ``performance_function`` one of
    :data:`mcverify.requirements.PERFORMANCES`), ``key`` (names it in checkpoints). Episodes are run in
    batches of the rows given (one rollout per call); an episode's id is its row within the call, which no value
    depends on (every input comes from x)."""

    cell: Cell
    seed: int
    target: str
    planner: Any
    performance_function: str = PERFORMANCES[0]
    draws: tuple[Draw, ...] = field(init=False)
    channels: tuple[int, ...] = field(init=False)
    steps: int = field(init=False)
    steps_run: int = 0  # control steps of every evaluation so far
    episodes_run: int = 0

    def __post_init__(self) -> None:
        if self.target not in TARGETS:
            raise RunError(f"unknown target {self.target!r}; valid: {', '.join(TARGETS)}")
        if self.performance_function not in PERFORMANCES:
            raise RunError(f"unknown performance function {self.performance_function!r}; valid: "
                           f"{', '.join(PERFORMANCES)}")
        check_law(self.cell)
        self.draws = random_draws(self.cell)
        self.channels = measured_channels(self.cell)
        self.steps = control_steps(self.cell.params.sim)

    @property
    def dimension(self) -> int:
        return len(self.draws) + self.steps * len(self.channels)

    @property
    def key(self) -> str:
        """The cell's parameters, seed, target and performance function, hashed: a checkpoint of another
        problem is refused. (The default performance function is left out, so that keys made before there
        was a choice stay valid.)"""
        fields = {"cell": self.cell.name, "params": repr(self.cell.params), "seed": self.seed, "target": self.target}
        if self.performance_function != PERFORMANCES[0]:
            fields["performance"] = self.performance_function
        text = json.dumps(fields, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()

    def inputs(self, x: np.ndarray) -> tuple[list[dict[str, float]], list[ErrorSchedule]]:
        """Rows of x as (scenario values, error schedule) per episode."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        if x.shape[1] != self.dimension:
            raise ValueError(f"inputs need {self.dimension} units per row, got {x.shape[1]}")
        s = len(self.draws)
        u = ndtr(x[:, :s])
        p = self.cell.params
        scenarios = [{d.name: value_of_unit(d, p, float(u[i, j])) for j, d in enumerate(self.draws)}
                     for i in range(x.shape[0])]
        noise = 2.0 * ndtr(x[:, s:].reshape(x.shape[0], self.steps, len(self.channels))) - 1.0
        units = np.zeros((x.shape[0], self.steps, len(CHANNELS)))
        units[:, :, list(self.channels)] = noise
        return scenarios, [ErrorSchedule.of(units[i]) for i in range(x.shape[0])]

    def simulate(self, x: np.ndarray, record: Sequence[int] | bool = ()) -> ChunkResult:
        """The episodes of the rows of x (ids 0 .. n - 1 of this call), as the rollout returns them."""
        scenarios, schedules = self.inputs(x)
        ids = list(range(len(schedules)))
        return run_episodes(self.cell, ids, self.seed, self.planner, scenarios=dict(enumerate(scenarios)),
                            schedules=schedules, record=record)

    def performance(self, row: dict[str, Any]) -> float:
        """The performance function of one row (<= 0 exactly at the event)."""
        values = [robustness(row, r) for r in TARGETS[self.target].requirements]
        g = float(min(values)) if values else math.nan
        if self.performance_function == PRECURSOR_LADDER:
            g /= 1.0 + int(row.get("both_infeasible_longest_run") or 0)  # a positive divisor keeps the sign
        elif self.performance_function == MARGIN_LADDER:
            g = margin_ladder(g, float(row.get("theorem5_margin", math.nan)))
        return g

    def evaluate(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        result = self.simulate(x)
        g = np.array([self.performance(r) for r in result.rows])
        steps = np.array([int(r["steps"]) for r in result.rows])
        self.steps_run += int(steps.sum())
        self.episodes_run += len(result.rows)
        return g, steps
