"""The status of one solve, typed: what the solver reported, how it ended, and which path answered.

A :class:`SolveStatus` replaces the status strings with prefixes that callers parsed. It keeps the
backend's own status text (``raw``: IPOPT's ``return_status``, ``"IPM_<status>"``,
``"exception: <msg>"``, ``"invalid_input: <msg>"``) for display, classifies it once
(:class:`SolveOutcome`), and says which path produced it (:class:`SolveRoute`).

``str(status)`` renders the form stored in episode rows (the keys of ``solver_statuses``) and shown
in benchmarks: ``raw`` for the backend's own path, ``"fallback:<raw>"`` for a solve the fast path
handed to the IPOPT reference, ``"presumed_infeasible:<raw>"`` for a fast-path-only failure,
``"unread:<raw>"`` for a fast-path-only failure of a Q2 the step's decision ignored (``Mpc.q2_solve``),
``"audited:<raw>"`` / ``"audit_disagreed:<raw>"`` for a C certificate of infeasibility that IPOPT
re-checked as the scheduled auditor (the MPC-DC attempt plan's phase-1 certificates) and failed on too / solved.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


class SolveOutcome(enum.Enum):
    """How a solve ended, as the solver saw it (before the common feasibility check)."""

    SOLVED = "solved"  # IPOPT "Solve_Succeeded", the IPM "Converged"
    SOLVED_ACCEPTABLE = "solved_acceptable"  # IPOPT "Solved_To_Acceptable_Level"
    INFEASIBLE = "infeasible"  # IPOPT's certificate of (local) infeasibility
    ITERATION_LIMIT = "iteration_limit"  # IPOPT or IPM iteration limit
    INVALID_INPUT = "invalid_input"  # non-finite parameters: nothing was solved
    EXCEPTION = "exception"  # the solver raised
    FAILED = "failed"  # any other failure (line search, restoration, non-finite values, ...)

    @property
    def converged(self) -> bool:
        """The solver reports a solution (the common feasibility check may still reject it)."""
        return self in (SolveOutcome.SOLVED, SolveOutcome.SOLVED_ACCEPTABLE)


class SolveRoute(enum.Enum):
    """Which path of the backend produced the result."""

    PRIMARY = "primary"  # the backend's own path: IPOPT for "ipopt", the IPM for "ipm"
    FALLBACK = "fallback"  # the IPM failed and the IPOPT reference path answered
    PRESUMED = "presumed"  # fast path only (a problem IPOPT certified infeasible): no reference tried
    UNREAD = "unread"  # fast path only (a Q2 the step's decision ignores, Mpc.q2_solve): no reference tried
    # phase-1 certificates (mcverify.solver.attempts): a C certificate IPOPT re-checked as the scheduled auditor and
    # also failed on (AUDITED), or solved (AUDIT_DISAGREED: the result is IPOPT's solution)
    AUDITED = "audited"
    AUDIT_DISAGREED = "audit_disagreed"


#: IPOPT ``return_status`` values with their own outcome; any other is :attr:`SolveOutcome.FAILED`.
IPOPT_OUTCOMES: dict[str, SolveOutcome] = {
    "Solve_Succeeded": SolveOutcome.SOLVED,
    "Solved_To_Acceptable_Level": SolveOutcome.SOLVED_ACCEPTABLE,
    "Infeasible_Problem_Detected": SolveOutcome.INFEASIBLE,
    "Maximum_Iterations_Exceeded": SolveOutcome.ITERATION_LIMIT,
}
#: IPM status names (:data:`mcverify.solver.ipm.STATUS`) with their own outcome; others FAILED.
IPM_OUTCOMES: dict[str, SolveOutcome] = {
    "Converged": SolveOutcome.SOLVED,
    "Max_Iterations": SolveOutcome.ITERATION_LIMIT,
    "Infeasible_Problem_Detected": SolveOutcome.INFEASIBLE,  # the restoration phase's certificate
}
#: Prefix of ``raw`` for an IPM status (the IPM's names differ from IPOPT's).
IPM_RAW_PREFIX = "IPM_"
#: Rendered prefixes of the routes other than PRIMARY (stored in ``solver_statuses``).
ROUTE_PREFIXES: dict[SolveRoute, str] = {
    SolveRoute.PRIMARY: "",
    SolveRoute.FALLBACK: "fallback:",
    SolveRoute.PRESUMED: "presumed_infeasible:",
    SolveRoute.UNREAD: "unread:",
    SolveRoute.AUDITED: "audited:",
    SolveRoute.AUDIT_DISAGREED: "audit_disagreed:",
}


@dataclass(frozen=True)
class SolveStatus:
    """One solve's status: ``raw`` backend text (display), ``outcome`` and ``route``."""

    raw: str
    outcome: SolveOutcome
    route: SolveRoute = SolveRoute.PRIMARY

    # ------------------------------------------------------------------ constructors
    @classmethod
    def ipopt(cls, return_status: str) -> SolveStatus:
        """IPOPT's ``return_status`` (the reference path)."""
        return cls(return_status, IPOPT_OUTCOMES.get(return_status, SolveOutcome.FAILED))

    @classmethod
    def ipm(cls, ipm_status: str) -> SolveStatus:
        """The IPM's status name (``"Converged"``, ``"Max_Iterations"``, ...); raw ``"IPM_<name>"``."""
        return cls(IPM_RAW_PREFIX + ipm_status, IPM_OUTCOMES.get(ipm_status, SolveOutcome.FAILED))

    @classmethod
    def exception(cls, message: str) -> SolveStatus:
        """The solver raised; ``message``: the exception's first line."""
        return cls(f"exception: {message}".splitlines()[0], SolveOutcome.EXCEPTION)

    @classmethod
    def invalid_input(cls, message: str) -> SolveStatus:
        """Nothing was solved: the inputs were not usable."""
        return cls(f"invalid_input: {message}", SolveOutcome.INVALID_INPUT)

    def via(self, route: SolveRoute) -> SolveStatus:
        """The same status, produced by ``route``."""
        return SolveStatus(self.raw, self.outcome, route)

    # ------------------------------------------------------------------ questions
    @property
    def fallback(self) -> bool:
        """The fast path failed and the IPOPT reference answered."""
        return self.route is SolveRoute.FALLBACK

    @property
    def presumed_infeasible(self) -> bool:
        """A fast-path-only failure of a problem presumed infeasible (not certified by IPOPT)."""
        return self.route is SolveRoute.PRESUMED

    @property
    def unread(self) -> bool:
        """A fast-path-only failure of a Q2 that the step's decision ignored (``Mpc.q2_solve``)."""
        return self.route is SolveRoute.UNREAD

    @property
    def audited(self) -> bool:
        """A C certificate of infeasibility that IPOPT re-checked (agreeing or not)."""
        return self.route in (SolveRoute.AUDITED, SolveRoute.AUDIT_DISAGREED)

    @property
    def audit_disagreed(self) -> bool:
        """IPOPT solved a problem the C restoration phase had certified infeasible."""
        return self.route is SolveRoute.AUDIT_DISAGREED

    @property
    def certified_infeasible(self) -> bool:
        """Local infeasibility certified: by IPOPT (directly or as the fast path's fallback) or, with
        phase-1 certificates (the MPC-DC attempt plan), by the C restoration phase from every start it was given."""
        return self.outcome is SolveOutcome.INFEASIBLE and self.route not in (SolveRoute.PRESUMED, SolveRoute.UNREAD)

    def __str__(self) -> str:
        return ROUTE_PREFIXES[self.route] + self.raw
