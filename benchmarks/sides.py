"""The engine benchmark's data: one side's episodes and CPU (:class:`SideResult`) and the interval of
the engine's speed-up over another side (:func:`ratio_interval`)."""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from typing import Any

import numpy as np

from benchmarks.ratios import ratio_of_sums_interval
from benchmarks.solve_classes import ClassTally
from mcverify.analysis.intervals import Interval

#: Columns compared between paired episodes (besides the safety verdict and the outcome).
PAIRED_VALUES = ("min_dist_front_m", "min_gap_opp_m", "overtake_time_s")
#: Side names, in report order: the engine, the fair baseline, the paper-style loop.
SIDES = ("engine", "baseline", "naive")


@dataclasses.dataclass
class SideResult:
    """One side's episodes over the mix: rows, CPU and wall seconds, engine phases, solve classes,
    per cell ``[episodes, cpu_s]`` and per cell the solves' CPU seconds by class (:class:`SolveClass`)."""

    name: str
    rows: list[dict]
    cpu_s: float
    wall_s: float
    phases: dict[str, float] = dataclasses.field(default_factory=dict)
    classes: ClassTally = dataclasses.field(default_factory=ClassTally)
    per_cell: dict[str, list[float]] = dataclasses.field(default_factory=dict)
    per_cell_classes: dict[str, Counter] = dataclasses.field(default_factory=dict)

    @property
    def episodes_per_cpu_min(self) -> float:
        return 60.0 * len(self.rows) / self.cpu_s if self.cpu_s > 0 else math.nan

    @property
    def cpu_s_per_episode(self) -> float:
        return self.cpu_s / len(self.rows) if self.rows else math.nan

    @property
    def solves(self) -> int:
        return sum(r["solves"] for r in self.rows)

    @property
    def cpu_ms_per_solve(self) -> float:
        return 1e3 * self.cpu_s / self.solves if self.solves else math.nan

    def add(self, cell: str, rows: list[dict], cpu_s: float, wall_s: float, class_cpu_s: Counter | None = None) -> None:
        self.rows.extend(rows)
        self.cpu_s += cpu_s
        self.wall_s += wall_s
        n, c = self.per_cell.get(cell, [0, 0.0])
        self.per_cell[cell] = [n + len(rows), c + cpu_s]
        self.per_cell_classes.setdefault(cell, Counter()).update(class_cpu_s or {})


def episode_cpu_s(side: SideResult) -> dict[Any, float]:
    """Each episode's share of its cell's measured CPU seconds: ``{episode_id: cpu_s}``.

    The engine runs a cell's episodes as one batch, so its process clock has no per-episode figure;
    both sides are therefore split the same way, in proportion to each episode's own solver clock
    (``solves * solve_time_mean_s``, where most of an episode's CPU goes), equally where a cell's
    episodes made no solve. The shares of a cell add up to its measured CPU, so sums over whole cells
    are the measured ones."""
    out: dict[Any, float] = {}
    for cell, (_, cpu_s) in side.per_cell.items():
        rows = [r for r in side.rows if r["cell"] == cell]
        clocks = np.array([r["solves"] * r["solve_time_mean_s"] if r.get("solves") else 0.0 for r in rows])
        weights = clocks / clocks.sum() if clocks.sum() > 0 else np.full(len(rows), 1.0 / max(len(rows), 1))
        out.update({r["episode_id"]: float(cpu_s * w) for r, w in zip(rows, weights, strict=True)})
    return out


def ratio_interval(engine: SideResult, other: SideResult, common_random_numbers: bool,
                   level: float = 0.95) -> Interval | None:
    """Interval for the engine's speed-up over ``other`` (episodes per CPU-minute over the mix) from the
    episodes drawn: :func:`~benchmarks.ratios.ratio_of_sums_interval` of ``other``'s CPU over the
    engine's, per episode as :func:`episode_cpu_s` splits them. The sampling units are independent:
    with common random numbers episode k of every cell shares its noise, so the unit is episode k of
    the whole mix (its CPU summed over the cells); without, the episodes, the cells as strata. None
    unless both sides ran the same episodes (the measured ratio is then the interval's point estimate)."""
    mine, theirs = episode_cpu_s(engine), episode_cpu_s(other)
    if not mine or set(mine) != set(theirs):
        return None
    units: dict[Any, list[float]] = {}  # unit -> [other's CPU, engine's CPU]
    strata: dict[Any, str] = {}
    for r in engine.rows:
        unit = r["cell_episode"] if common_random_numbers else r["episode_id"]
        sums = units.setdefault(unit, [0.0, 0.0])
        sums[0] += theirs[r["episode_id"]]
        sums[1] += mine[r["episode_id"]]
        strata[unit] = r["cell"]
    keys = sorted(units)
    return ratio_of_sums_interval([units[u][0] for u in keys], [units[u][1] for u in keys],
                                  None if common_random_numbers else [strata[u] for u in keys], level=level)
