"""What an estimate would spend, before it runs (``mcverify estimate --dry-run``).

The episode counts follow from each method's options; the CPU is the run dry run's per-episode
model (:mod:`mcverify.campaign.cost`, a rough range measured on this project's machine):

- ``mc``: at most ``budget`` episodes per cell; the anytime-valid stopping rule only saves.
- ``importance``: at most ``ce_samples`` episodes per cross-entropy iteration, ``ce_iterations``
  of them (fewer once the elite reaches the event), then ``samples`` final draws.
- ``splitting``: ``particles`` whole episodes per AMS run, ``replicates`` runs, then one partial
  re-simulation per iteration. With one particle killed per iteration an AMS run needs about
  ``particles * ln(1 / p)`` iterations (Cerou and Guyader 2007), so the total depends on the
  probability being estimated; the plan shows it for p = 1e-2 and 1e-5 (each restart counted as
  a whole episode: an upper figure) and the cap ``max_iterations``.
- ``subset``: ``stage_samples`` episodes at stage 0 and ``stage_samples (1 - p0)`` per further stage,
  about ``log p / log p0`` stages, ``replicates`` runs; shown for the same two probabilities.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from mcverify.campaign import cost
from mcverify.campaign.spec import Campaign
from mcverify.cell import Cell
from mcverify.requirements import PLAIN_ROBUSTNESS

#: Probabilities at which a splitting plan shows its expected iterations.
SPLITTING_PROBABILITIES = (1e-2, 1e-5)


@dataclass(frozen=True)
class EstimateOptions:
    """The options of ``mcverify estimate`` that decide how many episodes it may run, as the command line
    filled them (its defaults are the command's, not repeated here); ``cells`` empty: every cell."""

    method: str
    target: str
    budget: int
    samples: int
    ce_samples: int
    ce_iterations: int
    particles: int
    replicates: int
    max_iterations: int
    cells: tuple[str, ...]
    workers: int
    stage_samples: int = 2000
    p0: float = 0.1
    performance: str = PLAIN_ROBUSTNESS


def _selected(campaign: Campaign, cells: Sequence[str]) -> list[Cell]:
    return [c for c in campaign.cells if not cells or c.name in cells]


def _cpu_line(cells: list[Cell], episodes_per_cell: float, workers: int, bound: str) -> str:
    low = sum(cost.cell_seconds(c)[0] for c in cells) * episodes_per_cell
    high = sum(cost.cell_seconds(c)[1] for c in cells) * episodes_per_cell
    return (f"estimated CPU: {cost.duration_range(low, high)} {bound}; wall time on {workers} worker(s): "
            f"{cost.duration_range(low / workers, high / workers)} {bound}")


def render(campaign: Campaign, options: EstimateOptions) -> str:
    """The dry run's report: the method, the cells, the episodes and a rough CPU range."""
    cells = _selected(campaign, options.cells)
    names = ", ".join(c.name for c in cells)
    climbing = f" (performance function {options.performance})" if options.method == "subset" else ""
    head = (f"estimate {campaign.source}: {options.method}, target {options.target}{climbing}, {len(cells)} cell(s): "
            f"{names}")
    rough = "(per-episode costs measured on a 2-core machine, results/BENCHMARKS.md; a rough range)"
    if options.method == "mc":
        n = options.budget
        lines = [f"at most {n} episodes per cell, {n * len(cells)} in all (a cell stops earlier once its "
                 "interval is narrow enough)",
                 _cpu_line(cells, n, options.workers, "at most")]
    elif options.method == "importance":
        ce = options.ce_samples * options.ce_iterations
        n = ce + options.samples
        lines = [f"at most {options.ce_iterations} cross-entropy iterations of {options.ce_samples} episodes "
                 f"({ce}; they stop once the elite reaches the event) and {options.samples} final draws: at most "
                 f"{n} episodes per cell, {n * len(cells)} in all",
                 _cpu_line(cells, n, options.workers, "at most")]
    elif options.method == "subset":
        lines = _subset_lines(cells, options)
    else:
        lines = _splitting_lines(cells, options)
    return "\n".join([head, *lines, cost.kernels_to_build(cells).text(), rough])


def _splitting_lines(cells: list[Cell], options: EstimateOptions) -> list[str]:
    runs = options.replicates
    first = options.particles * runs
    lines = [f"{runs} AMS runs per cell of {options.particles} particles: {first} whole episodes per cell, then "
             f"one partial re-simulation per iteration (at most {options.max_iterations} per run)"]
    for p in SPLITTING_PROBABILITIES:
        iterations = math.ceil(options.particles * math.log(1.0 / p))
        per_cell = first + runs * min(iterations, options.max_iterations)
        lines.append(f"at p = {p:.0e}: about {iterations} iterations per run, at most {per_cell} episode "
                     f"equivalents per cell; " + _cpu_line(cells, per_cell, options.workers, "at most"))
    return lines


def _subset_lines(cells: list[Cell], options: EstimateOptions) -> list[str]:
    """Subset simulation: N episodes at stage 0, N (1 - p0) more per further stage; a run reaching p needs
    about ceil(log p / log p0) stages."""
    n, p0, runs = options.stage_samples, options.p0, options.replicates
    lines = [f"{runs} subset simulation runs per cell of {n} episodes per stage (conditional level {p0}): "
             f"{n} episodes at stage 0, {round(n * (1 - p0))} per further stage"]
    for p in SPLITTING_PROBABILITIES:
        stages = max(1, math.ceil(math.log(p) / math.log(p0) - 1e-9))
        per_cell = runs * (n + (stages - 1) * round(n * (1 - p0)))
        lines.append(f"at p = {p:.0e}: about {stages} stages per run, {per_cell} episodes per cell; "
                     + _cpu_line(cells, per_cell, options.workers, "in all"))
    return lines
