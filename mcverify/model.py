"""The model's numbers: every value the paper states, and a named default for every value it leaves open.

All lengths in metres, speeds in m/s, accelerations in m/s^2, angles in radians, times in seconds.
Road frame: x along the road (direction of ego travel), y to the left; the ego lane centre is y = 0
and the opposing lane centre is y = +lane_width_m.

Each dataclass is frozen: a campaign builds new instances with :func:`dataclasses.replace`, and the
resolved values are written to every run's ``manifest.json``.
"""

from __future__ import annotations

import math
import statistics
from dataclasses import asdict, dataclass, field

from mcverify import requirements as _requirements


@dataclass(frozen=True)
class VehicleGeometry:
    """Footprint of every vehicle (paper Sec. VI-A: Toyota Camry)."""

    length_m: float = 4.885
    """Footprint length of every vehicle. Valid: > 0. Paper: 4.885 (Toyota Camry)."""
    width_m: float = 1.840
    """Footprint width of every vehicle. Valid: > 0. Paper: 1.840."""


@dataclass(frozen=True)
class Road:
    """Two-lane, two-way road (paper Sec. VI-A: lane width 3.5 m)."""

    lane_width_m: float = 3.5
    """Width of each of the two lanes. Valid: > 0. Paper: 3.5."""

    @property
    def ego_lane_y_m(self) -> float:
        return 0.0

    @property
    def opp_lane_y_m(self) -> float:
        return self.lane_width_m


@dataclass(frozen=True)
class EgoLimits:
    """Input and state bounds of the ego kinematic bicycle (eq.kinematic_bicycle). The paper states only the
    speed limit (19.4 m/s = 70 km/h); the others are named defaults: a Camry's acceleration (0-100 km/h in about
    8 s), firm braking on dry asphalt, the c.g. kept on the road, and l_r about half the Camry's 2.825 m wheelbase.
    """

    accel_min_mps2: float = -6.0
    """Ego's strongest braking (a negative acceleration). Valid: < 0. Paper: not given."""
    accel_max_mps2: float = 3.0
    """Ego's largest acceleration. Valid: > 0. Paper: not given."""
    slip_max_rad: float = 0.15
    """Bound on the bicycle's slip angle beta. Valid: > 0. Paper: not given."""
    speed_min_mps: float = 0.0
    """Lowest ego speed. Valid: >= 0, below speed_max_mps."""
    speed_max_mps: float = 19.4
    """Ego speed limit (also set as ego.speed_max_kmh). Valid: > 0. Paper: 19.4 (70 km/h)."""
    heading_max_rad: float = 0.35
    """Bound on the ego heading psi. Valid: > 0. Paper: not given."""
    y_min_m: float = -0.83
    """Lowest lateral position of the ego c.g. (road edge minus half a width). Paper: not given."""
    y_max_m: float = 4.33
    """Highest lateral position of the ego c.g. Valid: > y_min_m. Paper: not given."""
    l_r_m: float = 1.4
    """Rear axle to c.g. distance of the bicycle model. Valid: > 0. Paper: not given."""


@dataclass(frozen=True)
class Barrier:
    """Varying-level CBF to the front vehicle (eq.VL-CBF, Theorem thm.VL-CBF_levelset).

    h_ef(x_e, t) = ((x_e - x_f)/a)^2 + ((y_e - y_f)/b)^2 - 1 is the ellipse of fig.relative_CBF in the
    standard form (the paper's beta_1 = 1/a^2, beta_2 = 1/b^2, beta_3 = 1 up to a common scale).

    The default axes are the smallest-area ellipse through the corners (+-L, +-W) of the Minkowski sum of two
    aligned footprints: a = sqrt(2) L, b = sqrt(2) W (with the ego c.g. outside it, they cannot touch). The level:
    :class:`mcverify.levels.Level` (``epsilon`` or ``lambda0``, with ``lambdas_m``).

    Opposing vehicle (eq.two_way_value_function_e): h_eo = x_o - x_e - (v_e - v_o)^2 / (2 a_l) (m), a_l =
    ``decel_max_mps2``, Lambda_eo = [-kappa~_eo(opp_epsilon_m), opp_lambdas_m...] (h in metres, lambda_1 in 1/s).
    The paper gives neither: a_l is the ego's braking limit, the level 1 m keeps a metre of stopping margin, and
    the linear kappa~ (m = 1) keeps the constraint well scaled when h_eo is tens of metres.
    """

    ellipse_a_m: float = math.sqrt(2.0) * 4.885
    """Longitudinal semi-axis of the safety ellipse h_ef. Valid: > 0. Paper: not given (beta_1)."""
    ellipse_b_m: float = math.sqrt(2.0) * 1.840
    """Lateral semi-axis of the safety ellipse. Valid: > 0. Paper: not given (beta_2)."""
    lambdas_m: tuple[float, ...] = (1.0, 0.5)
    """(lambda_1, ..., lambda_m) of kappa~(h) = sum lambda_i h^(2i-1). Valid: all > 0, 1-3 of them. Paper: order 2."""
    epsilon: float | None = 0.3
    """The level epsilon of the VL-CBF (lambda_0 = -kappa~(epsilon)); set this or lambda0. Valid: >= 0. Paper: 0.3."""
    lambda0: float | None = None
    """The level parameter lambda_0 directly; set this or epsilon. Valid: <= 0."""
    decel_max_mps2: float = 6.0
    """a_l of h_eo, the ego's assumed braking when meeting veh_o. Valid: > 0. Paper: not given."""
    opp_lambdas_m: tuple[float, ...] = (1.0,)
    """lambda_i of the ego's kappa~_eo on h_eo (h in metres, lambda_1 in 1/s). Valid: all > 0."""
    opp_epsilon_m: float = 1.0
    """Level of h_eo (metres of stopping margin). Valid: >= 0. Paper: not given."""

    @property
    def order_m(self) -> int:
        return len(self.lambdas_m)


#: The valid values of ``Mpc.backend`` (implemented by :mod:`mcverify.solver.backends`).
BACKEND_NAMES = ("ipopt", "ipm")
#: The MPC-DC baselines (Sec. VI-D): "mpcdc" keeps the ellipses at the nodes (h >= 0), "mpcdc_eps"
#: at the level of the cell (h >= barrier.epsilon); everything else about them is the same.
MPCDC_CONTROLLERS = ("mpcdc", "mpcdc_eps")
#: The controllers that keep no level ε of h_ef: plain MPC-DC keeps the ellipse itself (h >= 0 at the
#: nodes), so a figure draws no ε line for it.
CONTROLLERS_WITHOUT_LEVEL = ("mpcdc",)


def kept_level(controller: str | None, epsilon: float) -> float | None:
    """The level of h_ef that ``controller`` keeps: the cell's ε, or None for plain MPC-DC (h >= 0)."""
    return None if controller in CONTROLLERS_WITHOUT_LEVEL else float(epsilon)
#: The evidence that makes the ego abandon the overtake (:attr:`Mpc.abandon_rule`).
ABANDON_RULES = ("first_failure", "consecutive", "certified")
#: When the dual planner solves Q2 while overtaking (:attr:`Mpc.q2_solve`).
Q2_SOLVE_POLICIES = ("every_step", "fast_when_unneeded", "when_needed")
#: Most piecewise-constant segments of one structured disturbance (:attr:`Noise.front_x_segments`).
MAX_SEGMENTS = 8
#: Most noise branches of one episode (:attr:`Noise.branch_after_steps`).
MAX_BRANCHES = 64
#: The requirements (each also a valid :attr:`Simulation.stop_at`) and what a falsification search may
#: minimise instead (``[falsify] guide``): the registry's, :mod:`mcverify.requirements`.
REQUIREMENT_NAMES: tuple[str, ...] = _requirements.REQUIREMENT_NAMES
GUIDE_NAMES: tuple[str, ...] = _requirements.GUIDE_NAMES


@dataclass(frozen=True)
class Mpc:
    """TO-CBF-MPC settings (box eq.tompc): the controller, its optimal-control problem, and (last) the
    solver's tuning.

    Paper: N = 50, phi = 1.8 s (x_g = x_f + phi v_f). Named defaults: ``dt_max_s`` (eq.tompc_t; 0.3 s gives a
    15 s horizon, enough for the slowest Table II overtake), ``dt_min_s`` (the paper's "maximum time
    resolution"), ``eps_y_m`` (eq.tompc_y) and a small input-smoothing weight (allowed by the Remark after
    eq.tompc; it does not touch the safety constraints and makes the time-optimal problem well conditioned).
    ``abandon_rule`` reads Sec. IV's "whenever the feasibility of Q1 is being challenged, we merge back" three
    ways; while it waits, the ego follows its last Q1 plan (``q1_held_steps``). The ``ipm`` backend's attempts
    per controller family are data (:mod:`mcverify.solver.attempts`), not options: docs/decisions.md.
    """

    controller: str = "vlcbf"
    """vlcbf (the paper's dual TO-CBF-MPC), mpcdc (the Sec. VI-D baseline: distance constraints at the nodes, no
    Q2) or mpcdc_eps (the baseline at the level epsilon, h >= barrier.epsilon)."""
    horizon: int = 50
    """Number of MPC stages N. Valid: 2-500. Paper: 50."""
    dt_max_s: float = 0.3
    """Upper bound of every stage interval (eq.tompc_t). Valid: > dt_min_s. Paper: not given."""
    dt_min_s: float = 1e-4
    """Lower bound of every stage interval. Valid: > 0. Paper: 1e-4 (its time resolution)."""
    phi_s: float = 1.8
    """Goal reaction time phi: x_g = x_f + v_f T +- phi v_f. Valid: >= 0. Paper: 1.8."""
    eps_y_m: float = 0.25
    """Lateral goal tolerance epsilon_y (eq.tompc_y). Valid: > 0. Paper: not given."""
    smooth_weight: float = 1e-3
    """Weight of the input-smoothing term. Valid: >= 0. Paper: allowed by its Remark, no value."""
    abandon_rule: str = "first_failure"
    """What abandons the overtake: first_failure (Algorithm 1 literally: the first failed Q1 solve), consecutive
    (abandon_after_failures failed Q1 solves in a row) or certified (only a Q1 failure certified infeasible)."""
    abandon_after_failures: int = 3
    """Failed Q1 solves in a row that abandon with abandon_rule = consecutive. Valid: >= 1."""
    q2_solve: str = "every_step"
    """How Q2 is solved at the steps whose decision does not read it: every_step (Algorithm 1: in full),
    fast_when_unneeded (the fast path only) or when_needed (not at all)."""

    # ---- solver tuning: how the NLP is solved, not which NLP ----
    backend: str = "ipm"
    """NLP solver: ipm (the fast path, IPOPT as fallback) or ipopt (the reference)."""
    max_iter: int = 150
    """Solver iterations of a warm-started solve. Valid: >= 1."""
    max_iter_cold: int = 400
    """Solver iterations of a cold solve. Valid: >= 1."""
    tol: float = 1e-6
    """Solver tolerance on the scaled KKT error. Valid: > 0."""
    infeasible_recheck_steps: int = 10
    """After IPOPT certifies a VL-CBF problem infeasible, steps the fast path alone tries it (presumed infeasible
    when it fails) before IPOPT tries it in full again (1: every step); docs/decisions.md. Valid: >= 1."""
    infeasible_recheck_max_steps: int = 50
    """Largest wait of the doubling recheck period. Valid: >= infeasible_recheck_steps."""
    infeasibility_audit_every: int = 10
    """Where the C phase 1 certifies infeasibility (the MPC-DC baselines on the ipm backend): about one certificate
    in this many is re-checked by IPOPT (1: every one). Valid: >= 1."""

    @property
    def is_mpcdc(self) -> bool:
        """An MPC-DC baseline (:data:`MPCDC_CONTROLLERS`): distance constraints, no Q2."""
        return self.controller in MPCDC_CONTROLLERS


@dataclass(frozen=True)
class Noise:
    """Perception noise (paper Sec. VI-A), applied to what the planner measures of other vehicles.

    Position noise uniform in +-``pos_far_m`` (+-``pos_near_m`` when the footprint gap is below
    ``near_threshold_m``), speed noise uniform in +-``speed_rel`` of the true speed, all times ``scale``. The
    ego's own state is measured exactly (odometry); the paper's noise is on "the measured objects".

    Structured, bounded disturbances (what ``mcverify falsify`` searches over; all 0 by default,
    which leaves the paper's noise bit for bit as it was): each measured error is
    ``half_width * ((1 - structured_share) * u + structured_share * s(t))`` with ``u`` the uniform
    draw in [-1, 1] and ``s(t) = clip(bias + drift_per_s * t, -1, 1)`` per vehicle (front/opp) and
    quantity (x position, speed), t the episode time (s). So the error stays inside the declared
    bounds (the half-widths above) whatever the disturbance: a per-episode bias, a slow drift and the
    random part share the same budget. Biases in [-1, 1] (fractions of the half-width), drifts in
    1/s, the share in [0, 1]. Piecewise-constant offsets (``*_segments``, K <= :data:`MAX_SEGMENTS`
    values in [-1, 1] each): the episode duration ``sim.max_time_s`` is cut into K equal segments and
    the k-th value is added inside the clip during segment k, so ``s(t) = clip(bias + drift_per_s * t
    + offset_k(t), -1, 1)``; () (the default) adds nothing.

    veh_f's measured lateral position (y) has its own share, ``lateral_share`` (default 0, so the
    x/speed share never changes y): its error is ``half_width * ((1 - lateral_share) * u_y +
    lateral_share * s_y)`` with ``s_y = clip(front_y_bias + front_y_drift_per_s * t + offset_k(t) +
    gap_offset_j(gap), -1, 1)``, where the time offsets ``front_y_segments`` are as above and the
    *gap offsets* ``front_y_gap_segments`` cut veh_f's true footprint gap [0, front_y_gap_window_m]
    into J equal bands (band 0 the nearest) and add the j-th value while the gap is in band j, nothing
    beyond the window: a lateral error keyed to where the ego is, e.g. veh_f measured 1 m towards the
    ego exactly as the ego comes alongside, the pattern that makes Q1 infeasible there
    (docs/rare_events.md, "What decides an event at lower noise"). veh_o's lateral position is not
    measured (it is taken on its lane centre), so it has no lateral disturbance.
    """

    kind: str = "paper"
    """paper (the Sec. VI-A perception noise) or none."""
    pos_far_m: float = 0.5
    """Half-width of the uniform position noise when the footprint gap exceeds near_threshold_m. Valid: >= 0. Paper:
    0.5."""
    pos_near_m: float = 0.1
    """Half-width of the position noise when the gap is below near_threshold_m. Valid: >= 0. Paper: 0.1."""
    near_threshold_m: float = 2.0
    """Footprint gap that switches between the far and near noise. Valid: >= 0. Paper: 2."""
    speed_rel: float = 0.1
    """Half-width of the uniform speed noise, relative to the true speed. Valid: >= 0. Paper: 0.1 (10 %)."""
    scale: float = 1.0
    """Multiplies all three half-widths (sweeps of a stronger noise). Valid: >= 0. Paper: 1."""
    structured_share: float = 0.0
    """Share of each x-position and speed error taken by the structured disturbance. Valid: [0, 1]. Paper: 0 (none)."""
    front_x_bias: float = 0.0
    """Structured bias of veh_f's measured x, as a fraction of its half-width. Valid: [-1, 1]. Paper: 0."""
    front_x_drift_per_s: float = 0.0
    """Drift of veh_f's x disturbance (1/s; clipped to [-1, 1] with the bias). Valid: finite. Paper: 0."""
    front_v_bias: float = 0.0
    """Structured bias of veh_f's measured speed, as a fraction of its half-width. Valid: [-1, 1]. Paper: 0."""
    front_v_drift_per_s: float = 0.0
    """Drift of veh_f's speed disturbance (1/s). Valid: finite. Paper: 0."""
    opp_x_bias: float = 0.0
    """Structured bias of veh_o's measured x, as a fraction of its half-width. Valid: [-1, 1]. Paper: 0."""
    opp_x_drift_per_s: float = 0.0
    """Drift of veh_o's x disturbance (1/s). Valid: finite. Paper: 0."""
    opp_v_bias: float = 0.0
    """Structured bias of veh_o's measured speed, as a fraction of its half-width. Valid: [-1, 1]. Paper: 0."""
    opp_v_drift_per_s: float = 0.0
    """Drift of veh_o's speed disturbance (1/s). Valid: finite. Paper: 0."""
    front_x_segments: tuple[float, ...] = ()
    """Piecewise-constant offsets of veh_f's x disturbance, one per equal segment of sim.max_time_s (added to bias +
    drift t before the clip). Valid: up to 8 values in [-1, 1]. Paper: () (none)."""
    front_v_segments: tuple[float, ...] = ()
    """Piecewise-constant offsets of veh_f's speed disturbance (see front_x_segments). Valid: up to 8 values in [-1,
    1]. Paper: ()."""
    opp_x_segments: tuple[float, ...] = ()
    """Piecewise-constant offsets of veh_o's x disturbance (see front_x_segments). Valid: up to 8 values in [-1, 1].
    Paper: ()."""
    opp_v_segments: tuple[float, ...] = ()
    """Piecewise-constant offsets of veh_o's speed disturbance (see front_x_segments). Valid: up to 8 values in [-1,
    1]. Paper: ()."""
    lateral_share: float = 0.0
    """Share of veh_f's lateral (y) position error taken by its structured lateral disturbance. Valid: [0, 1]. Paper:
    0 (none)."""
    front_y_bias: float = 0.0
    """Structured bias of veh_f's measured y, as a fraction of its half-width (+ towards the opposing lane). Valid:
    [-1, 1]. Paper: 0."""
    front_y_drift_per_s: float = 0.0
    """Drift of veh_f's y disturbance (1/s). Valid: finite. Paper: 0."""
    front_y_segments: tuple[float, ...] = ()
    """Piecewise-constant offsets of veh_f's y disturbance over time (see front_x_segments). Valid: up to 8 values in
    [-1, 1]. Paper: ()."""
    front_y_gap_segments: tuple[float, ...] = ()
    """Offsets of veh_f's y disturbance by veh_f's true footprint gap: J equal bands of [0, front_y_gap_window_m],
    band 0 the nearest; none beyond the window. Valid: up to 8 values in [-1, 1]. Paper: ()."""
    front_y_gap_window_m: float = 8.0
    """The footprint-gap window that front_y_gap_segments divides. Valid: > 0. Paper: (unused)."""
    key_seed: int = -1
    """Root of the episodes' noise: -1 draws it from (campaign seed, cell, episode id); a seed >= 0 from (key_seed,
    episode id) only, whatever the cell (a splitting search re-runs a parent's noise in a child's cell). Valid: -1 or
    0 to 2^31 - 1. Paper: -1."""
    branch_after_steps: tuple[float, ...] = ()
    """Noise branches (splitting falsification): after control step branch_after_steps[i] the per-step noise comes from
    branch branch_ids[i] of the episode key (as a snapshot branch of mcverify.episode.snapshot). Valid: up to 64
    increasing integer steps >= 0. Paper: () (none)."""
    branch_ids: tuple[float, ...] = ()
    """The branch id of each of branch_after_steps. Valid: as many integers in [0, 2^31) as branch_after_steps. Paper:
    ()."""


@dataclass(frozen=True)
class Simulation:
    """Closed-loop timing: the planner's period, the plant's RK4 sub-steps under zero-order hold (every safety check
    runs at every sub-step), the episode's time limit, and how long the plant keeps running under the lane-keeping
    law of :mod:`mcverify.control.lane_keeping` after the goal test ("overtook" / "went_back"; the outcome and its
    time stay the goal test's). ``stop_at`` is set by ``mcverify falsify`` only (:data:`REQUIREMENT_NAMES`)."""

    control_period_s: float = 0.02
    """Planner sampling period. Valid: > 0. Paper: 0.02 (50 Hz)."""
    substeps: int = 10
    """RK4 sub-steps per control period; every safety check runs at every sub-step. Valid: 1-1000."""
    max_time_s: float = 25.0
    """Time limit of an episode; then it ends as a timeout. Valid: > 0."""
    settle_s: float = 3.0
    """After the goal test, how long the plant keeps running under the lane-keeping law (0: stop at once). Valid: >=
    0."""
    stop_at: str = ""
    """Falsify mode only: end the episode at its first violation of this requirement ("": never). Set by
    `mcverify falsify` ([falsify] stop_episodes); refused in campaign files."""


@dataclass(frozen=True)
class Scenario:
    """Initial conditions (paper Sec. VI-B: ego at x = 10 m, 10 m/s; front vehicle at x = 64 m) and veh_f's
    acceleration, which never switches sign (the paper's assumption); a range draws it per episode from the
    episode's key (the paper's Table III ranges (1,3], (3,5], (5,7]), and so do the ranges of the burst's onset
    and duration (values the paper leaves open)."""

    ego_x_m: float = 10.0
    """Ego's initial c.g. position. Paper: 10."""
    ego_speed_mps: float = 10.0
    """Ego's initial speed (also as scenario.ego_speed_kmh). Valid: within the ego speed range. Paper: 10."""
    front_x_m: float = 64.0
    """veh_f's initial c.g. position. Paper: 64."""
    front_speed_mps: float = 25.0 / 3.6
    """veh_f's initial speed (also as scenario.front_speed_kmh). Valid: >= 0. Paper: Table II 25-36 km/h."""
    front_accel_mps2: float = 0.0
    """veh_f's acceleration from front_accel_onset_s on (it never decelerates). Valid: >= 0."""
    front_accel_range_mps2: tuple[float, ...] = ()
    """(lo, hi): each episode draws veh_f's acceleration uniformly in (lo, hi]; replaces front_accel_mps2. Paper:
    Table III (1,3], (3,5], (5,7]."""
    front_accel_onset_s: float = 0.0
    """When veh_f starts accelerating. Valid: >= 0."""
    front_accel_onset_range_s: tuple[float, ...] = ()
    """(lo, hi): each episode draws when veh_f starts accelerating uniformly in (lo, hi]; replaces front_accel_onset_s
    (ignored while a range is set). Valid: 0 <= lo < hi. The paper gives no onset for Table III."""
    front_accel_duration_s: float = math.inf
    """How long veh_f's acceleration lasts (inf: until front_speed_max_mps, so no overtake once it is faster than the
    ego can go). Valid: >= 0."""
    front_accel_duration_range_s: tuple[float, ...] = ()
    """(lo, hi): each episode draws how long veh_f's acceleration lasts uniformly in (lo, hi] (always > 0); replaces
    front_accel_duration_s (ignored while a range is set). Valid: 0 <= lo < hi. The paper gives no duration for
    Table III."""
    front_speed_max_mps: float = 30.0
    """veh_f's speed cap while it accelerates. Valid: >= 0."""


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

    When veh_o appears (``spawn``; the paper does not say, and with a fixed start the two vehicles
    rarely meet while the ego borrows the lane): "start", from ``x_m`` at t = 0 (Tables III-IV as first
    reproduced), or "lane_entry", ``spawn_gap_m`` ahead of the ego when its footprint first crosses the lane
    line (``spawn_delay_s`` later), so that every episode that starts an overtake meets it mid-overtake. The
    ``*_range_*`` fields draw the gap, the delay and veh_o's speed per episode from the episode's key.
    """

    kind: str = "none"
    """none, autonomous (cruise law filtered by its own VL-CBF, known to the ego) or human (unknown law, worst case
    predicted)."""
    x_m: float = 250.0
    """veh_o's initial c.g. position (spawn = start)."""
    speed_mps: float = 15.0
    """veh_o's initial (and cruise) speed magnitude; it drives towards -x. Valid: >= 0."""
    accel_mps2: float = 0.0
    """A human veh_o's acceleration towards speed_limit_mps (0: constant speed). Paper: 1.6 in Case 2, 0 in Table IV."""
    speed_limit_mps: float = 19.4
    """veh_o's speed limit. Paper: 19.4."""
    accel_max_mps2: float = 3.0
    """The worst-case acceleration the ego predicts for a human veh_o. Valid: >= 0."""
    brake_max_mps2: float = 6.0
    """veh_o's largest deceleration (its CBF filter is clipped to it). Valid: > 0."""
    cruise_gain_per_s: float = 1.0
    """Gain of an autonomous veh_o's cruise law alpha = k (speed_mps - speed). Valid: >= 0."""
    lambdas_m: tuple[float, ...] = (1.0,)
    """lambda_i of veh_o's own kappa~_o on h_oe. Valid: all > 0."""
    epsilon_m: float = 1.0
    """Level of veh_o's barrier h_oe (metres). Valid: >= 0."""
    detect_range_m: float = 200.0
    """The ego sees veh_o (and adds eq.tompcAdd) once x_o - x_e is below this. Valid: > 0."""
    spawn: str = "start"
    """When veh_o appears: start (at x_m at t = 0) or lane_entry (when the ego first enters the opposing lane)."""
    spawn_gap_m: float = 150.0
    """x_o - x_e at which veh_o appears with spawn = lane_entry. Valid: > 0."""
    spawn_gap_range_m: tuple[float, ...] = ()
    """(lo, hi): draws the spawn gap per episode uniformly in (lo, hi]; replaces spawn_gap_m."""
    spawn_delay_s: float = 0.0
    """With lane_entry, how long after the lane entry veh_o appears. Valid: >= 0."""
    spawn_delay_range_s: tuple[float, ...] = ()
    """(lo, hi): draws the spawn delay per episode uniformly in (lo, hi]; replaces spawn_delay_s."""
    spawn_delay_sd_s: float = 0.0
    """> 0 with spawn_delay_range_s: the delay is normal with mean spawn_delay_s and this standard deviation,
    truncated to the range, instead of uniform (the timing of veh_o's arrival as a jitter around a nominal time).
    The range may lie in a tail (e.g. [1.9, 8] around 1.5: the normal conditioned on a late arrival). Valid: >= 0;
    needs spawn_delay_range_s holding more than 1e-12 of the normal's mass."""
    speed_range_mps: tuple[float, ...] = ()
    """(lo, hi): draws veh_o's speed per episode uniformly in (lo, hi]; replaces speed_mps."""

    @property
    def appears_at_lane_entry(self) -> bool:
        """Whether there is a veh_o and it appears at the ego's lane entry (where the spawn gap and
        delay apply)."""
        return self.kind != "none" and self.spawn == "lane_entry"


def normal_masses(mean: float, sd: float, lo: float, hi: float) -> tuple[float, float, float]:
    """(below lo, inside [lo, hi], above hi): the probabilities of a normal (``mean``, ``sd``), each tail taken
    from its own side so that a range far in a tail keeps its precision (the normal spawn delay,
    ``OpposingParams.spawn_delay_sd_s``: its validation, its draws and the importance sampler's nominal)."""
    unit = statistics.NormalDist()
    a, b = (lo - mean) / sd, (hi - mean) / sd
    below, above = unit.cdf(a), unit.cdf(-b)
    inside = unit.cdf(-a) - unit.cdf(-b) if a > 0 else unit.cdf(b) - unit.cdf(a)
    return below, inside, above


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
