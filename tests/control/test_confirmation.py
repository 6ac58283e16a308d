"""The confirmation rule: a turn-back is never decided on a presumed Q1 failure (the infeasibility
memo's fast-path-only verdict). When one meets a solved Q2 while overtaking, Q1 is solved in full
(IPM, then IPOPT) first and that verdict decides. Scripted fake solvers, no solver."""

from __future__ import annotations

import dataclasses

import numpy as np

from mcverify.control.decision import Mode, Source
from mcverify.control.episode_state import EpisodeState
from mcverify.control.planner import Planner
from mcverify.model import ModelParams
from tests.control.test_abandon import CERT_FB, PRES, _solution

P = ModelParams()
FRONT = np.array([64.0, 0.0, 7.0])
EGO = np.array([10.0, 0.0, 0.0, 10.0])
OPP = np.array([200.0, -10.0])


class _FastAndFull:
    """Full solves answer from ``full[direction]`` in order, fast-path-only solves from
    ``fast[direction]`` (None: solved; a status: failed with it; past the end: solved for full
    solves, presumed infeasible for fast ones). Every call is logged as (direction, fast_only, warm)."""

    full: dict[int, list] = {}
    fast: dict[int, list] = {}
    log: list = []

    def __init__(self, params, structure):
        self.taken = {(d, f): 0 for d in (+1, -1) for f in (False, True)}

    def solve(self, ego, front, direction, level, warm=None, opp_xv=None, guess=None, fast_only=False):
        if opp_xv is None and self.with_opp_only:
            return _solution()
        _FastAndFull.log.append((direction, fast_only, warm))
        script = (self.fast if fast_only else self.full).get(direction, [])
        k = self.taken[(direction, fast_only)]
        self.taken[(direction, fast_only)] += 1
        if k >= len(script):
            return _solution(False, PRES) if fast_only else _solution()
        status = script[k]
        if status is None:
            sol = _solution()
            return dataclasses.replace(sol, warm=("warm", direction, k, fast_only))
        return _solution(False, status)

    with_opp_only = False

    def guess_from_plan(self, plan, opp_xv):
        return None


def _run(full: dict, fast: dict, steps: int, human: bool = False) -> tuple[EpisodeState, list]:
    _FastAndFull.full, _FastAndFull.fast, _FastAndFull.log = full, fast, []
    _FastAndFull.with_opp_only = human
    params = P
    if human:
        params = dataclasses.replace(P, opposing=dataclasses.replace(P.opposing, kind="human"))
    planner = Planner(params, solver_factory=_FastAndFull)
    st = EpisodeState(0)
    recs = [planner.step(st, 0.02 * i, EGO, FRONT, OPP if human else None, 0.0)[1] for i in range(steps)]
    return st, recs


# step 0 solved; step 1 both certified infeasible (the memo remembers both); step 2 Q1's fast path
# fails (presumed infeasible) while Q2's fast path solves: Algorithm 1 would turn back here.
FULL_Q1 = [None, CERT_FB]
FULL_Q2 = [None, CERT_FB]
FAST_Q2 = [None]


def test_a_presumed_failure_is_confirmed_and_overturned():
    st, recs = _run({+1: FULL_Q1 + [None], -1: FULL_Q2}, {-1: FAST_Q2}, steps=3)
    assert [r.source for r in recs] == [Source.Q1, Source.HELD, Source.Q1]
    assert st.mode is Mode.OVERTAKE and st.went_back_reason == ""
    assert (st.q1_confirm_solves, st.q1_confirm_solved) == (1, 1)
    assert (+1, False) not in st.infeasible  # a confirmed solution ends Q1's memo
    # step 2: Q1 fast-only (presumed), Q2 fast-only, then Q1 in full
    assert [(d, f) for d, f, _ in _FastAndFull.log[-3:]] == [(+1, True), (-1, True), (+1, False)]
    assert recs[2].q1.success and not st.q1_fail_presumed_steps


def test_a_confirmed_failure_turns_back_on_the_full_verdict():
    st, recs = _run({+1: FULL_Q1 + [CERT_FB], -1: FULL_Q2}, {-1: FAST_Q2}, steps=3)
    assert [r.source for r in recs] == [Source.Q1, Source.HELD, Source.Q2]
    assert st.mode is Mode.GO_BACK and st.went_back_q1_failure == "certified_infeasible"
    assert (st.q1_confirm_solves, st.q1_confirm_solved) == (1, 0)
    # the full attempt after the wait failed again: the memo's wait doubles
    assert st.infeasible[(+1, False)] == (0, 2 * P.mpc.infeasible_recheck_steps)


def test_the_confirmation_starts_from_the_presumed_solves_warm_start():
    # Q1's fast path solves at step 2 (a warm start), fails at step 3 (presumed); Q2 solves at 3
    st, recs = _run({+1: FULL_Q1 + [None], -1: FULL_Q2}, {+1: [None, PRES], -1: [None, None]}, steps=4)
    assert recs[2].source is Source.Q1 and recs[3].source is Source.Q1
    assert st.q1_confirm_solves == 1
    confirm = _FastAndFull.log[-1]
    assert confirm[:2] == (+1, False) and confirm[2] == ("warm", +1, 0, True)


def test_no_switch_confirmation_when_q2_fails_too_or_the_failure_was_a_full_one():
    # Q2's fast path fails at step 2 as well: nothing to turn back with, no switch to confirm (the plan
    # would be held instead, and that is confirmed: the tests below)
    st, recs = _run({+1: FULL_Q1 + [CERT_FB], -1: FULL_Q2 + [CERT_FB]}, {}, steps=3)
    assert st.q1_confirm_solves == 0 and recs[2].source is Source.HELD and st.mode is Mode.OVERTAKE
    # a Q1 failure IPOPT itself gave (no memo yet) decides at once, as before
    st, recs = _run({+1: [None, CERT_FB]}, {}, steps=2)
    assert st.q1_confirm_solves == 0 and st.mode is Mode.GO_BACK
    assert st.went_back_q1_failure == "certified_infeasible"


def test_table_one_row_zero_is_confirmed_too():
    st, recs = _run({+1: FULL_Q1 + [None], -1: FULL_Q2}, {-1: FAST_Q2}, steps=3, human=True)
    assert recs[2].source is Source.Q1 and st.mode is Mode.OVERTAKE
    assert st.q1_confirm_solves == 1 and recs[2].table_row != 0


# ----------------------------------------------------------------------- the hold confirmation
# step 2: both fast paths fail (presumed infeasible): Algorithm 1 would hold the last plan on verdicts
# IPOPT never gave. The mode's own problem (Q1, overtaking) is solved in full first, then Q2.


def test_a_hold_on_presumed_failures_is_confirmed_and_overturned():
    st, recs = _run({+1: FULL_Q1 + [None], -1: FULL_Q2}, {}, steps=3)
    assert [r.source for r in recs] == [Source.Q1, Source.HELD, Source.Q1] and st.mode is Mode.OVERTAKE
    assert (st.hold_confirm_solves, st.hold_confirm_solved) == (1, 1) and st.q1_confirm_solves == 0
    # Q1 fast-only, Q2 fast-only, then Q1 in full; Q2 is not asked again once Q1 has a plan
    assert [(d, f) for d, f, _ in _FastAndFull.log[-3:]] == [(+1, True), (-1, True), (+1, False)]
    assert (+1, False) not in st.infeasible and (-1, False) in st.infeasible  # Q1's memo ends, Q2's goes on
    assert recs[2].q1.success and not st.q1_fail_presumed_steps


def test_a_hold_confirmation_may_turn_back_on_full_verdicts():
    # Q1's full solve fails again (certified), Q2's full solve finds a plan: the turn-back rests on IPOPT
    st, recs = _run({+1: FULL_Q1 + [CERT_FB], -1: FULL_Q2 + [None]}, {}, steps=3)
    assert recs[2].source is Source.Q2 and st.mode is Mode.GO_BACK
    assert st.went_back_q1_failure == "certified_infeasible"
    assert (st.hold_confirm_solves, st.hold_confirm_solved) == (2, 1)
    assert st.infeasible[(+1, False)] == (0, 2 * P.mpc.infeasible_recheck_steps)  # Q1's wait doubles


def test_a_confirmed_hold_holds_and_both_waits_double():
    st, recs = _run({+1: FULL_Q1 + [CERT_FB], -1: FULL_Q2 + [CERT_FB]}, {}, steps=3)
    assert recs[2].source is Source.HELD and st.mode is Mode.OVERTAKE
    assert (st.hold_confirm_solves, st.hold_confirm_solved) == (2, 0)
    assert st.infeasible[(+1, False)] == st.infeasible[(-1, False)] == (0, 2 * P.mpc.infeasible_recheck_steps)
    assert st.both_certified_infeasible_steps == 2  # steps 1 and 2, both now on IPOPT's certificates


def test_a_hold_confirmation_starts_from_the_presumed_solves_warm_start():
    # both fast paths solve at step 2 (warm starts) and fail at step 3: each full solve starts where its
    # presumed solve started
    st, recs = _run({+1: FULL_Q1 + [CERT_FB], -1: FULL_Q2 + [None]}, {+1: [None, PRES], -1: [None, PRES]}, steps=4)
    assert recs[3].source is Source.Q2 and st.hold_confirm_solves == 2
    assert [entry[2] for entry in _FastAndFull.log[-2:]] == [("warm", +1, 0, True), ("warm", -1, 0, True)]
