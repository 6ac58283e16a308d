"""Wasted warm attempts of the ipm backend, measured on recorded solves (report only).

:meth:`mcverify.solver.backends.IpmBackend.solve` tries, for a warm-started problem, the two
:data:`~mcverify.solver.ipm.WARM_ATTEMPTS` and then the cold start, up to the first converged one.
A failed attempt is CPU spent for nothing. Two measurements on recordings of
:mod:`mcverify.bench.recorded_ipm`:

1. :func:`attempt_costs`: every warm-started solve (every ``every``-th) replayed through the
   attempts: count and CPU (``time.process_time``) of each attempt by outcome, and the iteration
   counts of the converged ones (a lower iteration limit is free only if no attempt converges
   above it).
2. :func:`skip_rules`: from the recorded attempt statuses alone, how often a cheaper rule would
   skip warm attempt 1, and in how many of those it had converged (there the rule changes the
   answer: the next attempt starts elsewhere and may return another point or fail). The rules:
   "prev_cold" (the previous solve of the same problem needed the cold attempt) and
   "prev_not_warm1" (the previous solve's warm attempt 1 failed).

Run: ``python -m mcverify.bench.warm_attempts --recording FILE [--recording FILE ...] [--every K]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from collections import Counter
from collections.abc import Sequence
from typing import Any

import numpy as np

from mcverify.bench import recorded_ipm
from mcverify.solver.ipm import COLD, WARM_ATTEMPTS

#: The engine's tolerance (``Mpc.tol``'s default; every Table IV cell keeps it).
TOL = 1e-6


def attempt_costs(paths: Sequence[str], every: int = 1) -> dict[str, Any]:
    """Per attempt and outcome ("attempt1:ok", "attempt1:Max_Iterations", ...): count and CPU
    seconds; per attempt: iterations of the converged runs (max, 99th percentile, how many above
    15 and 20)."""
    from mcverify.solver import kernels

    lib = kernels.get_runtime_library("ipm").so_path
    runs = [(dataclasses.replace(o, tol=TOL), True) for o in WARM_ATTEMPTS]
    runs.append((dataclasses.replace(COLD, tol=TOL), False))
    count, cpu = Counter(), Counter()
    converged: dict[int, list[int]] = {k: [] for k in range(1, len(runs) + 1)}
    for path in paths:
        rec = recorded_ipm.load(path)
        rp = recorded_ipm.Replayer(rec, lib)
        for s in rec.solves[::every]:
            if s.warm is None:
                continue
            for k, (opts, warm) in enumerate(runs, 1):
                cpu0 = time.process_time()
                r = rp.solve(s, opts, warm)
                key = f"attempt{k}:{'ok' if r.success else r.status}"
                cpu[key] += time.process_time() - cpu0
                count[key] += 1
                if r.success:
                    converged[k].append(r.iterations)
                    break
    total = sum(cpu.values())
    iters = {}
    for k, v in converged.items():
        a = np.asarray(v)
        if a.size:
            iters[f"attempt{k}"] = {"converged": int(a.size), "max": int(a.max()), "p99": float(np.percentile(a, 99)),
                                    "above_15": int((a > 15).sum()), "above_20": int((a > 20).sum())}
    return {"count": dict(count), "cpu_s": dict(cpu), "cpu_share": {k: v / total for k, v in cpu.items()},
            "converged_iterations": iters}


def skip_rules(paths: Sequence[str]) -> dict[str, Any]:
    """Warm attempt 1's recorded outcomes and the two skip rules: fires / saves (warm attempt 1
    had failed anyway: the final answer is unchanged) / would_change (it had converged)."""
    out: dict[str, Any] = {"warm_started": 0, "warm1_failed": 0, "warm1_status": Counter(), "rules": Counter()}
    for path in paths:
        rec = recorded_ipm.load(path)
        prev: dict[int, recorded_ipm.RecordedSolve] = {}
        for s in rec.solves:
            p = prev.get(s.problem)
            prev[s.problem] = s
            if s.warm is None:
                continue
            ok1 = s.attempts[0].endswith(":Converged")
            out["warm_started"] += 1
            out["warm1_failed"] += not ok1
            out["warm1_status"][s.attempts[0].split(":", 1)[1]] += 1
            if p is None:
                continue
            fires = {"prev_cold": any(t.startswith("cold") for t in p.attempts),
                     "prev_not_warm1": not p.attempts[0].endswith(":Converged")}
            for rule, fired in fires.items():
                if fired:
                    out["rules"][f"{rule}:fires"] += 1
                    out["rules"][f"{rule}:{'would_change' if ok1 else 'saves'}"] += 1
    out["warm1_status"], out["rules"] = dict(out["warm1_status"]), dict(out["rules"])
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m mcverify.bench.warm_attempts", description=__doc__.split("\n")[0])
    ap.add_argument("--recording", action="append", required=True, help="a recorded_ipm pickle (repeatable)")
    ap.add_argument("--every", type=int, default=1, help="replay every K-th solve only (attempt costs)")
    args = ap.parse_args(argv)
    out = {"skip_rules": skip_rules(args.recording), "attempt_costs": attempt_costs(args.recording, args.every)}
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
