"""Abandoning the overtake on evidence (Mpc.abandon_rule) and counting failures by kind (Theorem 5
split): the decision logic on constructed step sequences, with scripted fake solutions (no solver)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mcverify.campaign.validate import validate_params
from mcverify.control.decision import Mode, Source, abandon_overtake, decide
from mcverify.control.episode_state import EpisodeState, failure_kind
from mcverify.control.planner import Planner
from mcverify.errors import CampaignError
from mcverify.model import ModelParams
from mcverify.solver.mpc import MpcSolution
from mcverify.solver.status import SolveOutcome, SolveRoute, SolveStatus

P = ModelParams()
FRONT = np.array([64.0, 0.0, 7.0])
EGO = np.array([10.0, 0.0, 0.0, 10.0])
OPP = np.array([200.0, -10.0])

#: Scripted failures: the status of one failed solve.
CERT = SolveStatus.ipopt("Infeasible_Problem_Detected")
CERT_FB = SolveStatus.ipopt("Infeasible_Problem_Detected").via(SolveRoute.FALLBACK)
PRES = SolveStatus.ipm("Max_Iterations").via(SolveRoute.PRESUMED)
ITER = SolveStatus.ipopt("Maximum_Iterations_Exceeded")
ITER_IPM = SolveStatus.ipm("Max_Iterations")
NUM = SolveStatus.ipopt("Restoration_Failed")
REJECTED = SolveStatus.ipopt("Solve_Succeeded")  # converged, but the feasibility check rejected the plan


def _solution(success: bool = True, status: SolveStatus | None = None) -> MpcSolution:
    n = P.mpc.horizon
    x = np.zeros((n + 1, 4))
    return MpcSolution(
        success=success, status=status or SolveStatus("fake", SolveOutcome.SOLVED), iterations=1, solve_time_s=0.0,
        total_time_s=1.0, x_plan=x, u_plan=np.tile([1.0, 0.0], (n, 1)), dt_plan=np.full(n, 1.0 / n), warm=None,
        opp_plan=np.tile([100.0, -10.0], (n + 1, 1)),
    )


class _Scripted:
    """A solver whose k-th solve of each direction returns script[direction][k] (None: solved; a
    SolveStatus: failed with it; past the end: solved). Only solves with veh_o consume the script
    when ``with_opp`` (the plain pre-solve of the two-stage cold start is always solved)."""

    script: dict[int, list[SolveStatus | None]] = {}
    with_opp = False

    def __init__(self, params, structure):
        self.calls = {+1: 0, -1: 0}

    def solve(self, ego, front, direction, level, warm=None, opp_xv=None, guess=None, fast_only=False):
        if self.with_opp and opp_xv is None:
            return _solution()
        k = self.calls[direction]
        self.calls[direction] += 1
        steps = self.script.get(direction, [])
        status = steps[k] if k < len(steps) else None
        return _solution() if status is None else _solution(False, status)

    def guess_from_plan(self, plan, opp_xv):
        return None


def _run(q1: list, q2: list | None = None, *, rule: str = "first_failure", k: int = 3, human: bool = False,
         steps: int | None = None) -> tuple[EpisodeState, list]:
    _Scripted.script = {+1: list(q1), -1: list(q2 or [])}
    _Scripted.with_opp = human
    mpc = dataclasses.replace(P.mpc, abandon_rule=rule, abandon_after_failures=k, infeasible_recheck_steps=1,
                              infeasible_recheck_max_steps=1)
    params = dataclasses.replace(P, mpc=mpc)
    if human:
        params = dataclasses.replace(params, opposing=dataclasses.replace(P.opposing, kind="human"))
    planner = Planner(params, solver_factory=_Scripted)
    st = EpisodeState(0)
    records = []
    for i in range(steps or len(q1) + 1):
        _, rec = planner.step(st, 0.02 * i, EGO, FRONT, OPP if human else None, 0.0)
        records.append(rec)
    return st, records


# ------------------------------------------------------------------------------ the rule itself


def test_abandon_rules_on_the_evidence():
    assert abandon_overtake("first_failure", 1, "iteration_limit", 3)
    assert not abandon_overtake("consecutive", 2, "certified_infeasible", 3)
    assert abandon_overtake("consecutive", 3, "other", 3)
    for kind, fires in (("certified_infeasible", True), ("presumed_infeasible", True), ("iteration_limit", False),
                        ("other", False)):
        assert abandon_overtake("certified", 1, kind, 3) is fires
    with pytest.raises(ValueError, match="unknown abandon rule"):
        abandon_overtake("never", 1, "other", 3)


def test_decide_holds_the_q1_plan_while_the_rule_waits():
    assert decide(Mode.OVERTAKE, False, True, abandon=False) == (Mode.OVERTAKE, Source.HELD)
    assert decide(Mode.OVERTAKE, False, True) == (Mode.GO_BACK, Source.Q2)  # the default: Algorithm 1
    assert decide(Mode.OVERTAKE, False, False, abandon=False) == (Mode.OVERTAKE, Source.FALLBACK)
    assert decide(Mode.GO_BACK, True, True, abandon=False) == (Mode.GO_BACK, Source.Q2)


def test_failure_kinds():
    assert [failure_kind(_solution(False, s)) for s in (CERT, CERT_FB, PRES, ITER, ITER_IPM, NUM, REJECTED)] == [
        "certified_infeasible", "certified_infeasible", "presumed_infeasible", "iteration_limit", "iteration_limit",
        "other", "other"]


# --------------------------------------------------------------------- sequences through the planner


def test_first_failure_abandons_on_an_iteration_limit():
    st, recs = _run([None, ITER])
    assert [r.source for r in recs] == [Source.Q1, Source.Q2, Source.Q2]
    assert st.mode is Mode.GO_BACK and st.switched_to_q2_at_s == pytest.approx(0.02)
    assert st.went_back_reason == "q1_not_solved" and st.went_back_q1_failure == "iteration_limit"
    assert st.q1_held_steps == 0 and st.held_steps == 0


def test_consecutive_needs_k_failures_in_a_row():
    # failures at 1-2, solved at 3 (the count restarts), failures at 4-6: abandoned at the third (6)
    st, recs = _run([None, ITER, NUM, None, ITER, CERT, ITER], rule="consecutive", k=3)
    assert [r.source for r in recs] == [Source.Q1, Source.HELD, Source.HELD, Source.Q1, Source.HELD, Source.HELD,
                                        Source.Q2, Source.Q2]
    assert st.mode is Mode.GO_BACK and st.switched_to_q2_at_s == pytest.approx(0.02 * 6)
    assert st.q1_held_steps == 4 and st.held_steps == 4 and st.fallback_steps == 0
    assert st.went_back_q1_failure == "iteration_limit"


def test_consecutive_never_fires_on_isolated_failures():
    st, recs = _run([None, ITER, None, ITER, None, NUM, None], rule="consecutive", k=2)
    assert st.mode is Mode.OVERTAKE and st.went_back_reason == "" and st.q1_held_steps == 3
    assert st.q1_fail_steps == 3


def test_certified_ignores_budget_and_numerical_failures():
    st, recs = _run([None, ITER, NUM, REJECTED, ITER_IPM, CERT_FB], rule="certified")
    assert [r.source for r in recs[:5]] == [Source.Q1] + [Source.HELD] * 4
    assert recs[5].source is Source.Q2 and st.mode is Mode.GO_BACK
    assert st.went_back_q1_failure == "certified_infeasible"
    assert (st.q1_fail_certified_steps, st.q1_fail_presumed_steps, st.q1_fail_iteration_limit_steps,
            st.q1_fail_other_steps) == (1, 0, 2, 2)


def test_certified_counts_a_presumed_infeasibility_once_a_full_solve_confirms_it():
    # the presumed failure at step 2 meets a solved Q2: Q1 is solved in full first (the confirmation
    # rule, test_confirmation.py), and that full solve's certificate abandons
    st, _ = _run([None, ITER, PRES, CERT_FB], rule="certified")
    assert st.mode is Mode.GO_BACK and st.went_back_q1_failure == "certified_infeasible"
    assert st.q1_confirm_solves == 1 and st.q1_fail_presumed_steps == 0


def test_a_waiting_rule_abandons_when_there_is_no_q1_plan_to_hold():
    # Q1 fails at the very first step: nothing to hold, so the ego goes back as Algorithm 1 says
    st, recs = _run([ITER], rule="certified", steps=1)
    assert recs[0].source is Source.Q2 and st.mode is Mode.GO_BACK
    # the held plan (1 s, 50 steps) used up: the rule no longer waits
    st, recs = _run([None] + [ITER] * 60, rule="certified")
    assert st.mode is Mode.GO_BACK and st.q1_held_steps == 50
    assert st.switched_to_q2_at_s == pytest.approx(0.02 * 51)


def test_table_one_row_zero_waits_for_the_rule_with_a_human_driver():
    st, recs = _run([None, ITER, ITER, ITER], rule="consecutive", k=3, human=True)
    assert [r.table_row for r in recs] == [4, 0, 0, 0, -1]
    assert [r.source for r in recs] == [Source.Q1, Source.HELD, Source.HELD, Source.Q2, Source.Q2]
    assert st.went_back_reason == "table_one_row_0" and st.went_back_q1_failure == "iteration_limit"
    assert st.q1_held_steps == 2
    st, recs = _run([None, ITER], human=True)  # the default: row 0 goes back at once
    assert [r.source for r in recs] == [Source.Q1, Source.Q2, Source.Q2] and st.went_back_reason == "table_one_row_0"


# ----------------------------------------------------------------------------------- Theorem 5 split


def test_both_unsolved_steps_split_by_certificate_and_longest_run():
    # overtaking: Q1 and Q2 both fail at steps 1-3 (certified, certified, Q2 out of iterations),
    # solved at 4, both fail again at 5, Q1 only presumed: the plan would be held on a presumed verdict,
    # so Q1 is solved in full there (the hold confirmation) and runs out of iterations (Q2 failed too: the plan
    # is held); Q1 runs out again at 6, where Q2 solves, and the default rule abandons there
    q1 = [None, CERT, CERT_FB, CERT, None, PRES, ITER, ITER]
    q2 = [None, CERT, CERT, ITER, None, CERT]
    st, recs = _run(q1, q2)
    assert st.both_infeasible_steps == 4
    assert st.both_certified_infeasible_steps == 2 and st.both_unsolved_uncertified_steps == 2
    # the per-step test the trajectory's `both_certified` column records agrees with the counts
    from mcverify.control.margins import both_certified_infeasible, neither_solved  # noqa: PLC0415
    assert [both_certified_infeasible(r.q1, r.q2) for r in recs][:6] == [False, True, True, False, False, False]
    assert sum(neither_solved(r.q1, r.q2) for r in recs) == st.both_infeasible_steps
    assert st.both_infeasible_longest_run == 3
    assert st.q1_fail_steps == 5 and (st.q1_fail_certified_steps, st.q1_fail_presumed_steps,
                                      st.q1_fail_iteration_limit_steps, st.q1_fail_other_steps) == (3, 0, 2, 0)
    assert st.went_back_q1_failure == "iteration_limit" and st.mode is Mode.GO_BACK
    assert (st.hold_confirm_solves, st.hold_confirm_solved) == (1, 0) and st.switched_to_q2_at_s == 0.02 * 6


def test_validation_names_the_field():
    for field, value in (("abandon_rule", "never"), ("abandon_after_failures", 0)):
        p = dataclasses.replace(P, mpc=dataclasses.replace(P.mpc, **{field: value}))
        with pytest.raises(CampaignError, match=f"mpc.{field}"):
            validate_params(p, "c.toml")
