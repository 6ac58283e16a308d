"""The TO-CBF-MPC problem (mcverify.ocp): maths against independent numpy, solved plans against every constraint."""

from __future__ import annotations

import dataclasses

import casadi as ca
import numpy as np
import pytest

from mcverify import ocp
from mcverify.levels import Level
from mcverify.model import ModelParams
from mcverify.ocp import problem
from mcverify.solver.mpc import MpcSolver
from mcverify.solver.status import SolveStatus

P = ModelParams()
TABLE_II_EGO = np.array([10.0, 0.0, 0.0, 10.0])
TOL = 1e-6


def lambda0_of(params: ModelParams) -> float:
    eps = params.barrier.epsilon
    return -sum(lam * eps ** (2 * k + 1) for k, lam in enumerate(params.barrier.lambdas_m))


LEVEL = Level(epsilon=P.barrier.epsilon, lambda0=lambda0_of(P))


# --- independent numpy model ------------------------------------------------------------------------


def np_rhs(x: np.ndarray, u: np.ndarray, l_r: float) -> np.ndarray:
    """eq.kinematic_bicycle, f(x) + g(x) u."""
    _, _, psi, v = x
    alpha, beta = u
    return np.array([
        v * np.cos(psi) - v * np.sin(psi) * beta,
        v * np.sin(psi) + v * np.cos(psi) * beta,
        v / l_r * beta,
        alpha,
    ])


def np_h(x: np.ndarray, t: float, front: np.ndarray, a: float, b: float) -> float:
    return ((x[0] - front[0] - front[2] * t) / a) ** 2 + ((x[1] - front[1]) / b) ** 2 - 1.0


def np_hdot(x, u, t, front, a, b, l_r) -> float:
    """Analytic total derivative along the dynamics, with dh/dt = -2 (x - x_f(t)) v_f / a^2."""
    xdot = np_rhs(x, u, l_r)
    dx = x[0] - front[0] - front[2] * t
    return 2 * dx / a**2 * xdot[0] + 2 * (x[1] - front[1]) / b**2 * xdot[1] - 2 * dx * front[2] / a**2


def np_lambda_h(lambdas, h) -> float:
    return lambdas[0] + sum(lam * h ** (2 * k - 1) for k, lam in enumerate(lambdas[1:], start=1))


# --- maths ------------------------------------------------------------------------------------------


def test_hdot_matches_finite_difference_and_numpy():
    rng = np.random.default_rng(0)
    vlcbf = problem.barrier_function(order_m=2)
    a, b, l_r = P.barrier.ellipse_a_m, P.barrier.ellipse_b_m, P.ego.l_r_m
    lambdas = np.array([-0.31, 1.0, 0.5])
    for _ in range(25):
        x = rng.uniform([0, -1, -0.35, 0], [100, 4.5, 0.35, 20])
        u = rng.uniform([-6, -0.15], [3, 0.15])
        t = rng.uniform(0, 10)
        front = rng.uniform([20, -0.5, 0], [120, 0.5, 12])
        h, hdot, cbf = (float(v) for v in vlcbf(x, u, t, front, a, b, lambdas, l_r))
        assert h == pytest.approx(np_h(x, t, front, a, b), rel=1e-12, abs=1e-12)
        # central finite difference of h along the flow (state and time together)
        eps = 1e-6
        xdot = np_rhs(x, u, l_r)
        fd = (np_h(x + eps * xdot, t + eps, front, a, b) - np_h(x - eps * xdot, t - eps, front, a, b)) / (2 * eps)
        assert hdot == pytest.approx(fd, rel=1e-6, abs=1e-6)
        assert hdot == pytest.approx(np_hdot(x, u, t, front, a, b, l_r), rel=1e-10, abs=1e-10)
        assert cbf == pytest.approx(hdot + np_lambda_h(lambdas, h), rel=1e-10, abs=1e-10)


def test_lambda_h_is_constant_plus_odd_powers():
    lambdas = ca.DM([-0.3, 2.0, 0.5, 0.25])
    h = 1.7
    assert float(problem.lambda_h(lambdas, h)) == pytest.approx(-0.3 + 2.0 * h + 0.5 * h**3 + 0.25 * h**5)


def test_param_layout_and_pack_params():
    layout = ocp.ParamLayout(P.barrier.order_m)
    p = ocp.pack_params(P, TABLE_II_EGO, [64.0, 0.0, 7.0], -1, LEVEL)
    assert p.shape == (layout.size,)
    sl = layout.slices
    assert np.array_equal(p[sl["x0"]], TABLE_II_EGO)
    assert p[sl["direction"]][0] == -1.0
    assert np.allclose(p[sl["lambdas"]], [LEVEL.lambda0, *P.barrier.lambdas_m])
    assert p[sl["y_goal"]][0] == P.road.ego_lane_y_m
    with pytest.raises(ValueError):
        ocp.pack_params(P, TABLE_II_EGO, [64.0, 0.0, 7.0], 0, LEVEL)


@pytest.mark.parametrize("with_opposing", [False, True])
@pytest.mark.parametrize("constraint", ["cbf", "distance"])
def test_nlp_dimensions(with_opposing, constraint):
    st = dataclasses.replace(ocp.OcpStructure.from_params(P, with_opposing=with_opposing), constraint=constraint)
    nlp = ocp.build_nlp(st)
    lay = ocp.NlpLayout.of(st)
    assert nlp["x"].numel() == lay.n_w
    assert nlp["g"].numel() == lay.n_g
    assert nlp["p"].numel() == ocp.ParamLayout.of(st).size
    lbx, ubx = ocp.decision_bounds(P, st)
    assert np.all(np.isinf(lbx[:4])) and np.all(np.isinf(ubx[:4]))  # X[:, 0] is not bounded
    opp = np.array([300.0, -10.0]) if with_opposing else None
    w0 = ocp.initial_guess(P, st, TABLE_II_EGO, [64.0, 0.0, 7.0], 1, opp)
    assert w0.shape == (lay.n_w,) and np.all(np.isfinite(w0))
    if with_opposing:
        with pytest.raises(ValueError, match="opp_xv"):
            ocp.pack_params(P, TABLE_II_EGO, [64.0, 0.0, 7.0], 1, LEVEL, structure=st)


def test_formulation_digest_follows_the_maths():
    plain = ocp.OcpStructure.from_params(P)
    assert ocp.formulation_digest(plain) == ocp.formulation_digest(dataclasses.replace(plain))
    others = [dataclasses.replace(plain, with_opposing=True), dataclasses.replace(plain, constraint="distance"),
              dataclasses.replace(plain, order_m=3)]
    digests = {ocp.formulation_digest(s) for s in [plain, *others]}
    assert len(digests) == 4


# --- solved plans ------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def solver() -> MpcSolver:
    return MpcSolver(P)


def check_plan(sol, params: ModelParams, ego, front, direction: int) -> None:
    """Every constraint of box eq.tompc, evaluated in numpy on the returned plan."""
    e, m, b = params.ego, params.mpc, params.barrier
    X, U, DT = sol.x_plan, sol.u_plan, sol.dt_plan
    n = m.horizon
    assert X.shape == (n + 1, 4) and U.shape == (n, 2) and DT.shape == (n,)
    assert np.allclose(X[0], ego, atol=TOL)
    t = np.concatenate([[0.0], np.cumsum(DT)])
    lambdas = [LEVEL.lambda0, *b.lambdas_m]
    for i in range(n):
        assert np.max(np.abs(X[i + 1] - X[i] - np_rhs(X[i], U[i], e.l_r_m) * DT[i])) <= TOL  # eq.tompc_dy
        h = np_h(X[i], t[i], front, b.ellipse_a_m, b.ellipse_b_m)
        hdot = np_hdot(X[i], U[i], t[i], front, b.ellipse_a_m, b.ellipse_b_m, e.l_r_m)
        assert hdot + np_lambda_h(lambdas, h) >= -TOL  # eq.tompc_cbf
    total = t[-1]
    x_goal = front[0] + front[2] * total + direction * m.phi_s * front[2]
    assert direction * (X[-1, 0] - x_goal) >= -TOL  # eq.tompc_goal
    assert abs(X[-1, 1] - params.road.ego_lane_y_m) <= m.eps_y_m + TOL  # eq.tompc_y
    lo = [e.accel_min_mps2, -e.slip_max_rad]
    hi = [e.accel_max_mps2, e.slip_max_rad]
    assert np.all(U >= np.array(lo) - TOL) and np.all(U <= np.array(hi) + TOL)  # eq.tompc_u
    Xs = X[1:]
    assert np.all(Xs[:, 1] >= e.y_min_m - TOL) and np.all(Xs[:, 1] <= e.y_max_m + TOL)  # eq.tompc_v
    assert np.all(np.abs(Xs[:, 2]) <= e.heading_max_rad + TOL)
    assert np.all(Xs[:, 3] >= e.speed_min_mps - TOL) and np.all(Xs[:, 3] <= e.speed_max_mps + TOL)
    assert np.all(DT >= m.dt_min_s - TOL) and np.all(DT <= m.dt_max_s + TOL)  # eq.tompc_t
    assert 0.0 < total < n * m.dt_max_s
    assert sol.total_time_s == pytest.approx(total)


@pytest.mark.parametrize("v_front_kmh", [25.0, 36.0])
def test_q1_plan_from_table_ii_start_satisfies_every_constraint(solver, v_front_kmh):
    front = np.array([64.0, 0.0, v_front_kmh / 3.6])
    sol = solver.solve(TABLE_II_EGO, front, 1, LEVEL)
    assert sol.success, sol.status
    check_plan(sol, P, TABLE_II_EGO, front, 1)
    # overtakes: ends at least phi v_f ahead of where veh_f is at T
    assert sol.x_plan[-1, 0] >= front[0] + front[2] * sol.total_time_s + P.mpc.phi_s * front[2] - TOL
    assert np.max(sol.x_plan[:, 1]) > 2.0  # passes in the opposing lane


def test_q2_plan_mid_manoeuvre_ends_behind(solver):
    # alongside veh_f in the opposing lane, faster than it: Q2 must brake and fall back
    ego = np.array([60.0, 3.5, 0.0, 17.0])
    front = np.array([64.0, 0.0, 25.0 / 3.6])
    sol = solver.solve(ego, front, -1, LEVEL)
    assert sol.success, sol.status
    check_plan(sol, P, ego, front, -1)
    assert sol.x_plan[-1, 0] <= front[0] + front[2] * sol.total_time_s - P.mpc.phi_s * front[2] + TOL


def test_q2_from_table_ii_start_is_immediate(solver):
    front = np.array([64.0, 0.0, 25.0 / 3.6])
    sol = solver.solve(TABLE_II_EGO, front, -1, LEVEL)
    assert sol.success, sol.status
    check_plan(sol, P, TABLE_II_EGO, front, -1)
    assert sol.total_time_s <= 10 * P.mpc.horizon * P.mpc.dt_min_s  # already behind and in lane


def test_uncatchable_front_vehicle_is_reported_infeasible(solver):
    front = np.array([64.0, 0.0, 19.0])  # 0.4 m/s below the ego speed limit: no overtake in 15 s
    sol = solver.solve(TABLE_II_EGO, front, 1, LEVEL)
    assert not sol.success
    assert sol.warm is None
    assert isinstance(sol.status, SolveStatus) and sol.status.raw


def test_smoothing_weight_keeps_plan_time_optimal():
    """T at the default weight 1e-3 vs 10x more and 100x less smoothing.

    Below about 1e-4 the plan chatters beta between +-slip_max (a forward-Euler artefact of the
    linearised slip terms) and gains 1-2% of T from it; 1e-3 suppresses that and the smoothing
    itself costs nothing measurable (10x more changes T by < 0.5%).
    """
    front = np.array([64.0, 0.0, 28.0 / 3.6])
    totals = {}
    for weight in (1e-5, 1e-3, 1e-2):
        params = dataclasses.replace(P, mpc=dataclasses.replace(P.mpc, smooth_weight=weight))
        sol = MpcSolver(params).solve(TABLE_II_EGO, front, 1, LEVEL)
        assert sol.success, (weight, sol.status)
        totals[weight] = sol.total_time_s
    assert totals[1e-2] == pytest.approx(totals[1e-3], rel=5e-3)
    assert totals[1e-3] == pytest.approx(totals[1e-5], rel=3e-2)


@pytest.mark.slow
def test_free_stage_intervals_variant_solves_table_ii_start(tmp_path):
    """The paper-literal structure (every DT_i free) compiles (about 20 s) and solves the Table II start."""
    structure = ocp.OcpStructure.from_params(P, uniform_dt=False)
    front = np.array([64.0, 0.0, 25.0 / 3.6])
    sol = MpcSolver(P, structure=structure, kernel_dir=tmp_path).solve(TABLE_II_EGO, front, 1, LEVEL)
    assert sol.success, sol.status
    check_plan(sol, P, TABLE_II_EGO, front, 1)
    assert np.ptp(sol.dt_plan) > 1e-3  # the intervals really are free


# --- the opposing vehicle (eq.tompcAdd) and MPC-DC ----------------------------------------------------

HUMAN = dataclasses.replace(P, opposing=dataclasses.replace(P.opposing, kind="human"))
AUTO = dataclasses.replace(P, opposing=dataclasses.replace(P.opposing, kind="autonomous"))
MPCDC = dataclasses.replace(HUMAN, mpc=dataclasses.replace(P.mpc, controller="mpcdc"))
MPCDC_EPS = dataclasses.replace(HUMAN, mpc=dataclasses.replace(P.mpc, controller="mpcdc_eps"))
FRONT_25 = np.array([64.0, 0.0, 25.0 / 3.6])


@pytest.fixture(scope="module")
def opp_solvers() -> dict[str, MpcSolver]:
    return {name: MpcSolver(p, ocp.OcpStructure.from_params(p, with_opposing=True))
            for name, p in (("human", HUMAN), ("auto", AUTO), ("mpcdc", MPCDC), ("mpcdc_eps", MPCDC_EPS))}


def np_opp_accel_numbers(plan_xo, dt):
    """veh_o's accelerations implied by two consecutive predicted nodes (exact double integrator)."""
    x, v = plan_xo[:, 0], plan_xo[:, 1]
    return (v[1:] - v[:-1]) / dt, x[1:] - x[:-1] - v[:-1] * dt - 0.5 * (v[1:] - v[:-1]) * dt


def test_far_opposing_vehicle_changes_nothing(opp_solvers):
    plain = MpcSolver(HUMAN).solve(TABLE_II_EGO, FRONT_25, 1, LEVEL)
    far = opp_solvers["human"].solve(TABLE_II_EGO, FRONT_25, 1, LEVEL, opp_xv=np.array([5000.0, -10.0]))
    assert plain.success and far.success, (plain.status, far.status)
    assert far.total_time_s == pytest.approx(plain.total_time_s, rel=1e-4)


def test_worst_case_prediction_is_conservative_closed_form(opp_solvers):
    """Human driver (Sec. V-C): the predicted veh_o is at least as advanced towards the ego as the
    exact worst case (accelerate at accel_max up to the speed limit), and at most WORST_CASE_FADE
    faster."""
    o = HUMAN.opposing
    x0, s0 = 420.0, 12.0
    sol = opp_solvers["human"].solve(TABLE_II_EGO, FRONT_25, 1, LEVEL, opp_xv=np.array([x0, -s0]))
    assert sol.success, sol.status
    t = np.concatenate([[0.0], np.cumsum(sol.dt_plan)])
    t_star = (o.speed_limit_mps - s0) / o.accel_max_mps2
    tau = np.minimum(t, t_star)
    x_worst = x0 - (s0 * tau + 0.5 * o.accel_max_mps2 * tau**2 + o.speed_limit_mps * (t - tau))
    x_pred = sol.opp_plan[:, 0]
    assert np.all(x_pred <= x_worst + 1e-6)
    assert np.all(x_pred >= x_worst - problem.WORST_CASE_FADE_MPS * t - 1e-6)
    accel, residual = np_opp_accel_numbers(sol.opp_plan, sol.dt_plan)
    assert np.max(np.abs(residual)) <= TOL  # eq.tompcAdd_dynamic_o, exact double integrator
    assert np.all(accel <= 1e-9) and np.all(accel >= -o.accel_max_mps2 - 1e-9)


def test_close_fast_human_driver_blocks_the_overtake(opp_solvers):
    """Table IV Scenario A start: veh_o 210 m ahead at 18 m/s. Without it Q1 solves; with its worst
    case no overtake can keep the ego's VL-CBF on h_eo, and Q2 (stay behind) still solves."""
    opp = np.array([220.0, -18.0])
    assert MpcSolver(HUMAN).solve(TABLE_II_EGO, FRONT_25, 1, LEVEL).success
    assert not opp_solvers["human"].solve(TABLE_II_EGO, FRONT_25, 1, LEVEL, opp_xv=opp).success
    assert opp_solvers["human"].solve(TABLE_II_EGO, FRONT_25, -1, LEVEL, opp_xv=opp).success


@pytest.mark.parametrize("kind", ["human", "auto"])
def test_plan_keeps_the_ego_vlcbf_on_h_eo_in_the_opposing_lane(opp_solvers, kind):
    """eq.tompcAdd_cbf_eo, re-evaluated in numpy on the plan: at every node where the ego footprint
    reaches the lane line, hdot_eo + Lambda_eo H(h_eo) >= 0 with veh_o's predicted acceleration."""
    params = HUMAN if kind == "human" else AUTO
    b = params.barrier
    sol = opp_solvers[kind].solve(TABLE_II_EGO, FRONT_25, 1, LEVEL, opp_xv=np.array([420.0, -12.0]))
    assert sol.success, sol.status
    lam0 = -b.opp_epsilon_m * b.opp_lambdas_m[0]
    accel_o, _ = np_opp_accel_numbers(sol.opp_plan, sol.dt_plan)
    checked = 0
    for i in range(P.mpc.horizon):
        x = sol.x_plan[i]
        top = x[1] + 0.5 * P.geometry.length_m * abs(np.sin(x[2])) + 0.5 * P.geometry.width_m * np.cos(x[2])
        if top < 1.75:
            continue
        checked += 1
        xdot = np_rhs(x, sol.u_plan[i], P.ego.l_r_m)
        eps = 1e-6  # xddot by a central difference along the flow, input held
        xddot = (np_rhs(x + eps * xdot, sol.u_plan[i], P.ego.l_r_m)[0]
                 - np_rhs(x - eps * xdot, sol.u_plan[i], P.ego.l_r_m)[0]) / (2 * eps)
        x_o, v_o = sol.opp_plan[i]
        h = x_o - x[0] - (xdot[0] - v_o) ** 2 / (2 * b.decel_max_mps2)
        hdot = v_o - xdot[0] - (xdot[0] - v_o) * (xddot - accel_o[i]) / b.decel_max_mps2
        assert hdot + lam0 + b.opp_lambdas_m[0] * h >= -1e-4, (i, h, hdot)
    assert checked >= 5  # the plan does pass through the opposing lane


def test_autonomous_prediction_is_its_law(opp_solvers):
    """The planner predicts an autonomous veh_o with its own law (mcverify.sim.agents.autonomous_accel),
    up to the smoothing of max/clip: check node by node where the exact and smooth lane gates agree."""
    from mcverify.levels import lambda0_from_epsilon
    from mcverify.sim import agents

    o = AUTO.opposing
    sol = opp_solvers["auto"].solve(TABLE_II_EGO, FRONT_25, 1, LEVEL, opp_xv=np.array([420.0, -12.0]))
    assert sol.success, sol.status
    accel_o, _ = np_opp_accel_numbers(sol.opp_plan, sol.dt_plan)
    law = dict(cruise_speed_mps=o.speed_mps, gain_per_s=o.cruise_gain_per_s,
               lambdas=np.array([lambda0_from_epsilon(o.lambdas_m, o.epsilon_m), *o.lambdas_m]),
               decel_max_mps2=AUTO.barrier.decel_max_mps2, accel_max_mps2=o.accel_max_mps2,
               brake_max_mps2=o.brake_max_mps2, l_r_m=P.ego.l_r_m)
    compared = 0
    for i in range(P.mpc.horizon):
        x = sol.x_plan[i]
        top = float(agents.ego_top_edge_m(x, P.geometry.length_m, P.geometry.width_m))
        if 1.0 < top < 2.0:  # near the line the OCP's smooth gate and the plant's exact one differ
            continue
        in_lane = top > 1.75
        exact = float(agents.autonomous_accel(sol.opp_plan[i], x, sol.u_plan[i], ego_in_opposing_lane=in_lane, **law))
        assert accel_o[i] == pytest.approx(exact, abs=problem.SMOOTH_ACCEL_MPS2), i
        compared += 1
    assert compared >= 20


def test_mpcdc_keeps_the_ellipses_at_the_nodes_only(opp_solvers):
    """MPC-DC (Sec. VI-D): every node 1..N outside the front ellipse and the ellipse around the
    predicted veh_o (extrapolated at its measured speed); no CBF condition is imposed."""
    b = MPCDC.barrier
    opp = np.array([420.0, -12.0])
    sol = opp_solvers["mpcdc"].solve(TABLE_II_EGO, FRONT_25, 1, LEVEL, opp_xv=opp)
    assert sol.success, sol.status
    t = np.concatenate([[0.0], np.cumsum(sol.dt_plan)])
    assert np.allclose(sol.opp_plan[:, 0], opp[0] + opp[1] * t, atol=1e-6)  # constant speed
    for i in range(1, P.mpc.horizon + 1):
        assert np_h(sol.x_plan[i], t[i], FRONT_25, b.ellipse_a_m, b.ellipse_b_m) >= -TOL
        ho = ((sol.x_plan[i, 0] - sol.opp_plan[i, 0]) / b.ellipse_a_m) ** 2 + \
             ((sol.x_plan[i, 1] - 3.5) / b.ellipse_b_m) ** 2 - 1
        assert ho >= -TOL
    # the plan rides the ellipse: its minimum over the nodes is (nearly) active
    h_nodes = [np_h(sol.x_plan[i], t[i], FRONT_25, b.ellipse_a_m, b.ellipse_b_m) for i in range(1, 51)]
    assert min(h_nodes) < 0.05


def test_mpcdc_eps_keeps_the_margin_at_the_nodes_on_the_same_kernel(opp_solvers):
    """MPC-DC with the eps-margin ellipse (controller "mpcdc_eps"): the same compiled kernel as
    MPC-DC (the margin is a runtime bound on the distance rows), every node 1..N at h_ef >= eps and
    h >= eps on veh_o's ellipse, and the plan rides the margin instead of the ellipse."""
    b = MPCDC_EPS.barrier
    eps = b.epsilon
    assert ocp.distance_margin(MPCDC_EPS) == eps == 0.3 and ocp.distance_margin(MPCDC) == 0.0
    assert opp_solvers["mpcdc_eps"].kernel_hash == opp_solvers["mpcdc"].kernel_hash
    st = ocp.OcpStructure.from_params(MPCDC_EPS, with_opposing=True)
    lbg, _ = ocp.constraint_bounds(st, eps)
    gs = ocp.NlpLayout.of(st).g_slices
    assert np.all(lbg[gs["front"]] == eps) and np.all(lbg[gs["opp"]] == eps) and np.all(lbg[gs["goal"]] == 0)
    opp = np.array([420.0, -12.0])
    sol = opp_solvers["mpcdc_eps"].solve(TABLE_II_EGO, FRONT_25, 1, LEVEL, opp_xv=opp)
    assert sol.success, sol.status
    t = np.concatenate([[0.0], np.cumsum(sol.dt_plan)])
    h_nodes = [np_h(sol.x_plan[i], t[i], FRONT_25, b.ellipse_a_m, b.ellipse_b_m) for i in range(1, 51)]
    assert min(h_nodes) >= eps - TOL
    assert min(h_nodes) < eps + 0.05  # active: the margin, not the ellipse, is what binds
    for i in range(1, 51):
        ho = ((sol.x_plan[i, 0] - sol.opp_plan[i, 0]) / b.ellipse_a_m) ** 2 + \
             ((sol.x_plan[i, 1] - 3.5) / b.ellipse_b_m) ** 2 - 1
        assert ho >= eps - TOL
    with pytest.raises(ValueError, match="constraint='distance'"):
        ocp.constraint_bounds(ocp.OcpStructure.from_params(HUMAN), eps)
