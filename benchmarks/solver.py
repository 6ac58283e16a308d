"""``python -m benchmarks.solver``: measure the solver backends against each other (not a timed test).

What it measures, all in one run so that ratios are taken under the same machine load:

1. **Per-solve CPU time on the same recorded states.** One closed loop per cell is run with the
   IPOPT reference, recording every solve's inputs (measured states, direction, the warm start it
   got). Every backend then solves each recorded problem twice: warm (from the reference's warm
   start) and cold. CPU time is the calling thread's (``time.thread_time``), so JAX's worker
   threads do not count; the plan returned is compared with the IPOPT reference's.
2. **Paired closed-loop episodes.** The campaign's cells are run with every backend on the same
   (seed, cell, episode id), hence the same perception noise: safety verdict, outcome, minimum
   distance to veh_f and overtaking time are compared episode by episode, with an exact
   (Clopper-Pearson) interval on the agreement rate; disagreements are listed. Chunks of both
   backends are interleaved on one process pool; each chunk's CPU time is measured in its
   worker (``time.process_time``), giving episodes per CPU-minute and their ratio.
3. **JAX side of a control step.** ``run_episodes`` with a stub solver that returns a constant
   input at once: CPU per control step of the vmapped observe/advance and the host transfers,
   for batches of 1 and 8 episodes, after a warm-up run (compilation excluded and counted apart).

The figures are written as a Markdown section between markers into ``results/BENCHMARKS.md``
(the rest of that file is left as it is) together with the exact command and the machine, by
:mod:`benchmarks.solver_report`; episodes are compared by :func:`benchmarks.agreement.agreement`.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import multiprocessing as mp
import os
import resource
import sys
import time
from collections import Counter
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks import section, solver_report
from benchmarks.agreement import agreement
from mcverify import provenance
from mcverify.campaign import executors
from mcverify.campaign.spec import Campaign, load_campaign
from mcverify.cell import Cell
from mcverify.cli.options import positive_int
from mcverify.errors import UserError
from mcverify.levels import Level
from mcverify.model import BACKEND_NAMES, ModelParams

# ------------------------------------------------------------------------------------ helpers


def with_backend(params: ModelParams, backend: str) -> ModelParams:
    return dataclasses.replace(params, mpc=dataclasses.replace(params.mpc, backend=backend))


def without_noise(params: ModelParams) -> ModelParams:
    return dataclasses.replace(params, noise=dataclasses.replace(params.noise, kind="none"))


def machine_info() -> dict[str, Any]:
    """The machine of a solver benchmark: CPU, Python, package versions, git commit, load average."""
    env = provenance.environment_info()
    try:
        load = [round(v, 2) for v in os.getloadavg()]
    except OSError:
        load = None
    return {
        "platform": env["platform"], "python": env["python"], "cpu_model": env["cpu_model"],
        "cpus": str(env["cpu_count"]), "cpus_usable": executors.default_workers(), "load_average": load,
        "casadi": env["packages"]["casadi"], "jax": env["packages"]["jax"],
        "git_commit": provenance.git_commit(short=True) or "",
    }


# --------------------------------------------------------------------------- recorded states


@dataclass(frozen=True)
class RecordedSolve:
    """The inputs of one solve of a reference closed loop (see :meth:`MpcSolver.solve`).

    structure: the solver's :class:`~mcverify.ocp.problem.OcpStructure` (with or without veh_o)."""

    structure: object
    ego: np.ndarray
    front: np.ndarray
    direction: int
    level: Level
    warm: object  # WarmStart | None
    opp_xv: np.ndarray | None
    guess: np.ndarray | None


class _Recorder:
    """Wraps a solver and records the inputs of every solve into a shared list."""

    def __init__(self, solver, calls: list) -> None:
        self.solver = solver
        self.calls = calls

    def solve(self, ego, front, direction, level, warm=None, opp_xv=None, guess=None, **kw):
        self.calls.append(RecordedSolve(
            self.solver.structure, np.array(ego), np.array(front), int(direction), level, warm,
            None if opp_xv is None else np.array(opp_xv), None if guess is None else np.array(guess),
        ))
        return self.solver.solve(ego, front, direction, level, warm, opp_xv=opp_xv, guess=guess, **kw)

    def __getattr__(self, name):
        return getattr(self.solver, name)


def record_solves(cell: Cell, seed: int, episode_ids: Sequence[int]) -> list[RecordedSolve]:
    """Run ``episode_ids`` of ``cell`` with the IPOPT reference and record every solve."""
    from mcverify.control.planner import Planner
    from mcverify.episode.rollout import run_episodes
    from mcverify.solver.mpc import MpcSolver

    params = with_backend(cell.params, "ipopt")
    calls: list[RecordedSolve] = []
    planner = Planner(params, solver_factory=lambda p, st: _Recorder(MpcSolver(p, st), calls))
    run_episodes(dataclasses.replace(cell, params=params), list(episode_ids), seed, planner)
    return calls


def replay(params: ModelParams, backend: str, calls: Sequence[RecordedSolve], warm: bool,
           reference: list | None = None) -> dict[str, Any]:
    """Solve every recorded problem with ``backend`` (warm from the recorded start, or cold).

    Returns summary statistics; with ``reference`` (the solutions of the IPOPT replay), also the
    differences in planned time T and first input u_0.
    """
    from mcverify.solver.mpc import MpcSolver

    solvers: dict = {}
    cpu, its, ok, fallback, sols = [], [], [], [], []
    statuses: Counter[str] = Counter()
    for c in calls:
        solver = solvers.get(c.structure)
        if solver is None:
            solver = solvers[c.structure] = MpcSolver(with_backend(params, backend), c.structure)
        start = c.warm if warm else None
        t0 = time.thread_time()
        sol = solver.solve(c.ego, c.front, c.direction, c.level, start, opp_xv=c.opp_xv, guess=c.guess)
        cpu.append(time.thread_time() - t0)
        its.append(sol.iterations)
        ok.append(sol.success)
        fallback.append(sol.status.fallback)
        statuses[str(sol.status)] += 1
        sols.append(sol)
    cpu_a = np.array(cpu)
    out: dict[str, Any] = {
        "backend": backend, "warm": warm, "solves": len(calls),
        "cpu_ms_mean": 1e3 * float(cpu_a.mean()), "cpu_ms_median": 1e3 * float(np.median(cpu_a)),
        "cpu_ms_p90": 1e3 * float(np.percentile(cpu_a, 90)), "cpu_ms_max": 1e3 * float(cpu_a.max()),
        "iterations_mean": float(np.mean(its)), "success_rate": float(np.mean(ok)),
        "fallback_rate": float(np.mean(fallback)), "statuses": dict(statuses.most_common()),
    }
    if reference is not None:
        both = [(a, b) for a, b in zip(sols, reference, strict=True) if a.success and b.success]
        if both:
            dt = np.array([abs(a.total_time_s - b.total_time_s) for a, b in both])
            du = np.array([float(np.max(np.abs(a.u_plan[0] - b.u_plan[0]))) for a, b in both])
            out.update({
                "compared": len(both), "dT_s_median": float(np.median(dt)), "dT_s_max": float(dt.max()),
                "du0_median": float(np.median(du)), "du0_p99": float(np.percentile(du, 99)), "du0_max": float(du.max()),
                "same_success": float(np.mean([a.success == b.success for a, b in zip(sols, reference, strict=True)])),
            })
    out["_solutions"] = sols
    return out


# --------------------------------------------------------------------------- paired episodes


def _run_chunk(cell: Cell, seed: int, episode_ids: tuple[int, ...], backend: str) -> dict[str, Any]:
    """Worker: one chunk with one backend; rows, CPU seconds of the worker, peak RSS (kB)."""
    from mcverify.control.planner import Planner
    from mcverify.episode.rollout import run_episodes

    params = with_backend(cell.params, backend)
    solver = _SOLVERS.get(params)
    if solver is None:
        solver = _SOLVERS[params] = Planner(params)
    c = dataclasses.replace(cell, params=params)
    t0 = time.process_time()
    res = run_episodes(c, list(episode_ids), seed, solver)
    cpu = time.process_time() - t0
    return {"backend": backend, "rows": res.rows, "cpu_s": cpu,
            "maxrss_kb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}


_SOLVERS: dict = {}


def paired_episodes(campaign: Campaign, backends: Sequence[str], workers: int, chunk_size: int,
                    progress: bool = True) -> dict[str, Any]:
    """Every cell's episodes with every backend, chunks interleaved on one process pool."""
    tasks = []
    for cell in campaign.cells:
        for start in range(0, cell.episodes, chunk_size):
            ids = tuple(range(start, min(cell.episodes, start + chunk_size)))
            for b in backends:
                tasks.append((cell, campaign.seed, ids, b))
    # build every (params, backend) kernel and runtime library here, once, before the workers start
    from mcverify.control.planner import Planner

    for cell in campaign.cells:
        for b in backends:
            Planner(with_backend(cell.params, b))
    results: list[dict[str, Any]] = []
    t_wall = time.perf_counter()
    if workers <= 1:
        for i, t in enumerate(tasks):
            results.append(_run_chunk(*t))
            if progress:
                print(f"  paired episodes: chunk {i + 1}/{len(tasks)}", file=sys.stderr)
    else:
        ctx = mp.get_context("spawn")
        with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
            futs = [pool.submit(_run_chunk, *t) for t in tasks]
            for i, f in enumerate(futs):
                results.append(f.result())
                if progress:
                    print(f"  paired episodes: chunk {i + 1}/{len(tasks)}", file=sys.stderr)
    wall = time.perf_counter() - t_wall
    by_backend: dict[str, dict[str, Any]] = {}
    for b in backends:
        rs = [r for r in results if r["backend"] == b]
        rows = [row for r in rs for row in r["rows"]]
        cpu = sum(r["cpu_s"] for r in rs)
        by_backend[b] = {
            "rows": rows, "episodes": len(rows), "cpu_s": cpu,
            "cpu_s_per_episode": cpu / max(1, len(rows)),
            "episodes_per_cpu_minute": 60.0 * len(rows) / cpu if cpu > 0 else math.nan,
            "maxrss_mb": max((r["maxrss_kb"] for r in rs), default=0) / 1024.0,
        }
    return {"by_backend": by_backend, "wall_s": wall, "workers": workers, "chunk_size": chunk_size}


# ------------------------------------------------------------------------------- JAX overhead


class StubSolver:
    """Returns a constant input at once (zero acceleration, zero slip) and a successful Q1/Q2 plan,
    so that ``run_episodes`` measures only its own (JAX and host) work. Build a planner of stubs
    with :func:`stub_planner`."""

    kernel_hash = "stub"

    def __init__(self, params: ModelParams, structure=None) -> None:
        from mcverify.solver.mpc import MpcSolution
        from mcverify.solver.status import SolveOutcome, SolveStatus

        n = params.mpc.horizon
        self.structure = structure
        self._sol = MpcSolution(
            success=True, status=SolveStatus("stub", SolveOutcome.SOLVED), iterations=0, solve_time_s=0.0,
            total_time_s=1.0,
            x_plan=np.zeros((n + 1, 4)), u_plan=np.zeros((n, 2)), dt_plan=np.full(n, 1.0 / n), warm=None,
        )

    def solve(self, ego, front, direction, level, warm=None, opp_xv=None, guess=None, **kw):
        return self._sol

    def guess_from_plan(self, plan, opp_xv):
        return None


def stub_planner(params: ModelParams):
    """A :class:`~mcverify.control.planner.Planner` whose solvers are :class:`StubSolver`."""
    from mcverify.control.planner import Planner

    return Planner(params, solver_factory=lambda p, st: StubSolver(p, st))


def jax_step_overhead(cell: Cell, seed: int, batch_sizes: Sequence[int] = (1, 8), steps: int = 100) -> dict:
    """CPU per control step of run_episodes with a stub solver (after a warm-up run that compiles)."""
    from mcverify.episode.rollout import run_episodes

    sim = dataclasses.replace(cell.params.sim, max_time_s=steps * cell.params.sim.control_period_s)
    params = dataclasses.replace(cell.params, sim=sim)
    c = dataclasses.replace(cell, params=params)
    stub = stub_planner(params)
    out = {}
    for b in batch_sizes:
        t0 = time.process_time()
        run_episodes(c, list(range(b)), seed, stub)
        first = time.process_time() - t0
        t0 = time.process_time()
        run_episodes(c, list(range(b, 2 * b)), seed, stub)
        cpu = time.process_time() - t0
        out[b] = {"cpu_ms_per_step": 1e3 * cpu / steps, "first_run_cpu_s": first, "steps": steps}
    return out


# ------------------------------------------------------------------------------------ report


def run(campaign_path: Path, episodes: int, record_episodes: int, workers: int, chunk_size: int,
        backends: Sequence[str] = BACKEND_NAMES, progress: bool = True) -> dict[str, Any]:
    """Everything above; returns a JSON-able dict (plus row lists)."""
    campaign = load_campaign(campaign_path, episodes=episodes)
    results: dict[str, Any] = {"machine": machine_info(), "campaign": str(campaign_path),
                               "episodes_per_cell": episodes, "backends": list(backends)}
    # 1. recorded states: first cell, noise-free and with the campaign's noise
    cell = campaign.cells[0]
    replays = []
    for label, params in (("noise-free", without_noise(cell.params)), (f"noise {cell.params.noise.kind}", cell.params)):
        c = dataclasses.replace(cell, params=params)
        calls = record_solves(c, campaign.seed, list(range(record_episodes)))
        if progress:
            print(f"  recorded {len(calls)} solves ({cell.name}, {label})", file=sys.stderr)
        ref = {w: replay(params, "ipopt", calls, w) for w in (True, False)}
        for b in backends:
            for w in (True, False):
                r = ref[w] if b == "ipopt" else replay(params, b, calls, w, reference=ref[w]["_solutions"])
                r = {k: v for k, v in r.items() if k != "_solutions"}
                replays.append({"cell": cell.name, "states": label, **r})
    results["replays"] = replays
    # 2. paired closed-loop episodes
    paired = paired_episodes(campaign, backends, workers, chunk_size, progress)
    ref_rows = paired["by_backend"]["ipopt"]["rows"]
    results["paired"] = {
        "wall_s": paired["wall_s"], "workers": workers, "chunk_size": chunk_size,
        "throughput": {b: {k: v for k, v in d.items() if k != "rows"} for b, d in paired["by_backend"].items()},
        "agreement": {b: agreement(ref_rows, d["rows"], status_column="solver_statuses")
                      for b, d in paired["by_backend"].items() if b != "ipopt"},
    }
    results["_rows"] = {b: d["rows"] for b, d in paired["by_backend"].items()}
    # 3. JAX side
    results["jax_step"] = jax_step_overhead(cell, campaign.seed)
    return results


def _parser() -> argparse.ArgumentParser:
    p = section.parser("solver", "Measure the solver backends against each other.")
    p.add_argument("--campaign", type=Path, default=Path("campaigns/table2.toml"),
                   help="campaign whose cells are run (default: campaigns/table2.toml)")
    p.add_argument("--episodes", type=positive_int, default=2, help="paired episodes per cell and backend")
    p.add_argument("--record-episodes", type=positive_int, default=1,
                   help="reference episodes recorded for the per-solve timing (first cell)")
    p.add_argument("--workers", type=positive_int, default=None, help="worker processes (default: cores)")
    p.add_argument("--chunk-size", type=positive_int, default=4, help="episodes per chunk")
    section.add_output_options(p, also="; the JSON of the run goes beside it")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    def body() -> int:
        args = _parser().parse_args(argv)
        if not args.campaign.is_file():
            raise UserError(f"campaign file not found: {args.campaign}")
        workers = args.workers or executors.default_workers()
        results = run(args.campaign, args.episodes, args.record_episodes, workers, args.chunk_size)
        text = solver_report.markdown(results, section.command("solver", argv))
        print(text)
        if not args.no_write:
            section.write("solver", text, args.write)
            json_path = args.write.parent / "benchmarks-solver.json"
            json_path.write_text(solver_report.to_json(results))
            print(f"written: {args.write} (section benchmarks.solver), {json_path}", file=sys.stderr)
        return 0

    return section.run_main("solver", body)


if __name__ == "__main__":
    sys.exit(main())
