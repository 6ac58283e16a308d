"""Theorem 5 (thm.one_in_two_feasibility) at one control step, graded: how much room a solve of Q1 or
Q2 left (:func:`problem_margin`), the step's signed margin (:func:`theorem5_margin`, negative exactly
when neither problem was solved) and whether both failures are certificates of infeasibility."""

from __future__ import annotations

import math

from mcverify.solver.backends import MAX_VIOLATION
from mcverify.solver.mpc import MpcSolution


def neither_solved(q1: MpcSolution | None, q2: MpcSolution | None) -> bool:
    """Theorem 5's failure at one dual-planner step: Q2 was solved and failed, and Q1 failed or was
    not solved (``q2`` is None when Q1's success made it unnecessary, :attr:`Mpc.q2_solve`)."""
    return (q1 is None or not q1.success) and q2 is not None and not q2.success


def problem_margin(sol: MpcSolution) -> float:
    """How much room one solve of Q1 or Q2 leaves, signed: >= 0 exactly when it was solved
    (``sol.success``), < 0 exactly when it failed.

    Solved: the smallest slack of its barrier rows over the horizon at the returned plan
    (:attr:`MpcSolution.cbf_slack`, floored at 0: a solved plan may sit within the solver's tolerance
    of a row). It never overstates the room: every feasible plan of a problem with little room has a
    small slack, so a small value is necessary for being near infeasibility (not sufficient: a row
    the optimum presses against has slack 0 however large the feasible set).
    Failed: minus the largest constraint or bound violation of the point the solver returned
    (:attr:`MpcSolution.max_violation`), at least :data:`~mcverify.solver.backends.MAX_VIOLATION` (a
    solve that failed at a feasible point, e.g. out of iterations); -inf without a finite point
    (exception, invalid input). For a certificate of infeasibility this point minimises the
    violation locally (the restoration phase's l1 phase-1 problem), so the value is minus a local
    phase-1 infeasibility measure, in the max norm; for other failures it is a proxy that only keeps
    the sign. Units: those of the NLP's rows (the front CBF row 1/s, the opposing one m/s)."""
    if sol.success:
        slack = sol.cbf_slack
        return max(slack, 0.0) if math.isfinite(slack) else (math.inf if slack == math.inf else 0.0)
    violation = sol.max_violation
    if not math.isfinite(violation):
        return -math.inf
    return -max(violation, MAX_VIOLATION)


def theorem5_margin(q1: MpcSolution | None, q2: MpcSolution | None) -> float:
    """Theorem 5 at one dual-planner step as a signed margin: negative exactly when
    :func:`neither_solved` (Q2 solved and failed, and Q1 failed or not solved).

    The larger :func:`problem_margin` of the problems solved this step; +inf when Q2 was not solved
    and Q1 has no solution (no claim to check: only MPC-DC steps, which have no Q2)."""
    if q2 is None and not (q1 is not None and q1.success):
        return math.inf
    return max(problem_margin(s) for s in (q1, q2) if s is not None)


def both_certified_infeasible(q1: MpcSolution | None, q2: MpcSolution | None) -> bool:
    """:func:`neither_solved` with both failures certificates of infeasibility (IPOPT's, or the
    certificate the infeasibility policy accepts): a counter-example to Theorem 5 up to local
    infeasibility."""
    return (neither_solved(q1, q2) and q1 is not None and q1.status.certified_infeasible
            and q2 is not None and q2.status.certified_infeasible)
