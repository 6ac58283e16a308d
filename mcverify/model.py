"""The model's numbers: every value the paper states, and a named default for every value it leaves open.

All lengths in metres, speeds in m/s, accelerations in m/s^2, angles in radians, times in seconds.
Road frame: x along the road (direction of ego travel), y to the left; the ego lane centre is y = 0
and the opposing lane centre is y = +lane_width_m.

Each dataclass is frozen: a campaign builds new instances with :func:`dataclasses.replace`, and the
resolved values are written to every run's ``manifest.json``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field


@dataclass(frozen=True)
class VehicleGeometry:
    """Footprint of every vehicle (paper Sec. VI-A: Toyota Camry)."""

    length_m: float = 4.885
    width_m: float = 1.840


@dataclass(frozen=True)
class Road:
    """Two-lane, two-way road (paper Sec. VI-A: lane width 3.5 m)."""

    lane_width_m: float = 3.5

    @property
    def ego_lane_y_m(self) -> float:
        return 0.0

    @property
    def opp_lane_y_m(self) -> float:
        return self.lane_width_m


@dataclass(frozen=True)
class EgoLimits:
    """Input and state bounds of the ego kinematic bicycle (eq.kinematic_bicycle).

    The paper states only the speed limit (19.4 m/s = 70 km/h). The rest are named defaults:
    ``accel_max_mps2`` 3.0 (a Camry's 0-100 km/h in about 8 s), ``accel_min_mps2`` -6.0 (firm
    braking on dry asphalt), slip angle |beta| <= 0.15 rad, heading |psi| <= 0.35 rad, the c.g.
    kept on the road (ego-lane outer edge to opposing-lane outer edge, minus half a width), and the
    rear axle to c.g. distance ``l_r_m`` = 1.4 m (about half the Camry's 2.825 m wheelbase).
    """

    accel_min_mps2: float = -6.0
    accel_max_mps2: float = 3.0
    slip_max_rad: float = 0.15
    speed_min_mps: float = 0.0
    speed_max_mps: float = 19.4
    heading_max_rad: float = 0.35
    y_min_m: float = -0.83
    y_max_m: float = 4.33
    l_r_m: float = 1.4


@dataclass(frozen=True)
class Barrier:
    """Varying-level CBF to the front vehicle (eq.VL-CBF, Theorem thm.VL-CBF_levelset).

    h_ef(x_e, t) = ((x_e - x_f)/a)^2 + ((y_e - y_f)/b)^2 - 1 is the ellipse of fig.relative_CBF in the
    standard form (the paper's beta_1 = 1/a^2, beta_2 = 1/b^2, beta_3 = 1 up to a common scale).

    The default axes are the smallest-area ellipse through the corners (+-L, +-W) of the
    Minkowski sum of two aligned footprints: a = sqrt(2) L, b = sqrt(2) W. With the ego c.g. outside
    it, two aligned footprints cannot touch.

    ``lambdas_m`` are (lambda_1, ..., lambda_m), all > 0, so kappa~(h) = sum lambda_i h^(2i-1) is class K_e.
    The level is either ``epsilon`` (then lambda_0 = -kappa~(epsilon)) or ``lambda0`` directly.

    Opposing vehicle (eq.two_way_value_function_e): h_eo = x_o - x_e - (v_e - v_o)^2 / (2 a_l) (m)
    with a_l = ``decel_max_mps2``, the ego's own Lambda_eo = [-kappa~_eo(opp_epsilon_m),
    opp_lambdas_m...] (kappa~_eo(h) = sum lambda_i h^(2i-1), h in metres, so lambda_1 is in 1/s).
    The paper gives neither a_l nor Lambda_eo: a_l = 6 m/s^2 is the ego's braking limit, the
    level 1 m keeps a metre of stopping margin, and the linear kappa~ (m = 1) keeps the constraint
    well scaled when h_eo is tens of metres.
    """

    ellipse_a_m: float = math.sqrt(2.0) * 4.885
    ellipse_b_m: float = math.sqrt(2.0) * 1.840
    lambdas_m: tuple[float, ...] = (1.0, 0.5)
    epsilon: float | None = 0.3
    lambda0: float | None = None
    decel_max_mps2: float = 6.0
    opp_lambdas_m: tuple[float, ...] = (1.0,)
    opp_epsilon_m: float = 1.0

    @property
    def order_m(self) -> int:
        return len(self.lambdas_m)


#: The valid values of ``Mpc.backend`` (implemented by :mod:`mcverify.solver.backends`).
BACKEND_NAMES = ("ipopt", "ipm")
#: The MPC-DC baselines (Sec. VI-D): "mpcdc" keeps the ellipses at the nodes (h >= 0), "mpcdc_eps"
#: at the level of the cell (h >= barrier.epsilon); everything else about them is the same.
MPCDC_CONTROLLERS = ("mpcdc", "mpcdc_eps")
#: The evidence that makes the ego abandon the overtake (:attr:`Mpc.abandon_rule`).
ABANDON_RULES = ("first_failure", "consecutive", "certified")


@dataclass(frozen=True)
class Mpc:
    """TO-CBF-MPC settings (box eq.tompc).

    Paper: N = 50, goal reaction time phi = 1.8 s (x_g = x_f + phi v_f). Named defaults: the upper
    bound on every stage interval ``dt_max_s`` (eq.tompc_t; 0.3 s gives a 15 s horizon, enough for
    the slowest Table II overtake), the lower bound ``dt_min_s`` = 1e-4 s (the paper's "maximum time
    resolution"), the lateral goal tolerance ``eps_y_m`` (eq.tompc_y), and a small input-smoothing
    weight (the paper's Remark after eq.tompc allows it; it does not touch the safety constraints and
    makes the time-optimal problem well conditioned).

    ``controller``: "vlcbf" (the paper's dual TO-CBF-MPC, Q1 and Q2 with VL-CBF constraints) or
    "mpcdc" (the Sec. VI-D baseline: the same time-optimal MPC and horizon with the ellipses as
    distance constraints at the nodes, no Q2 backup) or "mpcdc_eps" (the same MPC-DC with the
    distance constraints at the cell's level, h >= ε (``barrier.epsilon``) instead of h >= 0: the
    ε-margin ellipse, a runtime bound of the same kernel). ``backend``: the NLP solver ("ipopt", the
    reference; "ipm", the fast path of :mod:`mcverify.solver.backends`, the default). ``max_iter`` bounds
    warm-started solves, ``max_iter_cold`` cold ones (a cold start with the opposing vehicle needs
    many more iterations than a warm one).

    ``infeasible_recheck_steps``: once IPOPT has certified a problem infeasible
    ("Infeasible_Problem_Detected"), the following steps try only the fast path on it (presumed
    infeasible when that fails) and give IPOPT the full attempt again after this many steps (1:
    every step, the exhaustive behaviour). Every full attempt that fails again (certified or out of
    iterations) doubles the wait, up to ``infeasible_recheck_max_steps`` (equal to
    ``infeasible_recheck_steps``: a fixed period). A fast-path success within the wait does not
    end it: under perception noise a problem at the edge of feasibility flickers between solved and
    certified infeasible from one step to the next. Only the dual planner's Q1 and Q2 are presumed:
    MPC-DC has no second problem, so a presumed failure there would decide the control by itself
    (the held plan); MPC-DC always gets the full attempt. The fast path still tries every step, so
    a problem it can solve is back at once; the wait only delays what IPOPT alone could solve (up to
    1 s at 50 Hz). Only the ``ipm`` backend has a fast path; ``ipopt`` always runs in full. Why
    the memo exists, with its measurements: ``docs/decisions.md``.

    ``abandon_rule``: what evidence makes the ego abandon the overtake (Algorithm 1's break out of
    the Q1 loop, and Table I's row 0 "go back: Q1 not solved" for a human-driven veh_o). The paper
    says only "whenever the feasibility of Q1 is being challenged, we merge back" (Sec. IV) and
    Algorithm 1 breaks at the first step Q1 is not solved; it does not say what challenges it. A
    failed solve is not a proof: half of the turn-backs measured on Table III-like runs came from
    IPOPT iteration limits, often on a step where the noisy measured veh_f speed was 6-9 % above
    the truth. The rules:

    * "first_failure" (the default, the paper's Algorithm 1 read literally): the first failed Q1
      solve abandons, whatever the reason;
    * "consecutive": ``abandon_after_failures`` consecutive failed Q1 solves (k, default 3) abandon;
    * "certified": only a Q1 failure the solver certified infeasible (IPOPT's certificate, or a
      failure presumed infeasible by the infeasibility memo after such a certification) abandons;
      iteration limits and numerical failures do not.

    While the rule has not fired and Q1 failed (with Q2 solved), the ego keeps following its last
    Q1 plan (the held plan, counted in ``q1_held_steps``); once that plan is used up (or there is
    none) the rule no longer waits and Algorithm 1 goes on as in "first_failure". Everything else
    of Algorithm 1 and Table I is unchanged.
    """

    controller: str = "vlcbf"
    backend: str = "ipm"
    horizon: int = 50
    dt_max_s: float = 0.3
    dt_min_s: float = 1e-4
    phi_s: float = 1.8
    eps_y_m: float = 0.25
    smooth_weight: float = 1e-3
    max_iter: int = 150
    max_iter_cold: int = 400
    infeasible_recheck_steps: int = 10
    infeasible_recheck_max_steps: int = 50
    abandon_rule: str = "first_failure"
    abandon_after_failures: int = 3
    tol: float = 1e-6

    @property
    def is_mpcdc(self) -> bool:
        """An MPC-DC baseline (:data:`MPCDC_CONTROLLERS`): distance constraints, no Q2."""
        return self.controller in MPCDC_CONTROLLERS


@dataclass(frozen=True)
class Noise:
    """Perception noise (paper Sec. VI-A), applied to what the planner measures of other vehicles.

    ``kind``: "paper" or "none". Position noise uniform in +-``pos_far_m`` when the footprint gap to
    the measured vehicle exceeds ``near_threshold_m``, else +-``pos_near_m``; speed noise uniform in
    +-``speed_rel`` of the true speed. ``scale`` multiplies all three half-widths (a stronger noise
    for sweeps). The ego's own state is measured exactly (odometry); the paper's noise is on "the
    measured objects".

    Structured, bounded disturbances (what ``mcverify falsify`` searches over; all 0 by default,
    which leaves the paper's noise bit for bit as it was): each measured error is
    ``half_width * ((1 - structured_share) * u + structured_share * s(t))`` with ``u`` the uniform
    draw in [-1, 1] and ``s(t) = clip(bias + drift_per_s * t, -1, 1)`` per vehicle (front/opp) and
    quantity (x position, speed), t the episode time (s). So the error stays inside the declared
    bounds (the half-widths above) whatever the disturbance: a per-episode bias, a slow drift and the
    random part share the same budget. Biases in [-1, 1] (fractions of the half-width), drifts in
    1/s, the share in [0, 1].
    """

    kind: str = "paper"
    pos_far_m: float = 0.5
    pos_near_m: float = 0.1
    near_threshold_m: float = 2.0
    speed_rel: float = 0.1
    scale: float = 1.0
    structured_share: float = 0.0
    front_x_bias: float = 0.0
    front_x_drift_per_s: float = 0.0
    front_v_bias: float = 0.0
    front_v_drift_per_s: float = 0.0
    opp_x_bias: float = 0.0
    opp_x_drift_per_s: float = 0.0
    opp_v_bias: float = 0.0
    opp_v_drift_per_s: float = 0.0


@dataclass(frozen=True)
class Simulation:
    """Closed-loop timing.

    ``control_period_s``: the planner's sampling period (paper: 50 Hz towards the opposing vehicle).
    ``substeps``: RK4 sub-steps per control period under zero-order hold; every safety check is
    evaluated at every sub-step. ``max_time_s``: an episode that has neither overtaken nor gone back
    by then ends as a timeout. ``settle_s``: after the goal test fires ("overtook" / "went_back"),
    the plant keeps running this long (at most until ``max_time_s``) under the lane-keeping law of
    :mod:`mcverify.control.lane_keeping`, every safety check included; the outcome and its time stay
    those of the goal test. 0: the episode ends at the goal test.
    """

    control_period_s: float = 0.02
    substeps: int = 10
    max_time_s: float = 25.0
    settle_s: float = 3.0


@dataclass(frozen=True)
class Scenario:
    """Initial conditions (paper Sec. VI-B: ego at x = 10 m, 10 m/s; front vehicle at x = 64 m).

    ``front_accel_mps2`` > 0 makes the front vehicle accelerate from ``front_accel_onset_s`` on, up
    to ``front_speed_max_mps`` (it never switches sign, the paper's assumption).
    ``front_accel_range_mps2`` = (lo, hi), when given, replaces it: every episode draws its own
    alpha_f uniformly in (lo, hi] from its key (the paper's Table III ranges (1,3], (3,5], (5,7]).
    ``front_accel_duration_s``: how long the acceleration lasts from its onset (default: until the
    speed cap); after it veh_f keeps its speed (it still never decelerates).
    """

    ego_x_m: float = 10.0
    ego_speed_mps: float = 10.0
    front_x_m: float = 64.0
    front_speed_mps: float = 25.0 / 3.6
    front_accel_mps2: float = 0.0
    front_accel_range_mps2: tuple[float, ...] = ()
    front_accel_onset_s: float = 0.0
    front_accel_duration_s: float = math.inf
    front_speed_max_mps: float = 30.0


@dataclass(frozen=True)
class Opposing:
    """The opposing vehicle veh_o: a double integrator (eq.double_integrator) on the opposing lane
    centre, driving towards -x (its road-frame velocity is -speed).

    ``kind``:
    * "none": no opposing vehicle (Table II);
    * "autonomous": a cruise law alpha = ``cruise_gain_per_s`` (speed_mps - speed) filtered by its
      own VL-CBF on h_oe (eq.tompcAdd_cbf_oe) with Lambda_o = [-kappa~_o(``epsilon_m``),
      ``lambdas_m``...], solved exactly at every control step; its parameters are known to the
      ego (the paper's "via communications"), so the planner predicts it with the same law;
    * "human": accelerates towards ``speed_limit_mps`` at ``accel_mps2`` (the paper's Case 2 uses
      1.6 m/s^2; 0 = constant speed, Table IV). The planner does not know this law and predicts the
      worst case: ``accel_max_mps2`` towards the ego, capped at ``speed_limit_mps`` (Sec. V-C).

    ``x_m``: initial c.g. position; ``speed_mps`` >= 0: initial (and cruise) speed magnitude;
    ``detect_range_m``: the ego's sensors see veh_o (and Algorithm 1 adds eq.tompcAdd) once the
    longitudinal distance x_o - x_e is below it; ``brake_max_mps2``: the largest deceleration of
    veh_o (its CBF filter is clipped to it).

    When veh_o appears (``spawn``; the paper does not say, and with a fixed start the two vehicles
    rarely meet while the ego borrows the lane):
    * "start": it drives from ``x_m`` at t = 0 (Tables III-IV as first reproduced);
    * "lane_entry": it appears when the ego's footprint first crosses the lane line into the
      opposing lane (or ``spawn_delay_s`` later, when the ego is further into its overtake),
      ``spawn_gap_m`` ahead of the ego (x_o - x_e, m), so that every episode that starts an
      overtake meets it mid-overtake. ``spawn_gap_range_m`` = (lo, hi), when given,
      draws the gap per episode uniformly in (lo, hi] from the episode's key;
      ``speed_range_mps`` = (lo, hi) likewise draws veh_o's speed (either spawn mode).
    """

    kind: str = "none"
    x_m: float = 250.0
    speed_mps: float = 15.0
    accel_mps2: float = 0.0
    speed_limit_mps: float = 19.4
    accel_max_mps2: float = 3.0
    brake_max_mps2: float = 6.0
    cruise_gain_per_s: float = 1.0
    lambdas_m: tuple[float, ...] = (1.0,)
    epsilon_m: float = 1.0
    detect_range_m: float = 200.0
    spawn: str = "start"
    spawn_gap_m: float = 150.0
    spawn_gap_range_m: tuple[float, ...] = ()
    spawn_delay_s: float = 0.0
    speed_range_mps: tuple[float, ...] = ()


@dataclass(frozen=True)
class ModelParams:
    """Everything that defines one cell of a campaign, except the episode count and seed."""

    geometry: VehicleGeometry = field(default_factory=VehicleGeometry)
    road: Road = field(default_factory=Road)
    ego: EgoLimits = field(default_factory=EgoLimits)
    barrier: Barrier = field(default_factory=Barrier)
    mpc: Mpc = field(default_factory=Mpc)
    noise: Noise = field(default_factory=Noise)
    sim: Simulation = field(default_factory=Simulation)
    scenario: Scenario = field(default_factory=Scenario)
    opposing: Opposing = field(default_factory=Opposing)

    def to_dict(self) -> dict:
        return asdict(self)
