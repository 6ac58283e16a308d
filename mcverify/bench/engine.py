"""``mcverify bench``: the engine against a fair IPOPT baseline (and the naive loop), in one run.

All sides run the same paired episodes of every cell of one campaign (default: the paper's Table IV
mix, ``campaigns/table4_fixed_start.toml``, all six cells) with the same control period, horizon and
integration:

* engine: :func:`mcverify.episode.rollout.run_episodes` with the cell's solver backend (or ``--backend``);
* compiled IPOPT loop (the baseline a careful user writes, :mod:`mcverify.bench.ipopt_loop`):
  ``nlpsol`` with ``expand=True``, primal-dual warm start with ``mu_init`` 1e-7, the engine's
  infeasibility policy;
* naive (optional, ``naive_episodes`` > 0): :mod:`mcverify.bench.naive`, the paper's Opti loop.

Reported: episodes per CPU-minute of each side over the mix (``time.process_time`` of this process,
so worker counts flatter no side; every cell has the same number of episodes on a side, so this is
the mix's mean) and the ratios, the CPU per episode split by solve class
(:mod:`mcverify.bench.solve_classes`) and by cell, the peak resident memory, and the agreement of the
paired episodes (:func:`mcverify.bench.agreement.agreement`). The engine's CPU is also split by phase
(:class:`mcverify.episode.rollout.PhaseClock`): the host controllers, the JAX plant, the rest. The
figures are appended to ``results/BENCHMARKS.md`` (:mod:`mcverify.bench.engine_report`).
"""

from __future__ import annotations

import dataclasses
import math
import os
import platform
import resource
import shlex
import sys
import time
from collections import Counter
from collections.abc import Callable, Sequence
from datetime import datetime, timezone
from typing import Any

import jax
import numpy as np

from mcverify import provenance
from mcverify.analysis.stats import Interval, ratio_of_sums_interval
from mcverify.bench.agreement import agreement
from mcverify.bench.ipopt_loop import ipopt_loop_planner
from mcverify.bench.naive import naive_planner
from mcverify.bench.solve_classes import ClassTally, TimedSolver
from mcverify.campaign.spec import apply_overrides, load_campaign
from mcverify.cell import Cell
from mcverify.control.planner import Planner
from mcverify.episode.rollout import PhaseClock, episode_key, run_episodes
from mcverify.sim.plant import LaneGroups, initial_plant
from mcverify.solver.mpc import MpcSolver

DEFAULT_CAMPAIGN = "campaigns/table4_fixed_start.toml"
ALL_CELLS = "all"
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
    episodes drawn: :func:`~mcverify.analysis.ratios.ratio_of_sums_interval` of ``other``'s CPU over the
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


def _timed(name: str, fn) -> SideResult:
    cpu0, wall0 = time.process_time(), time.perf_counter()
    rows = fn()
    return SideResult(name, rows, time.process_time() - cpu0, time.perf_counter() - wall0)


def engine_phases(rows: list[dict], clock: PhaseClock, total_cpu_s: float) -> dict[str, float]:
    """CPU seconds per phase of the engine's loop; planner + plant + other = ``total_cpu_s``.

    planner: the host controllers (the solves, warm starts, Algorithm 1, Table I); plant: JAX
    observe/advance with their transfers; other: scenario draws, bookkeeping, rows. solver_wall:
    the solves' own clock (``solves * solve_time_mean_s``), wall time: on an idle machine it is
    the solver's share of the planner phase, on a loaded one it can exceed it.
    """
    planner = clock.cpu_s.get("planner", 0.0)
    plant = clock.cpu_s.get("plant", 0.0)
    return {
        "planner": planner,
        "plant": plant,
        "other": max(total_cpu_s - planner - plant, 0.0),
        "solver_wall": sum(r["solves"] * r["solve_time_mean_s"] for r in rows if r["solves"]),
        "control_steps": float(clock.calls.get("planner", 0)),
    }


def plant_transfer_ms(cell: Cell, batch: int, seed: int, reps: int = 200) -> dict[str, float]:
    """CPU ms per control step of a ``batch``-episode chunk: the jitted plant (observe + advance,
    waited for; the controls' copy to the device included) against the device-to-host copies the
    loop makes of its results (measurements, ego states, safety trace). Steps with zero control
    from the campaign's start; the cost does not depend on the state."""
    p = cell.params
    keys = jax.numpy.stack([episode_key(seed, cell.index, e) for e in range(batch)])
    world = LaneGroups(initial_plant(p, [0.0] * batch), keys, p)
    u, active = np.zeros((batch, 2)), np.ones(batch, dtype=bool)
    world.advance(u, active), world.observe(0)  # compiled outside the clock
    compute = transfer = 0.0
    for step in range(reps):
        t0 = time.process_time()
        obs = world.observe_on_device(step)
        subs = world.advance(u, active)
        jax.block_until_ready((obs, subs, world.plants, world.traces))
        t1 = time.process_time()
        [np.asarray(a) for group in obs for a in group], world.ego(), world.trace()
        transfer += time.process_time() - t1
        compute += t1 - t0
    return {"compute_ms": 1e3 * compute / reps, "transfer_ms": 1e3 * transfer / reps, "batch": float(batch)}


def pick_cells(campaign_path: str, cell_name: str, backend: str | None,
               overrides: dict | None = None, seed: int | None = None,
               settings: Sequence[str] = ()) -> tuple[list[Cell], int, bool]:
    """The cells to run (``cell_name`` or every cell for ``"all"``), with ``backend`` and other ``overrides``
    (dotted keys) applied when given; ``seed``:
    the campaign seed instead of the file's (other episodes, the same cells); ``settings``: as
    ``mcverify run --set``, written into the file before its cells are expanded."""
    camp = load_campaign(campaign_path, seed=seed, settings=settings)
    cells = list(camp.cells) if cell_name == ALL_CELLS else [camp.cell(cell_name)]
    changes = [("mpc.backend", backend, "--backend")]
    changes += [(k, v, "overrides") for k, v in (overrides or {}).items()]
    for key, value, flag in changes:
        if value is not None:
            cells = [dataclasses.replace(c, params=apply_overrides(c.params, {key: value}, flag)) for c in cells]
    return cells, camp.seed, camp.common_random_numbers


def machine() -> str:
    """One line naming the machine for a benchmark row."""
    return f"{provenance.cpu_model()}, {os.cpu_count()} logical cores, Python {platform.python_version()}"


def _planners(params, tallies: dict[str, ClassTally], sides: list[str]) -> dict[str, Planner]:
    """The planners of ``sides`` for one cell, every solver timed into its side's tally."""
    def timed(side: str) -> Callable:
        return lambda s: TimedSolver(s, tallies[side])

    make = {
        "engine": lambda: Planner(params, solver_factory=lambda p, st: timed("engine")(MpcSolver(p, st))),
        "baseline": lambda: ipopt_loop_planner(params, wrap=timed("baseline")),
        "naive": lambda: naive_planner(params, wrap=timed("naive")),
    }
    return {s: make[s]() for s in sides}


def ipm_attempts(planner: Planner) -> tuple[Counter, Counter]:
    """The IPM attempt outcomes (``warm1:Converged``, ...) counted by the engine planner's backends,
    and their CPU seconds (empty for a backend without IPM)."""
    count: Counter = Counter()
    cpu_s: Counter = Counter()
    for s in (planner.plain, getattr(planner, "with_opp", None)):
        backend = getattr(getattr(s, "solver", s), "backend", None)
        count.update(getattr(backend, "ipm_outcomes", {}))
        cpu_s.update(getattr(backend, "ipm_cpu_s", {}))
    return count, cpu_s


def _run_side(side: str, cell: Cell, ids: list[int], seed: int, planner: Planner, crn: bool,
              clock: PhaseClock) -> SideResult:
    """One side's episodes of one cell, timed: the engine as one batch (its phases into ``clock``),
    the loops one episode after the other, as their users would run them."""
    if side == "engine":
        return _timed(side, lambda: run_episodes(cell, ids, seed, planner, common_random_numbers=crn,
                                                 clock=clock).rows)
    return _timed(side, lambda: [row for e in ids for row in run_episodes(
        cell, [e], seed, planner, common_random_numbers=crn).rows])


def run(
    *,
    campaign: str = DEFAULT_CAMPAIGN,
    cell_name: str = ALL_CELLS,
    engine_episodes: int = 2,
    baseline_episodes: int = 2,
    naive_episodes: int = 0,
    backend: str | None = None,
    write: bool = True,
    progress=print,
    overrides: dict | None = None,
    seed: int | None = None,
    settings: Sequence[str] = (),
) -> dict[str, Any]:
    """Run the sides on every chosen cell and return the figures (and append them to results/BENCHMARKS.md).

    Per cell, the engine runs episodes 0 .. engine_episodes - 1, the baseline and the naive loop the
    first ``baseline_episodes`` / ``naive_episodes`` of them (paired; 0 skips a side's episodes).
    ``settings``: ``"SECTION.FIELD=VALUE"`` strings written into the campaign file (``mcverify bench --set``).
    """
    if engine_episodes < 1 or not 0 <= min(baseline_episodes, naive_episodes) <= max(
            baseline_episodes, naive_episodes) <= engine_episodes:
        raise ValueError("need engine_episodes >= 1 and 0 <= baseline_episodes, naive_episodes <= engine_episodes "
                         "(their episodes are paired with the engine's)")
    cells, seed, crn = pick_cells(campaign, cell_name, backend, overrides, seed, settings)
    counts = {"engine": engine_episodes, "baseline": baseline_episodes, "naive": naive_episodes}
    progress(f"bench: {campaign}, {len(cells)} cell(s); episodes per cell: engine {engine_episodes}, "
             f"compiled IPOPT loop {baseline_episodes}, naive {naive_episodes} (paired: the first ones)")
    sides = {s: SideResult(s, [], 0.0, 0.0) for s in SIDES}
    tallies = {s: sides[s].classes for s in SIDES}
    clock, outcomes, attempt_cpu, setup_cpu_s = PhaseClock(), Counter(), Counter(), 0.0
    active = [s for s in SIDES if counts[s]]
    for cell in cells:
        # One-off costs, outside every clock: building/loading the solvers (kernel load, nlpsol set-up)
        # and XLA's compilation of the plant - a one-step episode of each side triggers them.
        saved = {s: (Counter(t.count), Counter(t.cpu_s)) for s, t in tallies.items()}
        cpu0 = time.process_time()
        planners = _planners(cell.params, tallies, active)
        sim = dataclasses.replace(cell.params.sim, max_time_s=cell.params.sim.control_period_s)
        warm_cell = dataclasses.replace(cell, params=dataclasses.replace(cell.params, sim=sim))
        for s in active:
            run_episodes(warm_cell, [0], seed, planners[s], common_random_numbers=crn)
        setup_cpu_s += time.process_time() - cpu0
        warm_attempts = ipm_attempts(planners["engine"])
        for s, (count, cpu) in saved.items():  # the warm-up's solves are not counted either
            tallies[s].count, tallies[s].cpu_s = count, cpu
        progress(f"  cell {cell.name}")
        for s in active:
            ids = list(range(counts[s]))
            class_cpu0 = Counter(tallies[s].cpu_s)
            r = _run_side(s, cell, ids, seed, planners[s], crn, clock)
            if s == "engine":  # the backends' counters include the warm-up step: subtract it
                count, cpu = ipm_attempts(planners[s])
                outcomes.update(count - warm_attempts[0]), attempt_cpu.update(cpu - warm_attempts[1])
            sides[s].add(cell.name, r.rows, r.cpu_s, r.wall_s, Counter(tallies[s].cpu_s) - class_cpu0)
            progress(f"    {s}: {r.cpu_s / len(r.rows):.1f} CPU-s per episode")
    engine = sides["engine"]
    engine.phases = engine_phases(engine.rows, clock, engine.cpu_s)
    result = {
        "campaign": campaign,
        "cells": [c.name for c in cells],
        "backend": ",".join(sorted({c.params.mpc.backend for c in cells})),
        "sides": {s: sides[s] for s in active},
        "ratios": {s: engine.episodes_per_cpu_min / sides[s].episodes_per_cpu_min
                   for s in ("baseline", "naive") if counts[s]},
        "ratio_intervals": {s: ratio_interval(engine, sides[s], crn) for s in ("baseline", "naive") if counts[s]},
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "setup_cpu_s": setup_cpu_s,
        "plant_transfer": plant_transfer_ms(cells[0], engine_episodes, seed),
        "agreement": {s: agreement(sides[s].rows, engine.rows, key="episode_id", values=PAIRED_VALUES)
                      for s in ("baseline", "naive") if counts[s]},
        "ipm_attempts": {k: {"attempts": n, "cpu_s": attempt_cpu[k]} for k, n in outcomes.most_common()},
        "machine": machine(),
        "load_average": _load(),
        "command": "mcverify " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv[1:2] == ["bench"]
        else "mcverify bench",
        "date": datetime.now(timezone.utc).strftime("%Y-%m-%d"),
    }
    if write:
        from mcverify.bench.engine_report import append_markdown

        append_markdown(result)
    return result


def _load() -> list[float] | None:
    try:
        return [round(v, 2) for v in os.getloadavg()]
    except OSError:
        return None
