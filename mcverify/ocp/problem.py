"""The TO-CBF-MPC problem (paper box eq.tompc, with eq.tompcAdd for veh_o) as a CasADi NLP, written once.

Units: metres, seconds, radians, m/s, m/s^2. Road frame as in :mod:`mcverify.model`.

Decision vector ``w`` (see :class:`NlpLayout`), all stacked node by node:

* ``X``  (4, N+1): ego states ``[x, y, psi, v]`` at the nodes 0..N,
* ``U``  (2, N):   inputs ``[alpha, beta]`` (acceleration m/s^2, slip angle rad) on the stages,
* ``DT`` (N,):     stage intervals in seconds (the time-optimal part, eq.tompc_t),
* ``t``  (N+1,):   node times t_i = sum_{j<i} DT_j (s), an auxiliary clock fixed by equalities,
* ``XO`` (2, N+1): with an opposing vehicle, its predicted ``[x_o, v_o]`` (v_o signed, < 0 when
  it drives towards the ego), eq.tompcAdd_dynamic_o.

The clock is the same maths as writing t_i = cumsum(DT) into the barrier, but keeps every row of
the KKT system local to one stage (banded): with the cumsum, CBF row i depends on DT_0..DT_{i-1}
and the Lagrangian Hessian fills in (8.4k vs 1.3k nonzeros at N = 50); IPOPT's linear algebra, which
dominates the solve, then costs about 1.8x more per iteration and the generated C is 2.2x larger.

Parameter vector ``p`` (see :class:`ParamLayout`, built by :func:`pack_params`): everything numeric
that may change between solves (measurements, direction, goal, barrier coefficients, the opposing
vehicle's law) is a parameter or a runtime bound, so one compiled kernel serves every campaign cell
with the same :class:`OcpStructure`.

Constraint vector ``g`` (all written as ``lbg <= g <= ubg`` with the numeric bounds of
:func:`constraint_bounds`), equalities first:

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
  (``sat`` keeps the sign and bounds the row, see :data:`EO_ROW_SCALE_MPS`);
  "distance": the ellipse around the predicted veh_o, i = 1..N  (N)    eq.tompcAdd_cbf_eo
* ``s (X[0, N] - x_g) >= 0``                                    (1)    eq.tompc_goal
* ``eps_y -+ (X[1, N] - y_goal) >= 0``                          (2)    eq.tompc_y

The opposing vehicle's own constraint eq.tompcAdd_cbf_oe holds by construction: the predicted
acceleration of an autonomous veh_o *is* its VL-CBF-filtered law (:func:`opposing_accel`), which the
ego knows (the paper's "Lambda_o obtained via communications").
"""

from __future__ import annotations

import functools
import hashlib
import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from mcverify.model import ModelParams

# Bump whenever the maths of :func:`build_nlp` changes: it enters every kernel hash.
FORMULATION_VERSION = "tocbf-2"

N_X = 4  # [x, y, psi, v]
N_U = 2  # [alpha, beta]
N_FRONT = 3  # [x_f, y_f, v_f]
N_OPP = 2  # [x_o, v_o]

CONSTRAINTS = ("cbf", "distance")
#: Opposing-vehicle prediction laws, one-hot in the parameter ``opp_mode`` (in this order).
OPP_MODES = ("law", "worst", "constant")


@dataclass(frozen=True)
class OcpStructure:
    """Choices that change the compiled code (everything else is a parameter or a bound).

    horizon: N, the number of stages. order_m: the VL-CBF order m (Lambda has m+1 entries).
    constraint: "cbf" (the paper's VL-CBF constraints, eq.tompc_cbf) or "distance" (MPC-DC: the
    ellipses as distance constraints at the nodes, Sec. VI-D).
    with_opposing: add veh_o and its constraints (eq.tompcAdd). opp_order_m: order of the ego's
    Lambda_eo; opp_law_order_m: order of the autonomous veh_o's own Lambda_o.
    uniform_dt: require DT_0 = DT_1 = ... = DT_{N-1} (N-1 extra equality rows). The paper leaves
    every DT_i free; then the optimum is nearly degenerate (stages that are not needed shrink to
    dt_min, and where they sit barely changes T), and IPOPT crawls: on 40 cold starts along Table II
    closed loops, free DT took 142/174 mean iterations (Q1/Q2) and 32 of 80 solves exceeded 150,
    uniform DT took 48/36 with none over 113, and its T was within 0.4% (mean 0.2%) of the free-DT T.
    """

    horizon: int
    order_m: int
    with_opposing: bool = False
    uniform_dt: bool = True
    constraint: str = "cbf"
    opp_order_m: int = 1
    opp_law_order_m: int = 1

    def __post_init__(self) -> None:
        if self.horizon < 2:
            raise ValueError(f"horizon must be >= 2, got {self.horizon}")
        for name in ("order_m", "opp_order_m", "opp_law_order_m"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.constraint not in CONSTRAINTS:
            raise ValueError(f"constraint must be one of {CONSTRAINTS}, got {self.constraint!r}")

    @classmethod
    def from_params(cls, params: ModelParams, with_opposing: bool = False, uniform_dt: bool = True) -> OcpStructure:
        return cls(
            horizon=params.mpc.horizon,
            order_m=params.barrier.order_m,
            with_opposing=with_opposing,
            uniform_dt=uniform_dt,
            constraint="distance" if params.mpc.controller == "mpcdc" else "cbf",
            opp_order_m=len(params.barrier.opp_lambdas_m),
            opp_law_order_m=len(params.opposing.lambdas_m),
        )


# --------------------------------------------------------------------------------------------------
# Layouts of p, w and g
# --------------------------------------------------------------------------------------------------


def _slices(sizes: dict[str, int]) -> dict[str, slice]:
    out, start = {}, 0
    for name, size in sizes.items():
        out[name] = slice(start, start + size)
        start += size
    return out


@dataclass(frozen=True)
class ParamLayout:
    """The one place that defines the parameter vector p (all slices into p).

    ======================  =====  ==========================================================
    name                    size   meaning
    ======================  =====  ==========================================================
    x0                      4      measured ego state [x, y, psi, v]
    front                   3      measured front vehicle [x_f, y_f, v_f]
    direction               1      s: +1 = Q1 (end ahead of veh_f), -1 = Q2 (end behind it)
    phi                     1      goal reaction time phi (s)
    y_goal                  1      lateral goal y_g (m)
    eps_y                   1      lateral goal tolerance eps_y (m)
    ellipse_a, ellipse_b    1, 1   barrier ellipse semi-axes (m)
    lambdas                 m+1    Lambda = [lambda_0, lambda_1, ..., lambda_m]
    l_r                     1      rear axle to c.g. (m)
    u_scale                 2      input scales [alpha (m/s^2), beta (rad)] of the smoothing term
    smooth_weight           1      weight of the input-smoothing term
    ---- with veh_o --------------------------------------------------------------------------
    opp                     2      measured veh_o [x_o (m), v_o (m/s, signed)]
    opp_mode                3      one-hot prediction law: autonomous law, worst case, constant
    decel_max               1      a_l of h_eo (m/s^2)
    opp_lambdas             m_eo+1 the ego's Lambda_eo (h_eo in metres)
    opp_law_lambdas         m_o+1  veh_o's own Lambda_o
    opp_cruise_speed        1      veh_o's cruise speed (m/s, magnitude)
    opp_gain                1      gain of its cruise law (1/s)
    opp_accel_max           1      its largest acceleration towards the ego (m/s^2)
    opp_brake_max           1      its largest braking (m/s^2)
    opp_speed_limit         1      its speed limit (m/s)
    lane_line_y             1      y of the line between the lanes (m)
    gate_width              1      the eo constraint fades out over this lateral distance (m)
    gate_relax              1      M: how much the faded-out constraint is relaxed by
    half_length, half_width 1, 1   of the ego footprint (m), for its top edge
    opp_lane_y              1      centre of the opposing lane (m), the MPC-DC ellipse's y
    ======================  =====  ==========================================================
    """

    order_m: int
    with_opposing: bool = False
    opp_order_m: int = 1
    opp_law_order_m: int = 1

    @classmethod
    def of(cls, structure: OcpStructure) -> ParamLayout:
        return cls(structure.order_m, structure.with_opposing, structure.opp_order_m, structure.opp_law_order_m)

    @property
    def sizes(self) -> dict[str, int]:
        sizes = {
            "x0": N_X, "front": N_FRONT, "direction": 1, "phi": 1, "y_goal": 1, "eps_y": 1,
            "ellipse_a": 1, "ellipse_b": 1, "lambdas": self.order_m + 1, "l_r": 1, "u_scale": N_U,
            "smooth_weight": 1,
        }
        if self.with_opposing:
            sizes.update({
                "opp": N_OPP, "opp_mode": len(OPP_MODES), "decel_max": 1,
                "opp_lambdas": self.opp_order_m + 1, "opp_law_lambdas": self.opp_law_order_m + 1,
                "opp_cruise_speed": 1, "opp_gain": 1, "opp_accel_max": 1, "opp_brake_max": 1,
                "opp_speed_limit": 1, "lane_line_y": 1, "gate_width": 1, "gate_relax": 1,
                "half_length": 1, "half_width": 1, "opp_lane_y": 1,
            })
        return sizes

    @property
    def slices(self) -> dict[str, slice]:
        return _slices(self.sizes)

    @property
    def size(self) -> int:
        return sum(self.sizes.values())


#: The eo row c = hdot_eo + Lambda_eo H(h_eo) (m/s) enters as c / sqrt(1 + (c/s)^2) with this s:
#: the same sign and zero set (so the same constraint where it is enforced), but bounded by s, so a
#: far veh_o (c ~ 10^3 m/s) neither dominates IPOPT's scaling nor needs a huge relaxation.
EO_ROW_SCALE_MPS = 10.0
#: How much a faded-out eo row is relaxed: anything above EO_ROW_SCALE_MPS switches it off.
GATE_RELAX = 2.0 * EO_ROW_SCALE_MPS
#: Lateral distance (m) over which the eo constraint fades out below the lane line.
GATE_WIDTH_M = 0.5


def opposing_mode(params: ModelParams) -> str:
    """Which law the planner predicts veh_o with (one of :data:`OPP_MODES`).

    MPC-DC (the conventional baseline) extrapolates the measured speed; the VL-CBF planner predicts
    an autonomous veh_o with its known law and a human driver with the worst case (Sec. V-C).
    """
    if params.mpc.controller == "mpcdc":
        return "constant"
    return "law" if params.opposing.kind == "autonomous" else "worst"


def pack_params(
    params: ModelParams,
    ego_state: np.ndarray,
    front_xyv: np.ndarray,
    direction: int,
    lambda0: float,
    y_goal: float | None = None,
    *,
    opp_xv: np.ndarray | None = None,
    structure: OcpStructure | None = None,
) -> np.ndarray:
    """Parameter vector p (layout :class:`ParamLayout`) for one solve.

    ego_state: (4,) [x m, y m, psi rad, v m/s]. front_xyv: (3,) [x_f m, y_f m, v_f m/s].
    direction: +1 (Q1, overtake) or -1 (Q2, go back). lambda0: the level parameter (<= 0).
    y_goal: lateral goal (m), default the ego lane centre. opp_xv: (2,) measured veh_o
    [x_o m, v_o m/s signed], required when ``structure.with_opposing``. Other values come from
    ``params``; structure defaults to ``OcpStructure.from_params(params)``.
    """
    if direction not in (1, -1):
        raise ValueError(f"direction must be +1 or -1, got {direction}")
    structure = structure or OcpStructure.from_params(params)
    if structure.with_opposing and opp_xv is None:
        raise ValueError("this problem has an opposing vehicle: opp_xv (2,) [x_o, v_o] is required")
    layout = ParamLayout.of(structure)
    p = np.empty(layout.size)
    sl = layout.slices
    p[sl["x0"]] = np.asarray(ego_state, dtype=float).reshape(N_X)
    p[sl["front"]] = np.asarray(front_xyv, dtype=float).reshape(N_FRONT)
    p[sl["direction"]] = float(direction)
    p[sl["phi"]] = params.mpc.phi_s
    p[sl["y_goal"]] = params.road.ego_lane_y_m if y_goal is None else y_goal
    p[sl["eps_y"]] = params.mpc.eps_y_m
    p[sl["ellipse_a"]] = params.barrier.ellipse_a_m
    p[sl["ellipse_b"]] = params.barrier.ellipse_b_m
    p[sl["lambdas"]] = (lambda0, *params.barrier.lambdas_m)
    p[sl["l_r"]] = params.ego.l_r_m
    p[sl["u_scale"]] = input_scale(params)
    p[sl["smooth_weight"]] = params.mpc.smooth_weight
    if structure.with_opposing:
        from mcverify.sim.barriers import lambda0_from_epsilon_np  # local: barriers imports JAX

        b, o, geo, road = params.barrier, params.opposing, params.geometry, params.road
        p[sl["opp"]] = np.asarray(opp_xv, dtype=float).reshape(N_OPP)
        p[sl["opp_mode"]] = [float(m == opposing_mode(params)) for m in OPP_MODES]
        p[sl["decel_max"]] = b.decel_max_mps2
        p[sl["opp_lambdas"]] = (lambda0_from_epsilon_np(b.opp_lambdas_m, b.opp_epsilon_m), *b.opp_lambdas_m)
        p[sl["opp_law_lambdas"]] = (lambda0_from_epsilon_np(o.lambdas_m, o.epsilon_m), *o.lambdas_m)
        p[sl["opp_cruise_speed"]] = o.speed_mps
        p[sl["opp_gain"]] = o.cruise_gain_per_s
        p[sl["opp_accel_max"]] = o.accel_max_mps2
        p[sl["opp_brake_max"]] = o.brake_max_mps2
        p[sl["opp_speed_limit"]] = o.speed_limit_mps
        p[sl["lane_line_y"]] = 0.5 * (road.ego_lane_y_m + road.opp_lane_y_m)
        p[sl["gate_width"]] = GATE_WIDTH_M
        p[sl["gate_relax"]] = GATE_RELAX
        p[sl["half_length"]] = 0.5 * geo.length_m
        p[sl["half_width"]] = 0.5 * geo.width_m
        p[sl["opp_lane_y"]] = road.opp_lane_y_m
    return p


@dataclass(frozen=True)
class NlpLayout:
    """Index maps of w = [vec(X) (4(N+1)), vec(U) (2N), DT (N), t (N+1), vec(XO) (2(N+1)) with veh_o]
    and of g (column-major)."""

    horizon: int
    uniform_dt: bool = True
    with_opposing: bool = False

    @classmethod
    def of(cls, structure: OcpStructure) -> NlpLayout:
        return cls(structure.horizon, structure.uniform_dt, structure.with_opposing)

    def _w_sizes(self) -> dict[str, int]:
        n = self.horizon
        sizes = {"x": N_X * (n + 1), "u": N_U * n, "dt": n, "t": n + 1}
        if self.with_opposing:
            sizes["xo"] = N_OPP * (n + 1)
        return sizes

    def _g_sizes(self) -> dict[str, int]:
        n = self.horizon
        n_opp_eq = N_OPP * (n + 1) if self.with_opposing else 0
        return {
            "init": N_X, "clock0": 1, "dyn": N_X * n, "clock": n, "dt_equal": n - 1 if self.uniform_dt else 0,
            "opp_dyn": n_opp_eq, "front": n, "opp": n if self.with_opposing else 0, "goal": 1, "lat": 2,
        }

    @property
    def w_slices(self) -> dict[str, slice]:
        """Slices of w: "x", "u", "dt", "t" (and "xo")."""
        return _slices(self._w_sizes())

    @property
    def g_slices(self) -> dict[str, slice]:
        """Slices of g: "init", "clock0", "dyn", "clock", "dt_equal", "opp_dyn", "front", "opp", "goal", "lat"."""
        return _slices(self._g_sizes())

    @property
    def n_w(self) -> int:
        return sum(self._w_sizes().values())

    @property
    def n_g(self) -> int:
        return sum(self._g_sizes().values())

    @property
    def n_eq(self) -> int:
        """The equalities come first in g: init, clock0, dyn, clock, dt_equal, opp_dyn."""
        return self.g_slices["opp_dyn"].stop

    def unpack(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """w (n_w,) -> (x_plan (N+1, 4), u_plan (N, 2), dt_plan (N,)), copies."""
        w = np.asarray(w, dtype=float).reshape(-1)
        sl = self.w_slices
        return (
            w[sl["x"]].reshape(self.horizon + 1, N_X).copy(),
            w[sl["u"]].reshape(self.horizon, N_U).copy(),
            w[sl["dt"]].copy(),
        )

    def unpack_opposing(self, w: np.ndarray) -> np.ndarray:
        """w (n_w,) -> the predicted veh_o (N+1, 2) [x_o, v_o]; NaN without an opposing vehicle."""
        if not self.with_opposing:
            return np.full((self.horizon + 1, N_OPP), np.nan)
        return np.asarray(w, dtype=float).reshape(-1)[self.w_slices["xo"]].reshape(self.horizon + 1, N_OPP).copy()

    def pack(self, x_plan: np.ndarray, u_plan: np.ndarray, dt_plan: np.ndarray, xo_plan=None) -> np.ndarray:
        """Inverse of :meth:`unpack`; the clock is filled in as t = [0, cumsum(dt)]."""
        dt = np.ravel(dt_plan).astype(float)
        t = np.concatenate([[0.0], np.cumsum(dt)])
        parts = [np.ravel(x_plan).astype(float), np.ravel(u_plan).astype(float), dt, t]
        if self.with_opposing:
            if xo_plan is None:
                raise ValueError("this layout has an opposing vehicle: xo_plan (N+1, 2) is required")
            parts.append(np.ravel(xo_plan).astype(float))
        return np.concatenate(parts)


# --------------------------------------------------------------------------------------------------
# The maths
# --------------------------------------------------------------------------------------------------


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
    row built on it took IPOPT from 25 to 150+ iterations; the quadratic has constant curvature.
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
    problem.) Deterministic across processes; about 0.05 s (0.35 s with veh_o) the first time.
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


def input_scale(params: ModelParams) -> np.ndarray:
    """Scales [alpha (m/s^2), beta (rad)] that make the smoothing term dimensionless, (2,).

    Each input is measured in units of its largest admissible magnitude. Why: forward Euler
    (eq.tompc_dy) with the linearised slip terms of eq.kinematic_bicycle lets a time-optimal plan
    gain about 1% of x-speed by flipping beta between +-slip_max every stage (psi jumps across zero,
    so cos(psi) - sin(psi) beta > 1), which shortens T by 1-2%. Penalising raw beta (rad) at weight
    1e-3 is too weak to stop this discretisation artefact, and IPOPT then crawls through the
    chatter: on 40 cold Q1 starts along Table II closed loops (uniform DT) raw units took 101 mean
    iterations with 7 over 150, bound units 48 with none. In bound units T at weight 1e-3 is within
    0.1% of T at 1e-2, i.e. the smoothing itself costs no measurable time.
    """
    e = params.ego
    return np.array([max(abs(e.accel_min_mps2), abs(e.accel_max_mps2)), e.slip_max_rad])


def constraint_bounds(structure: OcpStructure) -> tuple[np.ndarray, np.ndarray]:
    """(lbg, ubg), each (n_g,): equalities == 0, inequalities >= 0."""
    lay = NlpLayout.of(structure)
    lbg = np.zeros(lay.n_g)
    ubg = np.full(lay.n_g, np.inf)
    ubg[: lay.n_eq] = 0.0
    return lbg, ubg


def decision_bounds(params: ModelParams, structure: OcpStructure) -> tuple[np.ndarray, np.ndarray]:
    """(lbx, ubx), each (n_w,), from EgoLimits and Mpc (eq.tompc_u, eq.tompc_v, eq.tompc_t).

    X[:, 0] is left unbounded: it is fixed by the initial-state equality, and a measured state
    slightly outside the state bounds must not make the problem infeasible. The clock and veh_o's
    predicted states are free (fixed by their equalities).
    """
    e, m, n = params.ego, params.mpc, structure.horizon
    lay = NlpLayout.of(structure)
    x_lo = np.array([-np.inf, e.y_min_m, -e.heading_max_rad, e.speed_min_mps])
    x_hi = np.array([np.inf, e.y_max_m, e.heading_max_rad, e.speed_max_mps])
    X_lo = np.vstack([np.full(N_X, -np.inf), np.tile(x_lo, (n, 1))])
    X_hi = np.vstack([np.full(N_X, np.inf), np.tile(x_hi, (n, 1))])
    U_lo = np.tile([e.accel_min_mps2, -e.slip_max_rad], (n, 1))
    U_hi = np.tile([e.accel_max_mps2, e.slip_max_rad], (n, 1))
    lbx, ubx = np.full(lay.n_w, -np.inf), np.full(lay.n_w, np.inf)
    ws = lay.w_slices
    lbx[ws["x"]], ubx[ws["x"]] = X_lo.ravel(), X_hi.ravel()
    lbx[ws["u"]], ubx[ws["u"]] = U_lo.ravel(), U_hi.ravel()
    lbx[ws["dt"]], ubx[ws["dt"]] = m.dt_min_s, m.dt_max_s
    return lbx, ubx


# --------------------------------------------------------------------------------------------------
# Initial guess
# --------------------------------------------------------------------------------------------------


_GUESS_STEP_S = 0.02  # resolution of the guess profiles (s)


def _speed_profile(params: ModelParams, v0: float, v_front: float, direction: int, t: np.ndarray) -> np.ndarray:
    """Guessed ego speed (m/s) at times t (s).

    Q1: towards the speed limit at 3/4 of the acceleration limit. Q2: down to 0.3 v_f (never up)
    at 3/4 of the braking limit, so the ego falls behind veh_f at a few m/s.
    """
    e = params.ego
    if direction > 0:
        rate, target = 0.75 * e.accel_max_mps2, e.speed_max_mps
    else:
        rate, target = 0.75 * abs(e.accel_min_mps2), min(max(0.3 * v_front, e.speed_min_mps), v0)
    return np.where(v0 < target, np.minimum(v0 + rate * t, target), np.maximum(v0 - rate * t, target))


def _lateral_path(params: ModelParams, t: np.ndarray, x_rel: np.ndarray, y0: float, v: np.ndarray) -> np.ndarray:
    """Guessed y (m) at times t: in the opposing lane while alongside veh_f, else in the ego lane.

    "Alongside" is |x - x_f| < 1.2 a. The lane changes are spread at half the largest lateral speed
    before and after (a max-plus dilation), and the path starts at y0.
    """
    e, road = params.ego, params.road
    v_lat = 0.5 * max(float(np.min(v)), 2.0) * (math.sin(e.heading_max_rad) + e.slip_max_rad)
    t_along = t[np.abs(x_rel) < 1.2 * params.barrier.ellipse_a_m]
    if t_along.size:
        # y_up(t) = max_s y_req(s) - v_lat |t - s| for y_req in {ego lane, opposing lane} (opposing above)
        idx = np.searchsorted(t_along, t)
        right = t_along[np.minimum(idx, t_along.size - 1)]
        left = t_along[np.maximum(idx - 1, 0)]
        dist = np.minimum(np.abs(t - right), np.abs(t - left))  # to the nearest time alongside
        y_up = np.maximum(road.ego_lane_y_m, road.opp_lane_y_m - v_lat * dist)
    else:
        y_up = np.full(t.size, road.ego_lane_y_m)
    return np.clip(y_up, y0 - v_lat * t, y0 + v_lat * t)


def _guess_profiles(
    params: ModelParams, ego: np.ndarray, front: np.ndarray, direction: int
) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(T, t, x, y, v) on a fine grid: guessed time to goal and the guessed path over [0, N dt_max]."""
    m = params.mpc
    horizon_s = m.horizon * m.dt_max_s
    t = np.arange(0.0, horizon_s + _GUESS_STEP_S, _GUESS_STEP_S)
    v = _speed_profile(params, max(ego[3], 0.0), front[2], direction, t)
    x = ego[0] + np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * _GUESS_STEP_S)])
    x_rel = x - (front[0] + front[2] * t)
    y = _lateral_path(params, t, x_rel, ego[1], v)
    margin = m.phi_s * front[2] + 1.0
    long_ok = x_rel >= margin if direction > 0 else x_rel <= -margin
    lat_ok = np.abs(y - params.road.ego_lane_y_m) <= 0.5 * m.eps_y_m
    done = np.flatnonzero(long_ok & lat_ok)
    total = t[done[0]] if done.size else horizon_s
    total = float(np.clip(total, 10 * m.dt_min_s * m.horizon, 0.95 * horizon_s))
    return total, t, x, y, v


def initial_guess(
    params: ModelParams,
    structure: OcpStructure,
    ego_state: np.ndarray,
    front_xyv: np.ndarray,
    direction: int,
    opp_xv: np.ndarray | None = None,
) -> np.ndarray:
    """A first guess for w, (n_w,).

    Speed: Q1 accelerates towards the speed limit, Q2 brakes to 0.3 v_f (both at 3/4 of the limit).
    Path: x integrates the speed; y moves to the opposing lane centre while the ego is alongside
    veh_f (|x - x_f| < 1.2 a) and to the ego lane otherwise, at half the largest lateral speed. T is
    the first time both the goal (with 1 m margin) and the lateral band are met, clipped to
    [10 N dt_min, 0.95 N dt_max]; DT = T/N. psi follows the path, and alpha, beta are the
    finite-difference inputs of the guess (clipped to their bounds). veh_o (with ``opp_xv``, (2,)
    [x_o m, v_o m/s]) is guessed at its measured speed.
    """
    n, e = structure.horizon, params.ego
    ego = np.asarray(ego_state, dtype=float).reshape(N_X)
    front = np.asarray(front_xyv, dtype=float).reshape(N_FRONT)
    total, t_fine, x_fine, y_fine, v_fine = _guess_profiles(params, ego, front, direction)
    dt = total / n
    t = dt * np.arange(n + 1)
    x, y, v = (np.interp(t, t_fine, f) for f in (x_fine, y_fine, v_fine))
    psi = np.clip(np.arctan2(np.diff(y), np.maximum(np.diff(x), 1e-3)), -e.heading_max_rad, e.heading_max_rad)
    psi = np.concatenate([[ego[2]], psi])
    X = np.column_stack([x, y, psi, v])
    X[0] = ego
    alpha = np.clip(np.diff(v) / dt, e.accel_min_mps2, e.accel_max_mps2)
    beta = np.diff(psi) * e.l_r_m / (np.maximum(v[:-1], 1.0) * dt)
    U = np.column_stack([alpha, np.clip(beta, -e.slip_max_rad, e.slip_max_rad)])
    xo = None
    if structure.with_opposing:
        if opp_xv is None:
            raise ValueError("this problem has an opposing vehicle: opp_xv (2,) [x_o, v_o] is required")
        x_o, v_o = np.asarray(opp_xv, dtype=float).reshape(N_OPP)
        xo = np.column_stack([x_o + v_o * t, np.full(n + 1, v_o)])  # at its measured speed
    return NlpLayout.of(structure).pack(X, U, np.full(n, dt), xo)
