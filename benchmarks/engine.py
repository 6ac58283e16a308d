"""``python -m benchmarks.engine``: the engine against a fair IPOPT baseline (and the naive loop), in one run.

All sides run the same paired episodes of every cell of one campaign (default: the paper's Table IV
mix, ``campaigns/table4_fixed_start.toml``, all six cells) with the same control period, horizon and
integration:

* engine: :func:`mcverify.episode.rollout.run_episodes` with the cell's solver backend (or ``--backend``);
* compiled IPOPT loop (the baseline a careful user writes, :mod:`benchmarks.ipopt_loop`):
  ``nlpsol`` with ``expand=True``, primal-dual warm start with ``mu_init`` 1e-7, the engine's
  infeasibility memo;
* naive (optional, ``naive_episodes`` > 0): :mod:`benchmarks.naive`, the paper's Opti loop.

Reported: episodes per CPU-minute of each side over the mix (``time.process_time`` of this process,
so worker counts flatter no side; every cell has the same number of episodes on a side, so this is
the mix's mean) and the ratios, the CPU per episode split by solve class
(:mod:`benchmarks.solve_classes`) and by cell, the peak resident memory, and the agreement of the
paired episodes (:func:`benchmarks.agreement.agreement`). The engine's CPU is also split by phase
(:class:`mcverify.episode.rollout.PhaseClock`): the host controllers, the JAX plant, the rest. The
figures replace the section ``benchmarks.engine`` of ``results/BENCHMARKS.md`` (:mod:`benchmarks.engine_report`).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import resource
import sys
import time
from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any

import jax
import numpy as np

from benchmarks import engine_report, section
from benchmarks.agreement import agreement
from benchmarks.ipopt_loop import ipopt_loop_planner
from benchmarks.naive import naive_planner
from benchmarks.sides import PAIRED_VALUES, SIDES, SideResult, ratio_interval
from benchmarks.solve_classes import ClassTally, TimedSolver
from mcverify.campaign.overrides import apply_overrides
from mcverify.campaign.spec import load_campaign
from mcverify.cell import Cell
from mcverify.cli.options import nonneg_int, positive_int
from mcverify.control.planner import Planner
from mcverify.episode.draws import episode_key
from mcverify.episode.rollout import PhaseClock, run_episodes
from mcverify.errors import UserError
from mcverify.sim.lanes import LaneGroups
from mcverify.sim.plant import initial_plant
from mcverify.solver.mpc import MpcSolver

DEFAULT_CAMPAIGN = "campaigns/table4_fixed_start.toml"
ALL_CELLS = "all"
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
    progress=print,
    overrides: dict | None = None,
    seed: int | None = None,
    settings: Sequence[str] = (),
) -> dict[str, Any]:
    """Run the sides on every chosen cell and return the figures.

    Per cell, the engine runs episodes 0 .. engine_episodes - 1, the baseline and the naive loop the
    first ``baseline_episodes`` / ``naive_episodes`` of them (paired; 0 skips a side's episodes).
    ``settings``: ``"SECTION.FIELD=VALUE"`` strings written into the campaign file (``--set``).
    """
    if engine_episodes < 1 or not 0 <= min(baseline_episodes, naive_episodes) <= max(
            baseline_episodes, naive_episodes) <= engine_episodes:
        raise ValueError("need engine_episodes >= 1 and 0 <= baseline_episodes, naive_episodes <= engine_episodes "
                         "(their episodes are paired with the engine's)")
    cells, seed, crn = pick_cells(campaign, cell_name, backend, overrides, seed, settings)
    counts = {"engine": engine_episodes, "baseline": baseline_episodes, "naive": naive_episodes}
    progress(f"benchmarks.engine: {campaign}, {len(cells)} cell(s); episodes per cell: engine {engine_episodes}, "
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
        "machine": section.machine(),
        "load_average": _load(),
    }
    return result


def _load() -> list[float] | None:
    try:
        return [round(v, 2) for v in os.getloadavg()]
    except OSError:
        return None


def _parser() -> argparse.ArgumentParser:
    p = section.parser("engine", "The engine against the compiled IPOPT loop (and the naive loop), in one run.")
    p.add_argument("--campaign", default=DEFAULT_CAMPAIGN,
                   help="campaign file (default: Table IV with veh_o on the road from the start)")
    p.add_argument("--cell", default=ALL_CELLS,
                   help="cell name of that campaign, or 'all' (default: all, the Table IV mix)")
    p.add_argument("--engine-episodes", type=positive_int, default=2, help="episodes per cell, engine")
    p.add_argument("--baseline-episodes", type=nonneg_int, default=2,
                   help="paired episodes per cell, compiled warm-started IPOPT loop (0: skip)")
    p.add_argument("--naive-episodes", type=nonneg_int, default=0,
                   help="paired episodes per cell, the paper-style Opti loop (0: skip, the default)")
    p.add_argument("--backend", help="the engine's solver backend (default: the cell's)")
    p.add_argument("--seed", type=nonneg_int, help="campaign seed (overrides the file: other episodes)")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE", dest="settings",
                   help="override a model parameter of every cell, on every side (repeatable)")
    section.add_output_options(p)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    def body() -> int:
        args = _parser().parse_args(argv)
        if max(args.naive_episodes, args.baseline_episodes) > args.engine_episodes:
            raise UserError("--baseline-episodes and --naive-episodes must be at most --engine-episodes "
                            "(their episodes are paired with the engine's)")
        result = run(
            campaign=args.campaign, cell_name=args.cell, engine_episodes=args.engine_episodes,
            baseline_episodes=args.baseline_episodes, naive_episodes=args.naive_episodes, backend=args.backend,
            progress=lambda msg: print(msg, file=sys.stderr),
            seed=args.seed, settings=args.settings,
        )
        result["command"] = section.command("engine", argv)
        print(engine_report.render(result))
        if not args.no_write:
            section.write("engine", engine_report.markdown(result), args.write)
            print(f"written: {args.write} (section benchmarks.engine)", file=sys.stderr)
        return 0

    return section.run_main("engine", body)


if __name__ == "__main__":
    sys.exit(main())
