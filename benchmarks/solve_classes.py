"""Where a closed loop's solver CPU goes, by solve class (for ``python -m benchmarks.engine``).

A :class:`TimedSolver` wraps a solver of the planner and adds every solve's CPU time
(``time.process_time``, seconds) to a :class:`ClassTally` under its :class:`SolveClass`, decided from
the returned :class:`~mcverify.solver.mpc.MpcSolution` alone, so the same classes apply to the
engine (fast path + IPOPT fallback) and to the IPOPT loops.
"""

from __future__ import annotations

import enum
import time
from collections import Counter
from dataclasses import dataclass, field

from mcverify.solver.mpc import MpcSolution
from mcverify.solver.status import SolveOutcome


class SolveClass(enum.Enum):
    """What a solve was, by who answered and how."""

    CONVERGED = "converged"  # solved by the first path (engine: the IPM; IPOPT loops: the first attempt)
    RESCUED = "rescued"  # solved, but only by IPOPT after the first path failed (fallback or cold retry)
    CERTIFIED_INFEASIBLE = "certified infeasible"  # failed; IPOPT's full attempt reported local infeasibility
    # failed on the short attempt while the memo presumes it (or, booked by the solver before the planner
    # names it "unread:", a Q2 the step's decision ignored, Mpc.q2_solve = "fast_when_unneeded")
    PRESUMED_INFEASIBLE = "presumed infeasible"
    OTHER_FAILURE = "other failure"  # failed otherwise (iteration limit, line search, exception ...)


def classify(sol: MpcSolution) -> SolveClass:
    if sol.success:
        return SolveClass.RESCUED if (sol.status.fallback or sol.retried_cold) else SolveClass.CONVERGED
    if sol.status.presumed_infeasible:
        return SolveClass.PRESUMED_INFEASIBLE
    if sol.status.outcome is SolveOutcome.INFEASIBLE:
        return SolveClass.CERTIFIED_INFEASIBLE
    return SolveClass.OTHER_FAILURE


@dataclass
class ClassTally:
    """Solves and CPU seconds per :class:`SolveClass` (summed over every wrapped solver)."""

    count: Counter = field(default_factory=Counter)
    cpu_s: Counter = field(default_factory=Counter)

    def add(self, cls: SolveClass, cpu_s: float) -> None:
        self.count[cls] += 1
        self.cpu_s[cls] += cpu_s

    def merge(self, other: ClassTally) -> None:
        self.count.update(other.count)
        self.cpu_s.update(other.cpu_s)

    @property
    def total_cpu_s(self) -> float:
        return float(sum(self.cpu_s.values()))

    def as_dict(self) -> dict[str, dict[str, float]]:
        """``{class value: {"solves": n, "cpu_s": s, "ms_per_solve": ms}}`` in enum order."""
        return {c.value: {"solves": self.count[c], "cpu_s": self.cpu_s[c],
                          "ms_per_solve": 1e3 * self.cpu_s[c] / self.count[c] if self.count[c] else 0.0}
                for c in SolveClass}


class TimedSolver:
    """A planner's solver whose every ``solve`` is timed into ``tally`` by class; the rest delegates."""

    def __init__(self, solver, tally: ClassTally) -> None:
        self.solver = solver
        self.tally = tally

    def solve(self, *args, **kwargs) -> MpcSolution:
        t0 = time.process_time()
        sol = self.solver.solve(*args, **kwargs)
        self.tally.add(classify(sol), time.process_time() - t0)
        return sol

    def __getattr__(self, name):
        return getattr(self.solver, name)
