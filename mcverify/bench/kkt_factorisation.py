"""The KKT factorisations of the C interior point compared on recorded solves: banded LU vs LDL^T.

Every solve of one or more recordings (:mod:`mcverify.bench.recorded_ipm`) is replayed twice in one
process, through the engine's IPM attempts (:meth:`~mcverify.bench.recorded_ipm.Replayer.engine_attempts`:
the warm attempts, then the cold one, up to the first converged), once with
``kkt_factorisation = "lu"`` (the default) and once with the variant ("ldlt" or "ldlt_curvature",
:class:`mcverify.solver.ipm.IpmOptions`). The two runs of a solve are interleaved (the order
alternates from solve to solve), so the CPU ratio is paired and robust to the machine's load.

Reported: CPU (``time.process_time``) per solve and per IPM iteration on each side and their
ratio; how many solves end with the same status sequence, the same final success (what decides
whether the engine hands the solve to IPOPT), the same iteration counts, and where both converged
the absolute difference of the returned points (largest, median, 99th percentile, how many within
1e-6 and 1e-3) and the largest of the multipliers; the
LDL^T path's counters (fallbacks to the LU, refinement steps, wrong-inertia factorisations, the
largest backward error of an accepted solve).

Run: ``python -m mcverify.bench.kkt_factorisation --recording FILE [--recording FILE ...]
[--variant ldlt] [--every K] [--json OUT]``; ``--only lu|ldlt|ldlt_curvature`` replays one side only
(to profile it, e.g. under ``perf record``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from mcverify.bench import recorded_ipm
from mcverify.solver.ipm import COLD, KKT_FACTORISATIONS, WARM_ATTEMPTS, IpmOptions, IpmResult

#: The engine's tolerance (``Mpc.tol``'s default; every Table IV cell keeps it).
TOL = 1e-6


@dataclass(frozen=True)
class Side:
    """One replay of one solve: statuses of the attempts, iterations, CPU seconds, the final result."""

    statuses: tuple[str, ...]
    iterations: int
    cpu_s: float
    last: IpmResult


def attempts(kkt: str, delta: float, tol: float = TOL) -> tuple[tuple[IpmOptions, ...], IpmOptions]:
    """The engine's warm attempts and cold attempt with the given factorisation."""
    warm = tuple(dataclasses.replace(o, tol=tol, kkt_factorisation=kkt, kkt_delta=delta) for o in WARM_ATTEMPTS)
    return warm, dataclasses.replace(COLD, tol=tol, kkt_factorisation=kkt, kkt_delta=delta)


def replay(rp: recorded_ipm.Replayer, s: recorded_ipm.RecordedSolve, warm: Sequence[IpmOptions],
           cold: IpmOptions) -> tuple[Side, list[IpmResult]]:
    cpu0 = time.process_time()
    runs = rp.engine_attempts(s, warm, cold)
    cpu = time.process_time() - cpu0
    return Side(tuple(r.status for r in runs), sum(r.iterations for r in runs), cpu, runs[-1]), runs


@dataclass
class Tally:
    """Sums over the compared solves (see :func:`compare`)."""

    solves: int = 0
    cpu_lu_s: float = 0.0
    cpu_variant_s: float = 0.0
    iterations_lu: int = 0
    iterations_variant: int = 0
    same_statuses: int = 0
    same_success: int = 0
    same_iterations: int = 0
    both_converged: int = 0
    max_abs_dw: float = 0.0
    max_abs_dlam: float = 0.0
    recorded_statuses_reproduced: int = 0
    fallbacks: int = 0
    refinements: int = 0
    wrong_inertia: int = 0
    factorisations_variant: int = 0
    factorisations_lu: int = 0
    ratio_max: float = 0.0
    differing: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    dw: list[float] = dataclasses.field(default_factory=list)  # max |w_lu - w_variant| per solve both converged

    def add(self, s: recorded_ipm.RecordedSolve, lu: Side, var: Side, lu_runs, var_runs) -> None:
        self.solves += 1
        self.cpu_lu_s += lu.cpu_s
        self.cpu_variant_s += var.cpu_s
        self.iterations_lu += lu.iterations
        self.iterations_variant += var.iterations
        self.same_statuses += lu.statuses == var.statuses
        self.same_success += lu.last.success == var.last.success
        self.same_iterations += [r.iterations for r in lu_runs] == [r.iterations for r in var_runs]
        recorded = tuple(t.split(":", 1)[1] for t in s.attempts)
        self.recorded_statuses_reproduced += recorded == lu.statuses
        self.fallbacks += sum(r.kkt_fallbacks for r in var_runs)
        self.refinements += sum(r.kkt_refinements for r in var_runs)
        self.wrong_inertia += sum(r.kkt_wrong_inertia for r in var_runs)
        self.factorisations_variant += sum(r.factorisations for r in var_runs)
        self.factorisations_lu += sum(r.factorisations for r in lu_runs)
        self.ratio_max = max(self.ratio_max, *(r.kkt_ratio_max for r in var_runs))
        if lu.last.success and var.last.success:
            self.both_converged += 1
            self.dw.append(float(np.max(np.abs(lu.last.w - var.last.w))))
            self.max_abs_dw = max(self.max_abs_dw, self.dw[-1])
            dlam = max(np.max(np.abs(lu.last.lam_g - var.last.lam_g)), np.max(np.abs(lu.last.lam_x - var.last.lam_x)))
            self.max_abs_dlam = max(self.max_abs_dlam, float(dlam))
        if lu.statuses != var.statuses and len(self.differing) < 20:
            self.differing.append({"lu": lu.statuses, "variant": var.statuses})

    def summary(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        dw = np.asarray(d.pop("dw") or [0.0])
        n = max(self.solves, 1)
        d.update(
            dw_median=float(np.median(dw)), dw_p99=float(np.percentile(dw, 99)),
            dw_within_1e_6=int(np.sum(dw <= 1e-6)), dw_within_1e_3=int(np.sum(dw <= 1e-3)),
            cpu_ms_per_solve_lu=1e3 * self.cpu_lu_s / n, cpu_ms_per_solve_variant=1e3 * self.cpu_variant_s / n,
            cpu_us_per_iteration_lu=1e6 * self.cpu_lu_s / max(self.iterations_lu, 1),
            cpu_us_per_iteration_variant=1e6 * self.cpu_variant_s / max(self.iterations_variant, 1),
            cpu_ratio_lu_over_variant=self.cpu_lu_s / self.cpu_variant_s if self.cpu_variant_s else float("nan"),
        )
        return d


def compare(paths: Sequence[str], variant: str = "ldlt", delta: float = 1e-9, every: int = 1,
            progress=print) -> dict[str, Any]:
    """Replay every ``every``-th solve of each recording with the LU and with ``variant``, interleaved."""
    from mcverify.solver import kernels

    lib = kernels.get_runtime_library("ipm").so_path
    lu_opts, var_opts = attempts("lu", delta), attempts(variant, delta)
    tally = Tally()
    for path in paths:
        rec = recorded_ipm.load(path)
        rp = recorded_ipm.Replayer(rec, lib)
        for k, s in enumerate(rec.solves[::every]):
            if k % 2 == 0:
                lu, lu_runs = replay(rp, s, *lu_opts)
                var, var_runs = replay(rp, s, *var_opts)
            else:
                var, var_runs = replay(rp, s, *var_opts)
                lu, lu_runs = replay(rp, s, *lu_opts)
            tally.add(s, lu, var, lu_runs, var_runs)
        progress(f"{path}: {tally.solves} solves so far", file=sys.stderr)
    out = tally.summary()
    out.update(variant=variant, delta=delta, every=every, recordings=list(paths))
    return out


def one_side(paths: Sequence[str], kkt: str, delta: float = 1e-9, every: int = 1) -> dict[str, Any]:
    """Only one factorisation's replay (for a profiler: ``perf record python -m ... --only lu``):
    solves, iterations, factorisations and CPU seconds."""
    from mcverify.solver import kernels

    lib = kernels.get_runtime_library("ipm").so_path
    opts = attempts(kkt, delta)
    out = {"kkt": kkt, "solves": 0, "iterations": 0, "factorisations": 0, "cpu_s": 0.0}
    for path in paths:
        rec = recorded_ipm.load(path)
        rp = recorded_ipm.Replayer(rec, lib)
        for s in rec.solves[::every]:
            side, runs = replay(rp, s, *opts)
            out["solves"] += 1
            out["iterations"] += side.iterations
            out["factorisations"] += sum(r.factorisations for r in runs)
            out["cpu_s"] += side.cpu_s
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m mcverify.bench.kkt_factorisation", description=__doc__.split("\n")[0])
    ap.add_argument("--recording", action="append", required=True, help="a recorded_ipm pickle (repeatable)")
    ap.add_argument("--variant", choices=[k for k in KKT_FACTORISATIONS if k != "lu"], default="ldlt")
    ap.add_argument("--delta", type=float, default=1e-9, help="the LDL^T's dual regularisation kkt_delta")
    ap.add_argument("--every", type=int, default=1, help="replay every K-th solve only")
    ap.add_argument("--json", help="write the summary here too")
    ap.add_argument("--only", choices=list(KKT_FACTORISATIONS), help="replay with this factorisation only (profiling)")
    args = ap.parse_args(argv)
    if args.only:
        out = one_side(args.recording, args.only, args.delta, args.every)
    else:
        out = compare(args.recording, args.variant, args.delta, args.every, progress=print)
    text = json.dumps(out, indent=1, default=str)
    print(text)
    if args.json:
        with open(args.json, "w") as fh:
            fh.write(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
