"""Theorem 5 as a graded margin (mcverify.control.margins.problem_margin / theorem5_margin): negative
exactly when neither Q1 nor Q2 is solved, on constructed solutions and on real solves, and the
analysis layer's recomputation from the recorded columns agrees with the planner."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest

from mcverify.analysis.theorem5 import theorem5_step_margin
from mcverify.control.episode_state import EpisodeState
from mcverify.control.margins import neither_solved, problem_margin, theorem5_margin
from mcverify.levels import Level
from mcverify.model import ModelParams
from mcverify.solver.backends import MAX_VIOLATION
from mcverify.solver.mpc import MpcSolution, MpcSolver
from mcverify.solver.status import SolveOutcome, SolveStatus

NAN = math.nan


def _sol(success: bool, slack: float = NAN, violation: float = NAN, outcome=None) -> MpcSolution:
    z = np.zeros((2, 2))
    outcome = outcome or (SolveOutcome.SOLVED if success else SolveOutcome.INFEASIBLE)
    return MpcSolution(success, SolveStatus("stub", outcome), 1, 0.0, 1.0, z, z, z[0], None,
                       max_violation=violation, cbf_slack=slack)


SOLVED = [_sol(True, slack=s, violation=0.0) for s in (0.0, 1e-9, -2e-6, 0.4, 25.0, NAN, math.inf)]
FAILED = [_sol(False, violation=v) for v in (0.0, 1e-7, 3e-4, 0.12, 9.0, NAN, math.inf)]


def test_a_problem_margin_is_non_negative_exactly_when_solved():
    assert all(problem_margin(s) >= 0.0 for s in SOLVED)
    assert all(problem_margin(s) < 0.0 for s in FAILED)
    # a failed solve at a feasible point (out of iterations) is still a failure, by the smallest amount
    assert problem_margin(_sol(False, violation=0.0, outcome=SolveOutcome.ITERATION_LIMIT)) == -MAX_VIOLATION
    assert problem_margin(_sol(False, violation=NAN, outcome=SolveOutcome.EXCEPTION)) == -math.inf


def test_the_step_margin_is_negative_exactly_when_neither_problem_is_solved():
    """Every combination of Q1 and Q2 (not solved, solved with any room, failed by any amount)."""
    options = [None, *SOLVED, *FAILED]
    for q1, q2 in itertools.product(options, options):
        if q2 is None and q1 is not None and not q1.success:
            continue  # the dual planner solves Q2 whenever Q1 failed (Q2 is skipped only after a solved Q1)
        margin = theorem5_margin(q1, q2)
        assert (margin < 0.0) == neither_solved(q1, q2), (q1 and q1.success, q2 and q2.success, margin)


def test_the_margin_ranks_near_violations():
    """More room in the better problem is a larger margin; a larger leftover violation is a lower one."""
    q1_failed = _sol(False, violation=0.3)
    roomy, tight = _sol(True, slack=5.0, violation=0.0), _sol(True, slack=0.01, violation=0.0)
    assert theorem5_margin(q1_failed, roomy) > theorem5_margin(q1_failed, tight) >= 0.0
    near, far = _sol(False, violation=0.02), _sol(False, violation=0.9)
    assert 0.0 > theorem5_margin(q1_failed, near) > theorem5_margin(_sol(False, violation=1.5), far)


def test_the_episode_keeps_its_lowest_step_margin_and_the_analysis_recomputes_it():
    """EpisodeState.theorem5_margin (the row's) equals the minimum of the per-sub-step margin the
    analysis layer recomputes from the recorded q1_margin / q2_margin columns (with going-back steps
    where Q1 was not solved, and steps where Q2 was skipped after a solved Q1)."""
    steps = [(_sol(True, slack=2.0, violation=0.0), None), (_sol(False, violation=0.2), _sol(True, slack=0.5)),
             (None, _sol(True, slack=0.3)), (_sol(False, violation=0.4), _sol(False, violation=0.05)),
             (_sol(True, slack=0.0, violation=0.0), _sol(False, violation=0.7))]
    state = EpisodeState(episode_id=0)
    assert math.isnan(state.theorem5_margin)
    sub_steps = 3
    col = {"q1_margin": [], "q2_margin": []}
    for q1, q2 in steps:
        state.count_theorem_five(q1, q2)
        for key, sol in (("q1_margin", q1), ("q2_margin", q2)):
            col[key] += [NAN if sol is None else problem_margin(sol)] * sub_steps
    per_sub_step = theorem5_step_margin({k: np.array(v) for k, v in col.items()})
    assert per_sub_step.shape == (len(steps) * sub_steps,)
    assert state.theorem5_margin == float(per_sub_step.min()) == -0.05
    unsolved = np.repeat([neither_solved(q1, q2) for q1, q2 in steps], sub_steps)
    np.testing.assert_array_equal(per_sub_step < 0.0, unsolved)
    assert state.both_infeasible_steps == 1


def test_no_decision_and_no_q2_make_no_claim():
    traj = {"q1_margin": np.array([NAN, -0.1, 0.2]), "q2_margin": np.array([NAN, NAN, NAN])}
    np.testing.assert_array_equal(theorem5_step_margin(traj), [math.inf, math.inf, 0.2])


# ----------------------------------------------------------------------------- real solves

P = dataclasses.replace(ModelParams(), mpc=dataclasses.replace(ModelParams().mpc, backend="ipopt"))
LEVEL = Level(epsilon=0.3, lambda0=-(0.3 + 0.5 * 0.3**3))
FRONT = np.array([64.0, 0.0, 28.0 / 3.6])


@pytest.fixture(scope="module")
def solver() -> MpcSolver:
    return MpcSolver(P)


def test_real_solves_lose_margin_as_the_ego_closes_in_and_turn_negative_when_both_fail(solver):
    """The ego in its lane behind veh_f at 14 m/s (veh_f 7.8 m/s), ever closer: the step margin
    falls; once IPOPT certifies both Q1 and Q2 infeasible it is negative (and falls further)."""
    margins, both_failed = [], []
    for gap_m in (40.0, 15.0, 10.0, 6.0):
        ego = np.array([FRONT[0] - gap_m, 0.0, 0.0, 14.0])
        q1, q2 = (solver.solve(ego, FRONT, d, LEVEL) for d in (1, -1))
        if q1.success:
            assert q1.cbf_slack >= -MAX_VIOLATION  # the returned plan keeps its barrier rows
        margins.append(theorem5_margin(q1, q2))
        both_failed.append(neither_solved(q1, q2))
    assert both_failed == [False, False, True, True]
    assert [m < 0.0 for m in margins] == both_failed
    assert margins == sorted(margins, reverse=True) and len(set(margins)) == len(margins)
