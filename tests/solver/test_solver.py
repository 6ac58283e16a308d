"""Host-side solve (mcverify.solver.mpc) on the IPOPT reference backend: determinism, warm starts,
failures as values (the fast path is tested against it in test_backends.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mcverify.levels import Level
from mcverify.model import ModelParams
from mcverify.ocp.problem import OcpStructure
from mcverify.solver.mpc import MpcSolution, MpcSolver
from mcverify.solver.status import SolveOutcome

P = dataclasses.replace(ModelParams(), mpc=dataclasses.replace(ModelParams().mpc, backend="ipopt"))
LEVEL = Level(epsilon=0.3, lambda0=-(0.3 + 0.5 * 0.3**3))  # lambda0 = -kappa~(0.3), lambdas (1, 0.5)
EGO = np.array([10.0, 0.0, 0.0, 10.0])
FRONT = np.array([64.0, 0.0, 28.0 / 3.6])
PLAN_FIELDS = ("x_plan", "u_plan", "dt_plan")


@pytest.fixture(scope="module")
def solver() -> MpcSolver:
    return MpcSolver(P)


def bicycle_step(x: np.ndarray, u: np.ndarray, h: float, l_r: float) -> np.ndarray:
    """One forward-Euler step of eq.kinematic_bicycle (enough to perturb the state like a plant)."""
    _, _, psi, v = x
    alpha, beta = u
    return x + h * np.array([
        v * np.cos(psi) - v * np.sin(psi) * beta,
        v * np.sin(psi) + v * np.cos(psi) * beta,
        v / l_r * beta,
        alpha,
    ])


def test_solution_fields(solver):
    sol = solver.solve(EGO, FRONT, 1, LEVEL)
    assert isinstance(sol, MpcSolution) and sol.success
    n = P.mpc.horizon
    assert sol.x_plan.shape == (n + 1, 4) and sol.u_plan.shape == (n, 2) and sol.dt_plan.shape == (n,)
    assert str(sol.status) == "Solve_Succeeded"
    assert 0 < sol.iterations <= P.mpc.max_iter
    assert sol.solve_time_s > 0
    assert sol.total_time_s == pytest.approx(sol.dt_plan.sum())
    assert sol.max_violation <= 1e-5
    assert sol.warm is not None and sol.warm.direction == 1
    assert len(solver.kernel_hash) == 64


def test_same_inputs_give_bit_identical_outputs(solver):
    first = solver.solve(EGO, FRONT, 1, LEVEL)
    solver.solve(EGO + np.array([3.0, 0.5, 0.02, 1.0]), FRONT, -1, LEVEL)  # an unrelated solve between
    second = solver.solve(EGO, FRONT, 1, LEVEL)
    for name in PLAN_FIELDS:
        assert np.array_equal(getattr(first, name), getattr(second, name))
    assert first.iterations == second.iterations and first.status == second.status
    # warm path too
    ego1 = bicycle_step(EGO, first.u_plan[0], P.sim.control_period_s, P.ego.l_r_m)
    a = solver.solve(ego1, FRONT, 1, LEVEL, warm=first.warm)
    b = solver.solve(ego1, FRONT, 1, LEVEL, warm=second.warm)
    for name in PLAN_FIELDS:
        assert np.array_equal(getattr(a, name), getattr(b, name))
    assert np.array_equal(a.warm.lam_g, b.warm.lam_g)


def test_warm_start_same_solution_fewer_iterations(solver):
    """Re-solving from its own warm start returns the same optimum in fewer iterations.

    T and the applied input u_plan[0] agree to 1e-6 (the next node to 1e-5). Late stages of the
    plan lie along nearly flat directions of the objective (e.g. the terminal speed only enters the
    1e-3 smoothing term), so at IPOPT tol 1e-6 they are determined only to about 1e-3 and are
    compared at that level.
    """
    cold = solver.solve(EGO, FRONT, 1, LEVEL)
    again = solver.solve(EGO, FRONT, 1, LEVEL, warm=cold.warm)
    assert again.success
    assert again.total_time_s == pytest.approx(cold.total_time_s, abs=1e-6)
    assert np.allclose(again.u_plan[0], cold.u_plan[0], atol=1e-6, rtol=0)
    assert np.allclose(again.x_plan[1], cold.x_plan[1], atol=1e-5, rtol=0)
    assert np.allclose(again.x_plan, cold.x_plan, atol=1e-2, rtol=0)
    assert np.allclose(again.u_plan, cold.u_plan, atol=5e-2, rtol=0)
    assert again.iterations <= cold.iterations


def test_warm_start_next_control_period(solver):
    """One control period later (ego moved along its plan, veh_f along the road): warm beats cold."""
    sol = solver.solve(EGO, FRONT, 1, LEVEL)
    ego, front = EGO, FRONT
    for _ in range(3):
        ego = bicycle_step(ego, sol.u_plan[0], P.sim.control_period_s, P.ego.l_r_m)
        front = front + np.array([front[2] * P.sim.control_period_s, 0.0, 0.0])
        cold = solver.solve(ego, front, 1, LEVEL)
        warm = solver.solve(ego, front, 1, LEVEL, warm=sol.warm)
        assert cold.success and warm.success
        assert warm.iterations <= cold.iterations
        assert warm.total_time_s == pytest.approx(cold.total_time_s, abs=1e-4)
        sol = warm


def test_warm_start_of_other_direction_is_ignored(solver):
    q1 = solver.solve(EGO, FRONT, 1, LEVEL)
    cold_q2 = solver.solve(EGO, FRONT, -1, LEVEL)
    q2 = solver.solve(EGO, FRONT, -1, LEVEL, warm=q1.warm)
    assert q2.iterations == cold_q2.iterations
    assert np.array_equal(q2.x_plan, cold_q2.x_plan)


def test_non_finite_input_is_a_failed_solution(solver):
    sol = solver.solve(np.array([10.0, 0.0, np.nan, 10.0]), FRONT, 1, LEVEL)
    assert not sol.success and sol.status.outcome is SolveOutcome.INVALID_INPUT
    assert sol.warm is None and np.all(np.isnan(sol.x_plan))


def test_solver_exception_is_a_failed_solution(solver, monkeypatch):
    def boom(**_kwargs):
        raise RuntimeError("simulated IPOPT crash\nwith a second line")

    monkeypatch.setattr(solver.backend, "_cold", boom)
    sol = solver.solve(EGO, FRONT, 1, LEVEL)
    assert not sol.success
    assert str(sol.status) == "exception: simulated IPOPT crash"


def test_structure_must_match_params():
    with pytest.raises(ValueError):
        MpcSolver(P, structure=OcpStructure(horizon=50, order_m=3))
