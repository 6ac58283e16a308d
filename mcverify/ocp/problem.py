"""The TO-CBF-MPC problem (paper box eq.tompc, with eq.tompcAdd for veh_o) as a CasADi NLP, written once.

Units: metres, seconds, radians, m/s, m/s^2. Road frame as in :mod:`mcverify.model`. The decision
vector ``w`` and the parameter vector ``p`` are laid out in :mod:`mcverify.ocp.layout`.

Constraint vector ``g`` (all written as ``lbg <= g <= ubg`` with the numeric bounds of
:func:`~mcverify.ocp.layout.constraint_bounds`), equalities first:

* ``X[:, 0] - x0 == 0``                                         (4)    initial state
* ``t_0 == 0``                                                  (1)    clock
* ``X[:, i+1] - X[:, i] - (f + g u) DT_i == 0``, i = 0..N-1      (4N)   eq.tompc_dy
* ``t_{i+1} - t_i - DT_i == 0``, i = 0..N-1                      (N)    clock
* ``DT_{i+1} - DT_i == 0``, i = 0..N-2, if ``uniform_dt``       (N-1)  see OcpStructure
* with veh_o: ``XO[:, 0] - [x_o, v_o] == 0`` and its exact double-integrator steps under the
  predicted acceleration (:func:`opposing_accel`)                (2+2N) eq.tompcAdd_dynamic_o
* front vehicle, "cbf": ``hdot_i + Lambda . H(h_i) >= 0``, i = 0..N-1; "distance" (MPC-DC):
  ``h_ef(x_i, t_i) >= 0``, i = 1..N                             (N)    eq.tompc_cbf / Sec. VI-D
* with veh_o, "cbf": ``sat(hdot_eo,i + Lambda_eo . H(h_eo,i)) + M (1 - gate_i) >= 0``, i = 0..N-1,
  the ego's VL-CBF on eq.two_way_value_function_e while its footprint is in the opposing lane
  (``sat`` keeps the sign and bounds the row, see :data:`~mcverify.ocp.layout.EO_ROW_SCALE_MPS`);
  "distance": the ellipse around the predicted veh_o, i = 1..N  (N)    eq.tompcAdd_cbf_eo
* ``s (X[0, N] - x_g) >= 0``                                    (1)    eq.tompc_goal
* ``eps_y -+ (X[1, N] - y_goal) >= 0``                          (2)    eq.tompc_y

The input and state bounds (eq.tompc_u, eq.tompc_v, eq.tompc_t) are bounds on ``w``
(:func:`~mcverify.ocp.layout.decision_bounds`). The dynamics are the forward-Euler discretisation of
the kinematic bicycle eq.kinematic_bicycle (:func:`bicycle_rhs`).

The opposing vehicle's own constraint eq.tompcAdd_cbf_oe holds by construction: the predicted
acceleration of an autonomous veh_o *is* its VL-CBF-filtered law (:func:`opposing_accel`), which the
ego knows (the paper's "Lambda_o obtained via communications").
"""

from __future__ import annotations

import functools
import hashlib

import casadi as ca

from mcverify.ocp.layout import (
    EO_ROW_SCALE_MPS,
    N_FRONT,
    N_OPP,
    N_U,
    N_X,
    NlpLayout,
    OcpStructure,
    ParamLayout,
)

# Bump whenever the maths of :func:`build_nlp` changes: it enters every kernel hash.
FORMULATION_VERSION = "tocbf-2"


def bicycle_rhs(x: ca.SX, u: ca.SX, l_r: ca.SX) -> ca.SX:
    """f(x) + g(x) u of the kinematic bicycle, eq.kinematic_bicycle. x (4,), u (2,) -> (4,)."""
    psi, v = x[2], x[3]
    alpha, beta = u[0], u[1]
    return ca.vertcat(
        v * ca.cos(psi) - v * ca.sin(psi) * beta,
        v * ca.sin(psi) + v * ca.cos(psi) * beta,
        v / l_r * beta,
        alpha,
    )


def barrier_h(x: ca.SX, t: ca.SX, front: ca.SX, a: ca.SX, b: ca.SX) -> ca.SX:
    """h_ef(x_e, t) = ((x - x_f(t))/a)^2 + ((y - y_f)/b)^2 - 1 with x_f(t) = x_f + v_f t (eq.VL-CBF).

    The front vehicle is predicted at its measured speed; t (s) is measured from the solve.
    """
    x_f = front[0] + front[2] * t
    return ((x[0] - x_f) / a) ** 2 + ((x[1] - front[1]) / b) ** 2 - 1


def lambda_h(lambdas: ca.SX, h: ca.SX) -> ca.SX:
    """Lambda . H(h) = lambda_0 + lambda_1 h + lambda_2 h^3 + ... + lambda_m h^(2m-1) (def.VL-CBF)."""
    out = lambdas[0]
    for k in range(1, lambdas.numel()):
        out = out + lambdas[k] * h ** (2 * k - 1)
    return out


def barrier_function(order_m: int) -> ca.Function:
    """CasADi Function (x (4), u (2), t, front (3), a, b, lambdas (m+1), l_r) -> (h, hdot, cbf).

    hdot = L_f h + L_g h u + dh/dt, the total derivative along eq.kinematic_bicycle with input u;
    cbf = hdot + Lambda . H(h), which eq.tompc_cbf requires to be >= 0.
    """
    x, u = ca.SX.sym("x", N_X), ca.SX.sym("u", N_U)
    t, front = ca.SX.sym("t"), ca.SX.sym("front", N_FRONT)
    a, b, l_r = ca.SX.sym("a"), ca.SX.sym("b"), ca.SX.sym("l_r")
    lambdas = ca.SX.sym("lambdas", order_m + 1)
    h = barrier_h(x, t, front, a, b)
    hdot = ca.jtimes(h, x, bicycle_rhs(x, u, l_r)) + ca.jacobian(h, t)  # L_f h + L_g h u + dh/dt
    cbf = hdot + lambda_h(lambdas, h)
    return ca.Function(
        "vlcbf",
        [x, u, t, front, a, b, lambdas, l_r],
        [h, hdot, cbf],
        ["x", "u", "t", "front", "a", "b", "lambdas", "l_r"],
        ["h", "hdot", "cbf"],
    )


def ego_x_motion(x: ca.SX, u: ca.SX, l_r: ca.SX) -> tuple[ca.SX, ca.SX]:
    """The ego's longitudinal velocity v_e^x = xdot_e and acceleration alpha_e^x = xddot_e (the
    paper's symbols in eq.value_derivative) along eq.kinematic_bicycle with the stage input u held."""
    vx = bicycle_rhs(x, u, l_r)[0]
    ax = ca.jtimes(vx, x, bicycle_rhs(x, u, l_r))
    return vx, ax


def h_two_way(x_e: ca.SX, vx_e: ca.SX, x_o: ca.SX, v_o: ca.SX, a_l: ca.SX) -> ca.SX:
    """h_eo = h_oe = x_o - x_e - (v_e^x - v_o)^2 / (2 a_l) (m), eq.two_way_value_function_e/_o."""
    return x_o - x_e - (vx_e - v_o) ** 2 / (2 * a_l)


def h_two_way_dot(vx_e: ca.SX, ax_e: ca.SX, v_o: ca.SX, a_o: ca.SX, a_l: ca.SX) -> ca.SX:
    """Its time derivative (m/s), eq.value_derivative: v_o - v_e - (v_e - v_o)(alpha_e - alpha_o)/a_l."""
    return v_o - vx_e - (vx_e - v_o) * (ax_e - a_o) / a_l


def smoothstep(z: ca.SX) -> ca.SX:
    """0 for z <= 0, 1 for z >= 1, 3z^2 - 2z^3 between (C^1)."""
    zc = ca.fmin(ca.fmax(z, 0), 1)
    return zc * zc * (3 - 2 * zc)


def opposing_lane_gate(x: ca.SX, par: dict) -> ca.SX:
    """1 when the ego footprint reaches the lane line (it is in the opposing lane), 0 when its top
    edge is ``gate_width`` or more below the line, C^1 between.

    The top edge of the footprint rotated by psi is y + (L/2)|sin psi| + (W/2) cos psi. |sin psi| is
    bounded above by the quadratic (psi^2 + c^2) / (2c) >= |psi| >= |sin psi| (c = 0.175 rad, half the
    usual heading bound), so the gate opens early, never late (by at most 0.23 m for |psi| <= 0.35).
    Why not sqrt(sin^2 psi + delta): its curvature at psi = 0 is 1/sqrt(delta), and a never-active
    row built on it made IPOPT crawl; the quadratic has constant curvature.
    """
    c = 0.175
    abs_sin_bound = (x[2] ** 2 + c**2) / (2 * c)
    top = x[1] + par["half_length"] * abs_sin_bound + par["half_width"] * ca.cos(x[2])
    return smoothstep((top - (par["lane_line_y"] - par["gate_width"])) / par["gate_width"])


#: Width (m/s^2) of the smooth max/min in veh_o's predicted law: the prediction differs from the
#: exact max/clip of the plant's law by at most half of it, and IPOPT sees no kinks.
SMOOTH_ACCEL_MPS2 = 0.05


#: The worst-case acceleration of a human-driven veh_o fades out over this speed band above its limit.
WORST_CASE_FADE_MPS = 0.5


def smooth_max(a: ca.SX, b: ca.SX, width: float = SMOOTH_ACCEL_MPS2) -> ca.SX:
    """(a + b + sqrt((a - b)^2 + width^2)) / 2: >= max(a, b), at most width/2 above it."""
    return 0.5 * (a + b + ca.sqrt((a - b) ** 2 + width**2))


def smooth_min(a: ca.SX, b: ca.SX, width: float = SMOOTH_ACCEL_MPS2) -> ca.SX:
    """-smooth_max(-a, -b): <= min(a, b), at most width/2 below it."""
    return -smooth_max(-a, -b, width)


def opposing_accel(x: ca.SX, u: ca.SX, xo: ca.SX, par: dict) -> ca.SX:
    """Predicted road-frame acceleration of veh_o at a node (m/s^2; > 0 brakes it, as v_o < 0).

    * "law" (autonomous veh_o, known to the ego): its cruise law k (-v_c - v_o) raised to the
      bound of its own VL-CBF on h_oe (eq.tompcAdd_cbf_oe, solved for alpha_o) while the ego is in
      its lane, clipped to [-accel_max, brake_max] - :func:`mcverify.sim.agents.autonomous_accel` with
      its max and clip smoothed (:data:`SMOOTH_ACCEL_MPS2`);
    * "worst" (human driver, Sec. V-C): full acceleration towards the ego up to its speed limit,
      faded to 0 over :data:`WORST_CASE_FADE_MPS` *above* the limit (C^1), so the prediction is never
      slower than the true worst case (at most that much faster: conservative);
    * "constant": 0 (MPC-DC extrapolates the measured speed).
    """
    x_o, v_o = xo[0], xo[1]
    vx_e, ax_e = ego_x_motion(x, u, par["l_r"])
    a_l = par["decel_max"]
    nominal = par["opp_gain"] * (-par["opp_cruise_speed"] - v_o)
    h = h_two_way(x[0], vx_e, x_o, v_o, a_l)
    closing = ca.fmax(vx_e - v_o, 0.1)  # > 0 whenever veh_o drives towards the ego
    cbf_bound = ax_e - a_l * (lambda_h(par["opp_law_lambdas"], h) + v_o - vx_e) / closing
    gate = opposing_lane_gate(x, par)
    law = nominal + gate * smooth_max(cbf_bound - nominal, 0)
    law = smooth_min(smooth_max(law, -par["opp_accel_max"]), par["opp_brake_max"])
    speed = -v_o
    fade = WORST_CASE_FADE_MPS
    worst = -par["opp_accel_max"] * smoothstep((par["opp_speed_limit"] + fade - speed) / fade)
    mode = par["opp_mode"]
    return mode[0] * law + mode[1] * worst


def build_nlp(structure: OcpStructure) -> dict[str, ca.SX]:
    """The TO-CBF-MPC NLP (box eq.tompc, plus eq.tompcAdd with veh_o) as ``{"x", "p", "f", "g"}``.

    Bounds on w come from :func:`decision_bounds`, those on g from :func:`constraint_bounds`.
    """
    n, lay = structure.horizon, NlpLayout.of(structure)
    pl = ParamLayout.of(structure)
    p = ca.SX.sym("p", pl.size)
    par = {name: p[sl] for name, sl in pl.slices.items()}
    w = ca.SX.sym("w", lay.n_w)
    ws = lay.w_slices
    X = ca.reshape(w[ws["x"]], N_X, n + 1)
    U = ca.reshape(w[ws["u"]], N_U, n)
    DT, t = w[ws["dt"]], w[ws["t"]]
    XO = ca.reshape(w[ws["xo"]], N_OPP, n + 1) if structure.with_opposing else None
    vlcbf = barrier_function(structure.order_m)
    front, a, b = par["front"], par["ellipse_a"], par["ellipse_b"]

    g_dyn, g_clock, g_front, g_opp_dyn, g_opp = [], [], [], [], []
    for i in range(n):
        # eq.tompc_dy (forward Euler): x^{i+1} = x^i + (f(x^i) + g(x^i) u^i) dt_i
        g_dyn.append(X[:, i + 1] - X[:, i] - bicycle_rhs(X[:, i], U[:, i], par["l_r"]) * DT[i])
        g_clock.append(t[i + 1] - t[i] - DT[i])  # t_i = sum_{j<i} DT_j
        if structure.constraint == "cbf":
            # eq.tompc_cbf: L_f h + L_g h u + dh/dt + Lambda H(h) >= 0 at node i, time t_i
            g_front.append(vlcbf(X[:, i], U[:, i], t[i], front, a, b, par["lambdas"], par["l_r"])[2])
        else:
            # MPC-DC: the ellipse as a distance constraint at the next node
            g_front.append(barrier_h(X[:, i + 1], t[i + 1], front, a, b))
        if XO is not None:
            a_o = opposing_accel(X[:, i], U[:, i], XO[:, i], par)
            # eq.tompcAdd_dynamic_o, exact for the double integrator under a held acceleration
            step = ca.vertcat(XO[1, i] * DT[i] + 0.5 * a_o * DT[i] ** 2, a_o * DT[i])
            g_opp_dyn.append(XO[:, i + 1] - XO[:, i] - step)
            g_opp.append(_opposing_row(structure, X, U, XO, t, i, a_o, par))

    # eq.tompc_goal with the goal moving with veh_f: x_g = x_f + v_f T + s phi v_f, s (x^N - x_g) >= 0
    s, total_time = par["direction"], t[n]
    x_goal = front[0] + front[2] * total_time + s * par["phi"] * front[2]
    g_goal = s * (X[0, n] - x_goal)
    # eq.tompc_y: |y^N - y_g| <= eps_y, as two rows >= 0
    dy = X[1, n] - par["y_goal"]
    g_lat = ca.vertcat(par["eps_y"] - dy, par["eps_y"] + dy)

    # uniform stages (OcpStructure.uniform_dt): DT_{i+1} - DT_i == 0
    g_equal = ca.diff(DT) if structure.uniform_dt else ca.SX(0, 1)
    opp_init = XO[:, 0] - par["opp"] if XO is not None else ca.SX(0, 1)

    g = ca.vertcat(
        X[:, 0] - par["x0"], t[0], *g_dyn, *g_clock, g_equal, opp_init, *g_opp_dyn,
        *g_front, *g_opp, g_goal, g_lat,
    )
    # Objective: sum DT + w_s (sum ||u^{i+1} - u^i||^2 + sum beta_i^2) (Remark after eq.tompc), with
    # u in units of its bound (see input_scale).
    Us = U / ca.repmat(par["u_scale"], 1, n)
    du = Us[:, 1:] - Us[:, :-1]
    smooth = ca.sumsqr(du) + ca.sumsqr(Us[1, :])
    J = ca.sum1(DT) + par["smooth_weight"] * smooth
    return {"x": w, "p": p, "f": J, "g": g}


@functools.lru_cache(maxsize=16)
def formulation_digest(structure: OcpStructure) -> str:
    """SHA-256 of the serialized NLP functions (objective and constraints) of ``structure``.

    The kernel cache is keyed by it, so any change to the maths - not only a bumped
    :data:`FORMULATION_VERSION` - compiles a new kernel. (A cache keyed by the version alone served
    a stale kernel after an edit of the opposing-vehicle rows: the solver silently solved the old
    problem.) Deterministic across processes.
    """
    nlp = build_nlp(structure)
    fn = ca.Function("nlp", [nlp["x"], nlp["p"]], [nlp["f"], nlp["g"]])
    return hashlib.sha256(fn.serialize().encode()).hexdigest()



def _opposing_row(structure: OcpStructure, X, U, XO, t, i: int, a_o, par: dict) -> ca.SX:
    """Row i of the opposing-vehicle constraint block (>= 0)."""
    if structure.constraint == "cbf":
        # eq.tompcAdd_cbf_eo at node i, faded out (relaxed by M) while the ego is in its own lane
        vx_e, ax_e = ego_x_motion(X[:, i], U[:, i], par["l_r"])
        h = h_two_way(X[0, i], vx_e, XO[0, i], XO[1, i], par["decel_max"])
        hdot = h_two_way_dot(vx_e, ax_e, XO[1, i], a_o, par["decel_max"])
        gate = opposing_lane_gate(X[:, i], par)
        row = hdot + lambda_h(par["opp_lambdas"], h)
        bounded = row / ca.sqrt(1 + (row / EO_ROW_SCALE_MPS) ** 2)  # same sign, |.| < EO_ROW_SCALE_MPS
        return bounded + par["gate_relax"] * (1 - gate)
    # MPC-DC: the same ellipse around the predicted veh_o (in the opposing lane) at the next node
    dx = (X[0, i + 1] - XO[0, i + 1]) / par["ellipse_a"]
    dy = (X[1, i + 1] - par["opp_lane_y"]) / par["ellipse_b"]
    return dx**2 + dy**2 - 1
