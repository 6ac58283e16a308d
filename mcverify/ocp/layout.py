"""Layouts of the TO-CBF-MPC NLP: what the compiled code depends on, and how its vectors are laid out.

Units: metres, seconds, radians, m/s, m/s^2. Road frame as in :mod:`mcverify.model`.

:class:`OcpStructure` holds the choices that change the compiled code. Everything numeric that may
change between solves (measurements, direction, goal, barrier coefficients, the opposing vehicle's
law) is a parameter (:class:`ParamLayout`, filled in by :func:`pack_params`) or a runtime bound
(:func:`decision_bounds`, :func:`constraint_bounds`), so one compiled kernel serves every campaign
cell with the same structure.

Decision vector ``w`` (see :class:`NlpLayout`), all stacked node by node:

* ``X``  (4, N+1): ego states ``[x, y, psi, v]`` at the nodes 0..N,
* ``U``  (2, N):   inputs ``[alpha, beta]`` (acceleration m/s^2, slip angle rad) on the stages,
* ``DT`` (N,):     stage intervals in seconds (the time-optimal part, eq.tompc_t),
* ``t``  (N+1,):   node times t_i = sum_{j<i} DT_j (s), an auxiliary clock fixed by equalities,
* ``XO`` (2, N+1): with an opposing vehicle, its predicted ``[x_o, v_o]`` (v_o signed, < 0 when
  it drives towards the ego), eq.tompcAdd_dynamic_o.

The clock is the same maths as writing t_i = cumsum(DT) into the barrier, but keeps every row of
the KKT system local to one stage (banded): with the cumsum, CBF row i depends on DT_0..DT_{i-1}
and the Lagrangian Hessian fills in, which makes IPOPT's linear algebra (it dominates the solve)
dearer per iteration and the generated C larger.

The constraint vector ``g`` is described in :mod:`mcverify.ocp.problem`; its blocks are
:attr:`NlpLayout.g_slices`, equalities first.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mcverify.levels import Level, lambda0_from_epsilon
from mcverify.model import ModelParams

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
    dt_min, and where they sit barely changes T), and IPOPT crawls through it, while uniform DT
    converges in a fraction of the iterations with T within a fraction of a percent of the free-DT T.
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
            constraint="distance" if params.mpc.is_mpcdc else "cbf",
            opp_order_m=len(params.barrier.opp_lambdas_m),
            opp_law_order_m=len(params.opposing.lambdas_m),
        )


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


def input_scale(params: ModelParams) -> np.ndarray:
    """Scales [alpha (m/s^2), beta (rad)] that make the smoothing term dimensionless, (2,).

    Each input is measured in units of its largest admissible magnitude. Why: forward Euler
    (eq.tompc_dy) with the linearised slip terms of eq.kinematic_bicycle lets a time-optimal plan
    gain about 1% of x-speed by flipping beta between +-slip_max every stage (psi jumps across zero,
    so cos(psi) - sin(psi) beta > 1), which shortens T by 1-2%. Penalising raw beta (rad) at weight
    1e-3 is too weak to stop this discretisation artefact, and IPOPT then crawls through the
    chatter; in bound units it does not, and the smoothing itself costs no measurable time T.
    """
    e = params.ego
    return np.array([max(abs(e.accel_min_mps2), abs(e.accel_max_mps2)), e.slip_max_rad])


def opposing_mode(params: ModelParams) -> str:
    """Which law the planner predicts veh_o with (one of :data:`OPP_MODES`).

    MPC-DC (the conventional baseline) extrapolates the measured speed; the VL-CBF planner predicts
    an autonomous veh_o with its known law and a human driver with the worst case (Sec. V-C).
    """
    if params.mpc.is_mpcdc:
        return "constant"
    return "law" if params.opposing.kind == "autonomous" else "worst"


def pack_params(
    params: ModelParams,
    ego_state: np.ndarray,
    front_xyv: np.ndarray,
    direction: int,
    level: Level,
    y_goal: float | None = None,
    *,
    opp_xv: np.ndarray | None = None,
    structure: OcpStructure | None = None,
) -> np.ndarray:
    """Parameter vector p (layout :class:`ParamLayout`) for one solve.

    ego_state: (4,) [x m, y m, psi rad, v m/s]. front_xyv: (3,) [x_f m, y_f m, v_f m/s].
    direction: +1 (Q1, overtake) or -1 (Q2, go back). level: the cell's VL-CBF level (its lambda0 enters p).
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
    p[sl["lambdas"]] = (level.lambda0, *params.barrier.lambdas_m)
    p[sl["l_r"]] = params.ego.l_r_m
    p[sl["u_scale"]] = input_scale(params)
    p[sl["smooth_weight"]] = params.mpc.smooth_weight
    if structure.with_opposing:

        b, o, geo, road = params.barrier, params.opposing, params.geometry, params.road
        p[sl["opp"]] = np.asarray(opp_xv, dtype=float).reshape(N_OPP)
        p[sl["opp_mode"]] = [float(m == opposing_mode(params)) for m in OPP_MODES]
        p[sl["decel_max"]] = b.decel_max_mps2
        p[sl["opp_lambdas"]] = (lambda0_from_epsilon(b.opp_lambdas_m, b.opp_epsilon_m), *b.opp_lambdas_m)
        p[sl["opp_law_lambdas"]] = (lambda0_from_epsilon(o.lambdas_m, o.epsilon_m), *o.lambdas_m)
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


def distance_margin(params: ModelParams) -> float:
    """The level the MPC-DC distance rows keep (h >= it at the nodes): for "mpcdc_eps" (the
    ε-margin ellipse) the cell's level ε (``barrier.epsilon``, or the ε of ``barrier.lambda0``), 0
    otherwise (the ellipse itself)."""
    if params.mpc.controller != "mpcdc_eps":
        return 0.0
    return Level.of_barrier(params.barrier).epsilon


def constraint_bounds(structure: OcpStructure, margin: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(lbg, ubg), each (n_g,): equalities == 0, inequalities >= 0.

    margin: with ``constraint="distance"`` (MPC-DC) the distance rows of the front and the opposing
    vehicle's ellipses get ``>= margin`` (:func:`distance_margin`): a runtime bound, so the margin
    needs no kernel of its own.
    """
    lay = NlpLayout.of(structure)
    lbg = np.zeros(lay.n_g)
    ubg = np.full(lay.n_g, np.inf)
    ubg[: lay.n_eq] = 0.0
    if margin and structure.constraint == "distance":
        gs = lay.g_slices
        lbg[gs["front"]] = margin
        lbg[gs["opp"]] = margin
    elif margin:
        raise ValueError(f"a distance margin ({margin}) needs constraint='distance', got {structure.constraint!r}")
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
