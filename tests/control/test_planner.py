"""The host-side controller (mcverify.control.planner): fallback, held plans, convergence, commitment."""

from __future__ import annotations

import numpy as np
import pytest

from mcverify.control.decision import Mode
from mcverify.control.episode_state import EpisodeState
from mcverify.control.planner import Planner, ego_in_own_lane, fallback_input, held_input
from mcverify.levels import Level
from mcverify.model import ModelParams
from mcverify.solver.status import SolveRoute, SolveStatus

P = ModelParams()
FRONT = np.array([64.0, 0.0, 7.0])


def test_fallback_brakes_behind_and_beside_but_not_ahead_of_the_front_vehicle():
    behind = fallback_input(np.array([50.0, 3.5, 0.1, 15.0]), FRONT, P)
    assert behind[0] == P.ego.accel_min_mps2 and behind[1] == pytest.approx(-0.1)  # straighten, no lane change
    ahead = fallback_input(np.array([80.0, 0.0, -0.05, 15.0]), FRONT, P)
    assert ahead[0] == 0.0 and ahead[1] == pytest.approx(0.05)
    stopping = fallback_input(np.array([50.0, 0.0, 0.0, 0.05]), FRONT, P)
    assert stopping[0] == pytest.approx(-0.05 / P.sim.control_period_s)  # stops, never reverses


def test_held_plan_is_followed_stage_by_stage_then_used_up():
    u = np.array([[1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
    held = (u, np.array([0.1, 0.1, 0.1]), 5.0)
    assert held_input(held, 5.02)[0] == 1.0
    assert held_input(held, 5.15)[0] == 2.0
    assert held_input(held, 5.29)[0] == 3.0
    assert held_input(held, 5.31) is None
    assert held_input(None, 5.0) is None


def test_own_lane_test_uses_the_rotated_footprint():
    assert ego_in_own_lane(np.array([0, 0.0, 0.0, 10]), P)
    assert not ego_in_own_lane(np.array([0, 0.5, 0.3, 10]), P)  # its corner reaches the lane line
    assert not ego_in_own_lane(np.array([0, 3.5, 0.0, 10]), P)


@pytest.fixture(scope="module")
def planner() -> Planner:
    return Planner(P)


def test_convergence_goals(planner):
    st = EpisodeState(0)
    phi_vf = P.mpc.phi_s * FRONT[2]
    assert planner.converged(st, np.array([64 + phi_vf + 0.1, 0.1, 0, 15]), FRONT) == "overtook"
    assert planner.converged(st, np.array([64 + phi_vf + 0.1, 0.4, 0, 15]), FRONT) is None  # not in lane yet
    assert planner.converged(st, np.array([10.0, 0.0, 0, 10]), FRONT) is None  # behind at the start: not done
    st.mode = Mode.GO_BACK
    assert planner.converged(st, np.array([10.0, 0.0, 0, 10]), FRONT) == "went_back"


def test_committed_once_back_in_lane_ahead_of_the_front_vehicle(planner):
    a = P.barrier.ellipse_a_m
    assert planner.committed(np.array([64 + a + 0.5, 0.2, 0.0, 15]), FRONT)
    assert not planner.committed(np.array([64 + a - 0.5, 0.2, 0.0, 15]), FRONT)
    assert not planner.committed(np.array([64 + a + 0.5, 2.0, 0.0, 15]), FRONT)


def test_step_overtakes_from_the_table_ii_start(planner):
    st = EpisodeState(0)
    u, rec = planner.step(st, 0.0, np.array([10.0, 0.0, 0.0, 10.0]), FRONT, None, Level(epsilon=0.3, lambda0=-0.3135))
    assert rec.q1.success and rec.q2.success and st.mode is Mode.OVERTAKE
    assert u[0] > 0  # accelerates to overtake
    assert st.steps == 1 and len(st.iterations) == 2


class _CertifiedInfeasibleSolver:
    """Q2 certified infeasible by the reference, never solved by the fast path; Q1 always solved."""

    solved_calls: frozenset[int] = frozenset()  # Q2 calls the fast path solves (a flickering edge)
    failing_direction = -1  # the certified infeasible problem: Q2 (-1) or Q1 (+1)

    def __init__(self, params, structure):
        from benchmarks.solver import StubSolver

        self.structure = structure
        self.ok = StubSolver(params, structure)._sol
        self.full_calls: list[int] = []  # calls of the failing problem given the full attempt
        self.calls = 0

    def solve(self, ego, front, direction, level, warm=None, opp_xv=None, guess=None, fast_only=False):
        import dataclasses

        if direction != self.failing_direction:
            return self.ok
        self.calls += 1
        if self.calls in self.solved_calls:
            return self.ok
        if not fast_only:
            self.full_calls.append(self.calls)
        if fast_only:
            status = SolveStatus.ipm("Max_Iterations").via(SolveRoute.PRESUMED)
        else:
            status = SolveStatus.ipopt("Infeasible_Problem_Detected").via(SolveRoute.FALLBACK)
        return dataclasses.replace(self.ok, success=False, status=status)

    def guess_from_plan(self, plan, opp_xv):
        return None


def _certified_infeasible_loop(steps: int, recheck: int, recheck_max: int, solved=frozenset(), controller="vlcbf"):
    import dataclasses

    _CertifiedInfeasibleSolver.solved_calls = frozenset(solved)
    _CertifiedInfeasibleSolver.failing_direction = -1 if controller == "vlcbf" else +1

    mpc = dataclasses.replace(P.mpc, infeasible_recheck_steps=recheck, infeasible_recheck_max_steps=recheck_max,
                              controller=controller)
    params = dataclasses.replace(P, mpc=mpc)
    made = []
    planner = Planner(params, solver_factory=lambda p, st: made.append(_CertifiedInfeasibleSolver(p, st)) or made[-1])
    st = EpisodeState(0)
    for k in range(steps):
        planner.step(st, 0.02 * k, np.array([10.0, 0.0, 0.0, 10.0]), FRONT, None, 0.0)
    return planner.plain, st


def test_certified_infeasible_problem_gets_the_reference_again_every_recheck_period():
    plain, st = _certified_infeasible_loop(10, recheck=4, recheck_max=4)
    assert plain.full_calls == [1, 5, 9]  # certified at 1, presumed at 2-4, IPOPT again at 5, ...
    assert st.presumed_infeasible_solves == 7 and st.q2_fail_steps == 10 and st.q1_fail_steps == 0


def test_mpcdc_problem_is_never_presumed_infeasible():
    # MPC-DC has no backup problem: every step gets the full attempt, whatever IPOPT certified before
    plain, st = _certified_infeasible_loop(10, recheck=4, recheck_max=16, controller="mpcdc")
    assert plain.full_calls == list(range(1, 11))
    assert st.presumed_infeasible_solves == 0 and st.q1_fail_steps == 10 and not st.infeasible


def test_failed_rechecks_double_the_wait_up_to_the_cap():
    plain, st = _certified_infeasible_loop(60, recheck=4, recheck_max=16)
    # waits 4, 8, 16, 16, ...: full attempts at 1, 5, 13, 29, 45
    assert plain.full_calls == [1, 5, 13, 29, 45]
    assert st.presumed_infeasible_solves == 60 - 5 and st.q2_fail_steps == 60


def test_a_fast_path_success_within_the_wait_keeps_the_presumption():
    # certified at 1 (wait 4); solved at 3, inside the wait, so 4 is still presumed; IPOPT at 5 fails
    # (wait 8): solved at 7, 8-12 presumed, IPOPT at 13 fails (wait 8, the cap); 14-19 presumed,
    # solved at 20 (inside) and 21 (the wait is over: the memo ends), so 22 gets IPOPT at once
    plain, st = _certified_infeasible_loop(22, recheck=4, recheck_max=8, solved={3, 7, 20, 21})
    assert plain.full_calls == [1, 5, 13, 22]
    assert st.q2_fail_steps == 22 - 4
