"""Mpc.q2_solve = "when_needed": Q2 left unsolved only where Algorithm 1 would not read it (scripted
fake solutions per control step, no solver)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mcverify.campaign.validate import validate_params
from mcverify.control.decision import Mode, Source
from mcverify.control.episode_state import EpisodeState
from mcverify.control.planner import Planner
from mcverify.errors import CampaignError
from mcverify.model import ModelParams
from mcverify.solver.status import SolveRoute, SolveStatus
from tests.control.test_abandon import CERT, FRONT, ITER, OPP, P, _solution

EGO = np.array([10.0, 0.0, 0.0, 10.0])


class _PerStep:
    """Q1's and Q2's outcome scripted per control step (``q1[step]``, ``q2[step]``: None solved, a
    SolveStatus failed with it; with ``fast_only`` a failure is the IPM's, as the backend returns it);
    every solve is logged as (step, direction, with veh_o) and its fast_only flag in ``fast``."""

    q1: list = []
    q2: list = []
    step = 0
    log: list[tuple[int, int, bool]] = []
    fast: list[bool] = []

    def __init__(self, params, structure):
        pass

    def solve(self, ego, front, direction, level, warm=None, opp_xv=None, guess=None, fast_only=False):
        _PerStep.log.append((_PerStep.step, direction, opp_xv is not None))
        _PerStep.fast.append(fast_only)
        script = _PerStep.q1 if direction > 0 else _PerStep.q2
        status = script[_PerStep.step] if _PerStep.step < len(script) else None
        if status is not None and fast_only:
            status = SolveStatus.ipm("Max_Iterations").via(SolveRoute.PRESUMED)
        return _solution() if status is None else _solution(False, status)

    def guess_from_plan(self, plan, opp_xv):
        return None


def _run(policy: str, q1: list, q2: list, *, opposing: str = "none") -> tuple[EpisodeState, list, list]:
    _PerStep.q1, _PerStep.q2, _PerStep.log, _PerStep.fast = list(q1), list(q2), [], []
    params = dataclasses.replace(P, mpc=dataclasses.replace(P.mpc, q2_solve=policy, infeasible_recheck_steps=1,
                                                            infeasible_recheck_max_steps=1),
                                 opposing=dataclasses.replace(P.opposing, kind=opposing))
    planner = Planner(params, solver_factory=_PerStep)
    st, records = EpisodeState(0), []
    for k in range(len(q1)):
        _PerStep.step = k
        _, rec = planner.step(st, 0.02 * k, EGO, FRONT, None if opposing == "none" else OPP, 0.0)
        records.append(rec)
    return st, records, _PerStep.log


def _q2_steps(log: list) -> list[int]:
    return sorted({step for step, direction, _ in log if direction < 0})


def test_q2_is_solved_only_where_q1_failed_and_after_the_switch():
    # Q1 solved at 0-2, fails at 3 (the default rule abandons), Q2 drives from then on
    q1 = [None, None, None, ITER, None, None]
    st, recs, log = _run("when_needed", q1, [])
    assert _q2_steps(log) == [3, 4, 5]
    assert [r.source for r in recs] == [Source.Q1] * 3 + [Source.Q2] * 3
    assert [r.q2 is None for r in recs] == [True] * 3 + [False] * 3
    assert st.mode is Mode.GO_BACK and st.switched_to_q2_at_s == pytest.approx(0.06)
    # the same decisions as Algorithm 1 solving both problems every step
    st_all, recs_all, log_all = _run("every_step", q1, [])
    assert _q2_steps(log_all) == list(range(6))
    assert [r.source for r in recs_all] == [r.source for r in recs]
    assert st_all.switched_to_q2_at_s == st.switched_to_q2_at_s


def test_an_unread_q2_failure_is_not_counted_as_a_failed_step():
    # Q2 certified infeasible while Q1 solves (the ego far ahead of where going back is possible):
    # Algorithm 1 applies Q1 either way; only the policy that solves Q2 counts the failures
    q1, q2 = [None] * 4, [CERT] * 4
    st_all, recs_all, _ = _run("every_step", q1, q2)
    st, recs, log = _run("when_needed", q1, q2)
    assert [r.source for r in recs] == [r.source for r in recs_all] == [Source.Q1] * 4
    assert st_all.q2_fail_steps == 4 and st.q2_fail_steps == 0 and _q2_steps(log) == []
    assert st.both_infeasible_steps == st_all.both_infeasible_steps == 0


def test_fast_when_unneeded_gives_an_unread_q2_the_fast_path_only():
    # Q2 infeasible at 0-1 while Q1 solves; Q1 fails at 2 (abandoned: Q2 read, in full, and solved)
    q1, q2 = [None, None, CERT, None], [CERT, CERT, None, None]
    st, recs, log = _run("fast_when_unneeded", q1, q2)
    q2_fast = [fast for (step, direction, _), fast in zip(log, _PerStep.fast, strict=True) if direction < 0]
    assert _q2_steps(log) == [0, 1, 2, 3] and q2_fast == [True, True, False, False]
    assert [str(r.q2.status) for r in recs[:2]] == ["unread:IPM_Max_Iterations"] * 2
    assert [r.source for r in recs] == [Source.Q1, Source.Q1, Source.Q2, Source.Q2] and st.mode is Mode.GO_BACK
    # an unread failure is no evidence: neither presumed nor certified infeasible
    assert not recs[0].q2.status.certified_infeasible and not recs[0].q2.status.presumed_infeasible
    assert st.presumed_infeasible_solves == 0 and st.statuses["unread:IPM_Max_Iterations"] == 2
    assert st.q2_fail_steps == 2 and st.both_infeasible_steps == 0
    st_all, recs_all, _ = _run("every_step", q1, q2)
    assert [r.source for r in recs_all] == [r.source for r in recs]
    assert [str(r.q2.status) for r in recs_all[:2]] == ["Infeasible_Problem_Detected"] * 2


def test_theorem_five_is_still_counted_when_q1_fails():
    q1, q2 = [None, CERT, None], [None, CERT, None]
    st, recs, log = _run("when_needed", q1, q2)
    assert _q2_steps(log) == [1]  # neither solved at 1: still overtaking (held plan), Q1 solves again at 2
    assert [r.source for r in recs] == [Source.Q1, Source.HELD, Source.Q1] and st.mode is Mode.OVERTAKE
    assert st.both_infeasible_steps == 1 and st.both_certified_infeasible_steps == 1 and st.q2_fail_steps == 1


def test_a_human_driver_gets_q2_every_step_for_table_one():
    st, recs, log = _run("when_needed", [None] * 3, [], opposing="human")
    assert _q2_steps(log) == [0, 1, 2] and all(r.table_row >= 0 for r in recs)


def test_an_autonomous_opposing_vehicle_does_not_need_q2():
    st, recs, log = _run("when_needed", [None] * 3, [], opposing="autonomous")
    # only Q1's plain pre-solve of the two-stage cold start and Q1 with veh_o, every step
    assert _q2_steps(log) == [] and log == [(0, +1, False), (0, +1, True), (1, +1, True), (2, +1, True)]


def test_validation_names_the_field():
    p = dataclasses.replace(P, mpc=dataclasses.replace(P.mpc, q2_solve="lazy"))
    with pytest.raises(CampaignError, match="mpc.q2_solve: unknown policy 'lazy'; valid: every_step, "
                       "fast_when_unneeded, when_needed"):
        validate_params(p, "c.toml")
    validate_params(ModelParams(mpc=dataclasses.replace(P.mpc, q2_solve="when_needed")), "c.toml")
