"""Solver backends (mcverify.solver.backends, mcverify.solver.ipm, mcverify.solver.kkt): the fast path against IPOPT.

The IPM backend must give IPOPT's plans (objective T, first input, every constraint), keep the
node-0 CBF row exact after a full Newton step, hand to IPOPT what it cannot solve (so that a failed
solve means IPOPT failed too), and be deterministic.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_solver import bicycle_step

from mcverify.campaign import spec as campaign
from mcverify.levels import Level
from mcverify.model import BACKEND_NAMES, ModelParams
from mcverify.ocp import NlpLayout, OcpStructure, constraint_bounds, pack_params
from mcverify.solver import backends
from mcverify.solver.cfun import CFunction
from mcverify.solver.ipm import WARM_ATTEMPTS, IpmResult, with_options
from mcverify.solver.kkt import KktStructure
from mcverify.solver.mpc import MpcSolver
from mcverify.solver.status import SolveOutcome

P = dataclasses.replace(ModelParams(), mpc=dataclasses.replace(ModelParams().mpc, backend="ipopt"))
P_IPM = dataclasses.replace(P, mpc=dataclasses.replace(P.mpc, backend="ipm"))
LEVEL = Level(epsilon=0.3, lambda0=-(0.3 + 0.5 * 0.3**3))  # lambda0 = -kappa~(0.3), lambdas (1, 0.5)
EGO = np.array([10.0, 0.0, 0.0, 10.0])
PERIOD = P.sim.control_period_s


@pytest.fixture(scope="module")
def ipopt() -> MpcSolver:
    return MpcSolver(P)


@pytest.fixture(scope="module")
def ipm() -> MpcSolver:
    return MpcSolver(P_IPM)




def closed_loop_states(solver: MpcSolver, front: np.ndarray, direction: int, steps: int, ego=EGO):
    """(ego, front, warm) of ``steps`` control periods driven by the solver's own plans."""
    out = []
    sol = solver.solve(ego, front, direction, LEVEL)
    for _ in range(steps):
        ego = bicycle_step(ego, sol.u_plan[0], PERIOD, P.ego.l_r_m)
        front = front + np.array([front[2] * PERIOD, 0.0, 0.0])
        out.append((ego, front, sol.warm))
        sol = solver.solve(ego, front, direction, LEVEL, sol.warm)
    return out


# ------------------------------------------------------------------------------------- selection


def attempt_starts(solver: MpcSolver, warm, monkeypatch, fast_only: bool = False,
                   front: np.ndarray | None = None) -> list[tuple[float, bool]]:
    """(mu_init, warm-started) of every IPM run of one solve from ``warm`` (a WarmStart) whose IPM attempts all
    fail (IPOPT then answers, unless ``fast_only``)."""
    backend = solver.backend
    failed = IpmResult(np.zeros(solver.layout.n_w), np.zeros(solver.layout.n_w), np.zeros(solver.layout.n_g),
                       False, "Line_Search_Failed", 30, 30, 0, 0, 0, 1.0, 1.0)
    seen = []
    monkeypatch.setattr(backend.ipm, "solve", lambda p, w0, lx, lg, o: seen.append((o.mu_init, lx is not None))
                        or failed)
    front = np.array([64.0, 0.0, 25.0 / 3.6]) if front is None else front
    solver.solve(EGO, front, 1, LEVEL, warm=warm, fast_only=fast_only)
    monkeypatch.undo()
    return seen


def test_registry_implements_every_backend_name():
    assert set(backends.REGISTRY) == set(BACKEND_NAMES)
    assert all(cls.name == name for name, cls in backends.REGISTRY.items())


def test_backend_selection(ipm):
    assert isinstance(ipm.backend, backends.IpmBackend)
    assert isinstance(MpcSolver(ModelParams()).backend, backends.IpmBackend)  # the default
    assert isinstance(MpcSolver(P).backend, backends.IpoptBackend)
    with pytest.raises(ValueError, match="unknown solver backend"):
        backends.create_backend("fastest", ipm.problem, P)


def test_create_backend_passes_the_kernel_dir_to_the_ipm_library(ipm, monkeypatch, tmp_path):
    """The ipm backend's compiled C library comes from the kernel cache it is given, through create_backend and
    MpcSolver alike (both used to drop it and build into the default cache)."""
    from mcverify.solver import mpc as mpc_module

    asked = []
    real = backends.get_runtime_library
    monkeypatch.setattr(backends, "get_runtime_library", lambda name, kernel_dir=None: asked.append(kernel_dir)
                        or real(name, None))
    backend = backends.create_backend("ipm", ipm.problem, P_IPM, kernel_dir=tmp_path)
    assert isinstance(backend, backends.IpmBackend) and asked == [tmp_path]
    assert backends.create_backend("ipopt", ipm.problem, P, kernel_dir=tmp_path).name == "ipopt"
    monkeypatch.setattr(mpc_module, "get_kernel", lambda structure, kernel_dir=None: ipm.kernel)  # no new build
    MpcSolver(P_IPM, kernel_dir=tmp_path / "cache")
    assert asked == [tmp_path, tmp_path / "cache"]


def test_campaign_accepts_ipm_backend():
    raw = {"campaign": {"name": "t", "seed": 1, "episodes": 1}, "model": {"mpc": {"backend": "ipm"}}}
    camp = campaign.campaign_from_dict(raw)
    assert camp.cells[0].params.mpc.backend == "ipm"
    raw["model"]["mpc"]["backend"] = "sqp"
    with pytest.raises(campaign.CampaignError, match="unknown solver backend"):
        campaign.campaign_from_dict(raw)


# ------------------------------------------------------------------------- agreement with IPOPT


@pytest.mark.parametrize("v_front_kmh", [25.0, 36.0])
def test_cold_plan_matches_ipopt(ipopt, ipm, v_front_kmh):
    front = np.array([64.0, 0.0, v_front_kmh / 3.6])
    ref = ipopt.solve(EGO, front, 1, LEVEL)
    sol = ipm.solve(EGO, front, 1, LEVEL)
    assert ref.success and sol.success, (ref.status, sol.status)
    assert str(sol.status) == "IPM_Converged"
    assert sol.max_violation <= 1e-6
    assert sol.total_time_s == pytest.approx(ref.total_time_s, rel=1e-5)
    assert np.allclose(sol.u_plan[0], ref.u_plan[0], atol=1e-3, rtol=0)
    assert np.allclose(sol.x_plan[1], ref.x_plan[1], atol=1e-4, rtol=0)


@pytest.mark.parametrize("direction", [1, -1])
def test_warm_solves_along_a_closed_loop_match_ipopt(ipopt, ipm, direction):
    """Ten control periods, each solved warm by both backends from the same warm start.

    Both stop at a KKT error of 1e-6 (scaled), not at the same point: along the flatter Q2 problems
    T then differs by up to about 1e-5 relative (e.g. 4.61823 s vs 4.61818 s).
    """
    front = np.array([64.0, 0.0, 28.0 / 3.6])
    ego = EGO if direction == 1 else np.array([58.0, 3.5, 0.0, 16.0])  # Q2: alongside veh_f
    for ego_k, front_k, warm in closed_loop_states(ipopt, front, direction, 10, ego):
        ref = ipopt.solve(ego_k, front_k, direction, LEVEL, warm)
        sol = ipm.solve(ego_k, front_k, direction, LEVEL, warm)
        assert ref.success and sol.success, (ref.status, sol.status)
        assert str(sol.status) == "IPM_Converged"
        assert sol.total_time_s == pytest.approx(ref.total_time_s, rel=1e-4)
        assert np.allclose(sol.u_plan[0], ref.u_plan[0], atol=2e-3, rtol=0)


def test_warm_start_needs_fewer_iterations_than_cold(ipm):
    front = np.array([64.0, 0.0, 25.0 / 3.6])
    for ego, front_k, warm in closed_loop_states(ipm, front, 1, 3):
        warm_sol = ipm.solve(ego, front_k, 1, LEVEL, warm)
        cold_sol = ipm.solve(ego, front_k, 1, LEVEL)
        assert warm_sol.success and cold_sol.success
        assert warm_sol.iterations < cold_sol.iterations
        assert warm_sol.total_time_s == pytest.approx(cold_sol.total_time_s, rel=1e-4)


def test_multipliers_satisfy_stationarity(ipm):
    """grad f + J' lam_g + lam_x = 0 (CasADi's sign convention), so IPOPT can be warm-started from them."""
    front = np.array([64.0, 0.0, 25.0 / 3.6])
    sol = ipm.solve(EGO, front, 1, LEVEL)
    assert sol.success
    so = ipm.kernel.so_path
    p = pack_params(P, EGO, front, 1, LEVEL)
    fg, jac = CFunction(so, "nlp_grad_f"), CFunction(so, "nlp_jac_g")
    fg.inputs[0][:], fg.inputs[1][:] = sol.warm.x, p
    jac.inputs[0][:], jac.inputs[1][:] = sol.warm.x, p
    grad = fg()[1]
    rows, cols = jac.sparsity_out[1]
    jt_lam = np.bincount(cols, jac()[1] * sol.warm.lam_g[rows], minlength=grad.size)
    residual = grad + jt_lam + sol.warm.lam_x
    assert np.max(np.abs(residual)) <= 1e-5
    # an acceleration at its upper bound carries a positive bound multiplier
    u = NlpLayout.of(ipm.structure).w_slices["u"]
    at_max = np.isclose(sol.warm.x[u][0::2], P.ego.accel_max_mps2, atol=1e-6)
    assert at_max.any() and np.all(sol.warm.lam_x[u][0::2][at_max] > 0)


# ----------------------------------------------------------------------------------- safety


def test_node0_cbf_row_is_affine_in_u0_and_touches_only_node0(ipm):
    """The premise of the safety argument: with X[:, 0] and t_0 fixed, the node-0 row of eq.tompc_cbf
    depends on u_0 alone among the variables, and affinely (the bicycle is control-affine)."""
    lay = NlpLayout.of(ipm.structure)
    row = lay.g_slices["front"].start
    ws = lay.w_slices
    jac = CFunction(ipm.kernel.so_path, "nlp_jac_g")
    rows, cols = jac.sparsity_out[1]
    node0 = {*range(ws["x"].start, ws["x"].start + 4), *range(ws["u"].start, ws["u"].start + 2), ws["t"].start}
    assert set(cols[rows == row]) <= node0
    g_fun = CFunction(ipm.kernel.so_path, "nlp_g")
    front = np.array([30.0, 0.0, 25.0 / 3.6])
    p = pack_params(P, EGO, front, 1, LEVEL)
    w = ipm.solve(EGO, front, 1, LEVEL).warm.x.copy()
    u0 = slice(ws["u"].start, ws["u"].start + 2)
    vals = []
    for u in (np.array([-5.0, -0.1]), np.array([2.0, 0.12]), np.array([-1.5, 0.01])):
        w[u0] = u
        g_fun.inputs[0][:], g_fun.inputs[1][:] = w, p
        vals.append(g_fun()[0][row])
    assert vals[2] == pytest.approx(0.5 * (vals[0] + vals[1]), rel=1e-12, abs=1e-9)  # midpoint: affine


def test_node0_cbf_row_holds_after_one_newton_step(ipopt, ipm):
    """The IPM fixes X[:, 0] and t_0 at its start (initial value embedding); every iterate keeps them,
    so the node-0 row's residual g - s shrinks by (1 - alpha) per step and is 0 wherever the row
    starts strictly feasible, its slack s staying above the (relaxed) bound. After one iteration -
    with the rest of the plan still violated by 1e-3 to 1e-2 - the input u_0 already satisfies the
    CBF condition at the sample. Checked behind veh_f and alongside it (where the row is active).
    """
    lay = NlpLayout.of(ipm.structure)
    row = lay.g_slices["front"].start
    g_fun = CFunction(ipm.kernel.so_path, "nlp_g")
    checked = unconverged = 0
    scenarios = (
        (EGO, np.array([64.0, 0.0, 25.0 / 3.6])),  # behind veh_f: the row is inactive
        (np.array([55.0, 3.3, 0.0, 17.0]), np.array([60.0, 0.0, 7.0])),  # alongside: the row is active
    )
    for ego0, front in scenarios:
        for ego, front_k, warm in closed_loop_states(ipopt, front, 1, 8, ego0):
            p = pack_params(P, ego, front_k, 1, LEVEL)
            r = ipm.backend.ipm.solve(p, warm.x, warm.lam_x, warm.lam_g, with_options(WARM_ATTEMPTS[0], max_iter=1))
            assert np.array_equal(r.w[lay.w_slices["x"]][:4], ego)  # X[:, 0] is the measured state, exactly
            assert r.w[lay.w_slices["t"].start] == 0.0
            g_fun.inputs[0][:], g_fun.inputs[1][:] = r.w, p
            assert g_fun()[0][row] >= -1e-6  # the bound relaxation (1e-8 on the row-scaled row)
            checked += 1
            unconverged += int(r.max_violation > 1e-5)
    assert checked == 16 and unconverged >= 8


# ------------------------------------------------------------------------------ failure handling


def test_infeasible_problem_fails_only_after_ipopt_fails(ipopt, ipm):
    front = np.array([64.0, 0.0, 19.0])  # 0.4 m/s below the ego speed limit: no overtake in 15 s
    sol = ipm.solve(EGO, front, 1, LEVEL)
    assert not sol.success and sol.warm is None
    assert sol.status.fallback
    assert not ipopt.solve(EGO, front, 1, LEVEL).success


def test_ipm_failure_hands_the_solve_to_ipopt(ipopt, monkeypatch):
    solver = MpcSolver(P_IPM)
    failed = IpmResult(np.zeros(solver.layout.n_w), np.zeros(solver.layout.n_w), np.zeros(solver.layout.n_g),
                       False, "Max_Iterations", 30, 30, 0, 0, 0, 1.0, 1.0)
    monkeypatch.setattr(solver.backend.ipm, "solve", lambda *a, **k: failed)
    front = np.array([64.0, 0.0, 25.0 / 3.6])
    sol = solver.solve(EGO, front, 1, LEVEL)
    ref = ipopt.solve(EGO, front, 1, LEVEL)
    assert sol.success and str(sol.status) == "fallback:Solve_Succeeded"
    assert np.array_equal(sol.u_plan, ref.u_plan) and sol.total_time_s == ref.total_time_s
    assert sol.iterations == 30 + ref.iterations  # the cold attempt's iterations counted too
    assert solver.backend.ipm_outcomes["cold1:Max_Iterations"] == 1


def test_fast_only_failure_is_presumed_infeasible_without_ipopt(monkeypatch):
    solver = MpcSolver(P_IPM)
    failed = IpmResult(np.zeros(solver.layout.n_w), np.zeros(solver.layout.n_w), np.zeros(solver.layout.n_g),
                       False, "Max_Iterations", 30, 30, 0, 0, 0, 1.0, 1.0)
    monkeypatch.setattr(solver.backend.ipm, "solve", lambda *a, **k: failed)
    monkeypatch.setattr(solver.backend.reference, "solve", lambda *a, **k: pytest.fail("IPOPT was called"))
    sol = solver.solve(EGO, np.array([64.0, 0.0, 25.0 / 3.6]), 1, LEVEL, fast_only=True)
    assert not sol.success and str(sol.status) == "presumed_infeasible:IPM_Max_Iterations" and sol.iterations == 30


def test_non_finite_input_is_a_failed_solution(ipm):
    sol = ipm.solve(np.array([10.0, 0.0, np.nan, 10.0]), np.array([64.0, 0.0, 7.0]), 1, LEVEL)
    assert not sol.success and sol.status.outcome is SolveOutcome.INVALID_INPUT


# ----------------------------------------------------------------------------------- determinism


def test_same_inputs_give_bit_identical_outputs(ipm):
    front = np.array([64.0, 0.0, 28.0 / 3.6])
    first = ipm.solve(EGO, front, 1, LEVEL)
    ipm.solve(EGO + np.array([3.0, 0.5, 0.02, 1.0]), front, -1, LEVEL)  # an unrelated solve between
    second = ipm.solve(EGO, front, 1, LEVEL)
    ego1 = bicycle_step(EGO, first.u_plan[0], PERIOD, P.ego.l_r_m)
    a = ipm.solve(ego1, front, 1, LEVEL, warm=first.warm)
    ipm.solve(EGO, front, -1, LEVEL)
    b = ipm.solve(ego1, front, 1, LEVEL, warm=second.warm)
    for x, y in ((first, second), (a, b)):
        for name in ("x_plan", "u_plan", "dt_plan"):
            assert np.array_equal(getattr(x, name), getattr(y, name))
        assert np.array_equal(x.warm.lam_g, y.warm.lam_g) and np.array_equal(x.warm.lam_x, y.warm.lam_x)
        assert (x.status, x.iterations) == (y.status, y.iterations)


# ------------------------------------------------------------------------------- KKT structure


def test_kkt_structure_of_the_default_kernel(ipm):
    st = OcpStructure.from_params(P)
    lbg, ubg = constraint_bounds(st)
    kkt = KktStructure.of_kernel(ipm.kernel.so_path, lbg == ubg)
    lay = NlpLayout.of(st)
    assert (kkt.n_w, kkt.n_g) == (lay.n_w, lay.n_g)
    assert kkt.bandwidth <= 20  # stage-wise coupling only; the dense alternative would be n = 762
    # the fixing rows are exactly the initial-state rows, on X[:, 0] and t_0
    gs, ws = lay.g_slices, lay.w_slices
    assert sorted(kkt.fix_row) == [*range(gs["init"].start, gs["init"].stop), gs["clock0"].start]
    assert sorted(kkt.fix_var) == [*range(ws["x"].start, ws["x"].start + 4), ws["t"].start]
    assert np.all(kkt.fix_coef == 1.0)
    # every entry sits inside the band storage
    ldab = 3 * kkt.bandwidth + 1
    rows_in_band = kkt.ent_pos % ldab
    assert np.all((rows_in_band >= kkt.bandwidth) & (rows_in_band <= 3 * kkt.bandwidth))
    assert sorted(kkt.perm) == list(range(kkt.n))


# ------------------------------------------------------------------- with the opposing vehicle


HUMAN = dataclasses.replace(P_IPM, opposing=dataclasses.replace(P.opposing, kind="human"))
MPCDC = dataclasses.replace(HUMAN, mpc=dataclasses.replace(HUMAN.mpc, controller="mpcdc"))


@pytest.mark.parametrize("params", [HUMAN, MPCDC], ids=["vlcbf", "mpcdc"])
def test_ipm_solves_the_opposing_structure_like_ipopt(params):
    """The backend reads its structure from the kernel: the eq.tompcAdd rows and veh_o's variables
    (and MPC-DC's distance rows) need nothing of it. veh_o 410 m ahead at 12 m/s: feasible.

    A cold start of the VL-CBF problem with veh_o is beyond the IPM (its infeasibility grows and the
    line search fails after about 20 iterations; IPOPT needs 210 iterations and its restoration
    phase), so that solve may come from the fallback; the warm solves of the next control periods,
    which are what a closed loop is made of, must not.
    """
    st = OcpStructure.from_params(params, with_opposing=True)
    fast = MpcSolver(params, st)
    ref = MpcSolver(dataclasses.replace(params, mpc=dataclasses.replace(params.mpc, backend="ipopt")), st)
    front, opp = np.array([64.0, 0.0, 25.0 / 3.6]), np.array([420.0, -12.0])
    a, b = fast.solve(EGO, front, 1, LEVEL, opp_xv=opp), ref.solve(EGO, front, 1, LEVEL, opp_xv=opp)
    assert a.success and b.success, (a.status, b.status)
    assert a.total_time_s == pytest.approx(b.total_time_s, rel=1e-4)
    assert np.allclose(a.opp_plan, b.opp_plan, atol=1e-3)
    sol, ego = a, EGO
    for _ in range(3):
        ego = bicycle_step(ego, sol.u_plan[0], PERIOD, P.ego.l_r_m)
        front, opp = front + np.array([front[2] * PERIOD, 0, 0]), opp + np.array([opp[1] * PERIOD, 0])
        sol_ref = ref.solve(ego, front, 1, LEVEL, sol.warm, opp_xv=opp)
        sol = fast.solve(ego, front, 1, LEVEL, sol.warm, opp_xv=opp)
        assert sol.success and str(sol.status) == "IPM_Converged", sol.status
        assert sol.total_time_s == pytest.approx(sol_ref.total_time_s, rel=1e-4)


def test_blocked_overtake_fails_through_ipopt_and_q2_solves():
    """Table IV Scenario A start (veh_o 210 m ahead at 18 m/s): no overtake keeps the ego's VL-CBF on
    h_eo against the worst case, so Q1 fails - after IPOPT failed too - and Q2 (stay behind) solves."""
    fast = MpcSolver(HUMAN, OcpStructure.from_params(HUMAN, with_opposing=True))
    front, opp = np.array([64.0, 0.0, 25.0 / 3.6]), np.array([220.0, -18.0])
    q1 = fast.solve(EGO, front, 1, LEVEL, opp_xv=opp)
    assert not q1.success and q1.status.fallback
    assert fast.solve(EGO, front, -1, LEVEL, opp_xv=opp).success
