"""The host-side memory and bookkeeping of one episode (:class:`EpisodeState`, mutated by
:meth:`mcverify.control.planner.Planner.step`) and how a failed solve failed (:func:`failure_kind`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from mcverify.control.decision import Mode
from mcverify.control.margins import both_certified_infeasible, neither_solved, theorem5_margin
from mcverify.solver.mpc import MpcSolution, WarmStart
from mcverify.solver.status import SolveOutcome


@dataclass
class EpisodeState:
    """Host-side memory and bookkeeping of one episode (mutated by :meth:`Planner.step`)."""

    episode_id: int
    mode: Mode = Mode.OVERTAKE
    done: bool = False
    outcome: str = "running"
    end_time_s: float = math.nan
    overtake_time_s: float = math.nan
    steps: int = 0
    opp_detected_steps: int = 0
    q1_fail_steps: int = 0
    # q1_fail_steps split by how the solve failed (decision.FAILURE_KINDS; they sum to q1_fail_steps)
    q1_fail_certified_steps: int = 0
    q1_fail_presumed_steps: int = 0
    q1_fail_iteration_limit_steps: int = 0
    q1_fail_other_steps: int = 0
    q1_failures_in_a_row: int = 0  # failed Q1 solves in a row while overtaking (Mpc.abandon_rule)
    q1_held_steps: int = 0  # Q1 failed, Q2 solved, the abandonment rule waited: the last Q1 plan applied
    q2_fail_steps: int = 0
    both_infeasible_steps: int = 0
    # both_infeasible_steps split: both problems certified infeasible this step, or not (Theorem 5)
    both_certified_infeasible_steps: int = 0
    both_unsolved_uncertified_steps: int = 0
    both_infeasible_run: int = 0  # the current run of consecutive both-unsolved steps
    both_infeasible_longest_run: int = 0
    both_infeasible_longest_run_first_step: int = -1  # 0-based control step at which that run began
    theorem5_margin: float = math.nan  # the lowest theorem5_margin of a step (NaN before any dual-planner step)
    fallback_steps: int = 0
    held_steps: int = 0
    q2_driven_steps: int = 0
    q1_rescue_steps: int = 0
    cold_retries: int = 0
    presumed_infeasible_solves: int = 0
    q1_confirm_solves: int = 0  # presumed Q1 failures that would have turned back, solved in full first
    q1_confirm_solved: int = 0  # ... and solved there (the overtake goes on)
    hold_confirm_solves: int = 0  # presumed failures that would have held the plan (or braked), solved in full first
    hold_confirm_solved: int = 0  # ... and solved there (a plan was applied)
    infeasibility_audits: int = 0  # phase-1 certificates (the MPC-DC attempt plan) IPOPT re-checked
    infeasibility_audit_disagreements: int = 0  # ... and solved
    switched_to_q2_at_s: float = math.nan
    went_back_reason: str = ""
    went_back_q1_failure: str = ""  # the kind of the Q1 failure that abandoned the overtake
    first_unsafe_s: float = math.nan  # start of the control period in which the ego first left the safe set
    first_unsafe_cause: str = ""  # what drove it then (rollout.UNSAFE_CAUSES)
    opp_spawn_s: float = math.nan  # when veh_o appeared (Opposing.spawn; set by the rollout)
    table_one_rows: dict[int, int] = field(default_factory=dict)
    iterations: list[int] = field(default_factory=list)
    solve_times_s: list[float] = field(default_factory=list)
    statuses: dict[str, int] = field(default_factory=dict)  # str(SolveStatus) -> solves (solver_statuses)
    warm: dict[tuple[int, bool], WarmStart] = field(default_factory=dict)
    # problems IPOPT certified infeasible: key -> (fast-only solves since the last full attempt, steps
    # to wait before the next one) (Mpc.infeasible_recheck_steps, infeasible_recheck_max_steps)
    infeasible: dict[tuple[int, bool], tuple[int, int]] = field(default_factory=dict)
    held: tuple[np.ndarray, np.ndarray, float] | None = None  # last applied plan: (u_plan, dt_plan, t_solved)

    def record_solve(self, sol: MpcSolution) -> None:
        self.iterations.append(sol.iterations)
        self.solve_times_s.append(sol.solve_time_s)
        shown = str(sol.status)  # the stored form: "fallback:" / "presumed_infeasible:" + raw
        self.statuses[shown] = self.statuses.get(shown, 0) + 1
        self.cold_retries += int(sol.retried_cold)
        self.presumed_infeasible_solves += int(sol.status.presumed_infeasible)
        self.infeasibility_audits += int(sol.status.audited)
        self.infeasibility_audit_disagreements += int(sol.status.audit_disagreed)

    def count_q1_failure(self, sol: MpcSolution) -> None:
        """A failed Q1 solve: ``q1_fail_steps`` and its split by :func:`failure_kind`."""
        self.q1_fail_steps += 1
        kind = failure_kind(sol)
        if kind == "certified_infeasible":
            self.q1_fail_certified_steps += 1
        elif kind == "presumed_infeasible":
            self.q1_fail_presumed_steps += 1
        elif kind == "iteration_limit":
            self.q1_fail_iteration_limit_steps += 1
        else:
            self.q1_fail_other_steps += 1

    def count_theorem_five(self, q1: MpcSolution | None, q2: MpcSolution | None) -> None:
        """Theorem 5's check of one dual-planner step: neither Q1 nor Q2 solved, split by whether
        both failures are certificates of infeasibility, and the runs of such steps. ``q2`` is None
        when it was not solved because Q1 was (:attr:`Mpc.q2_solve`)."""
        both = neither_solved(q1, q2)
        self.both_infeasible_steps += int(both)
        margin = theorem5_margin(q1, q2)
        self.theorem5_margin = margin if math.isnan(self.theorem5_margin) else min(self.theorem5_margin, margin)
        if not both:
            self.both_infeasible_run = 0
            return
        certified = both_certified_infeasible(q1, q2)
        self.both_certified_infeasible_steps += int(certified)
        self.both_unsolved_uncertified_steps += int(not certified)
        self.both_infeasible_run += 1
        if self.both_infeasible_run > self.both_infeasible_longest_run:  # the first of equally long runs is kept
            self.both_infeasible_longest_run = self.both_infeasible_run
            self.both_infeasible_longest_run_first_step = self.steps - self.both_infeasible_run  # steps counts this one



def failure_kind(sol: MpcSolution) -> str:
    """How a failed solve failed (:data:`mcverify.control.decision.FAILURE_KINDS`): certified
    infeasible by IPOPT, presumed infeasible by the memo after such a certificate, out of iterations,
    or anything else (numerical failure, exception, invalid input, a converged solve that the
    feasibility check rejected)."""
    status = sol.status
    if status.certified_infeasible:
        return "certified_infeasible"
    if status.presumed_infeasible:
        return "presumed_infeasible"
    if status.outcome is SolveOutcome.ITERATION_LIMIT:
        return "iteration_limit"
    return "other"
