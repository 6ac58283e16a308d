"""Validation of the model's parameters (:class:`mcverify.model.ModelParams`): every value a campaign may
set, checked when a cell is built.

Each problem becomes a :class:`~mcverify.errors.CampaignError` whose one line names the file, the
field and what is wrong; nothing is simulated with a parameter set that fails here.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from mcverify.draws import DRAWS, field_value
from mcverify.errors import CampaignError
from mcverify.levels import Level
from mcverify.model import (
    ABANDON_RULES,
    BACKEND_NAMES,
    MAX_BRANCHES,
    MAX_SEGMENTS,
    Q2_SOLVE_POLICIES,
    REQUIREMENT_NAMES,
    ModelParams,
    normal_masses,
)

#: The piecewise-constant disturbance fields of [model.noise].
SEGMENT_FIELDS = ("front_x_segments", "front_v_segments", "opp_x_segments", "opp_v_segments", "front_y_segments",
                  "front_y_gap_segments")

CONTROLLERS = ("vlcbf", "mpcdc", "mpcdc_eps")
OPPOSING_KINDS = ("none", "autonomous", "human")
SPAWN_MODES = ("start", "lane_entry")
#: Bounds that keep one episode computable (the kernel's size grows with the horizon; an episode
#: runs max_time_s / control_period_s steps of ``substeps`` RK4 sub-steps each).
MAX_HORIZON = 500
MAX_SUBSTEPS = 1000
MAX_CONTROL_STEPS = 1_000_000
#: The least share of a normal spawn delay's mass its range may hold (below it the draws lose precision).
MIN_NORMAL_SHARE = 1e-12


def validate_params(p: ModelParams, where: str) -> None:
    """Reject impossible parameter combinations with a message naming the field."""

    def bad(key: str, why: str) -> CampaignError:
        return CampaignError(f"{where}: {key}: {why}")

    _check_finite(p, bad)
    _check_signs(p, bad)
    _check_mpc_and_sim(p, bad)
    _check_barrier_and_scenario(p, bad)
    _validate_front_and_opposing(p, bad)
    _check_start_outside_level(p, bad)


def _check_finite(p: ModelParams, bad) -> None:
    # NaN and inf slip through the comparisons below: refuse them first (inf only where the model's
    # own default is inf, meaning "no limit", e.g. scenario.front_accel_duration_s).
    for sec in dataclasses.fields(p):
        section = getattr(p, sec.name)
        for f in dataclasses.fields(section):
            v = getattr(section, f.name)
            default = getattr(type(section)(), f.name)
            unbounded = isinstance(default, float) and math.isinf(default)
            for x in v if isinstance(v, tuple) else (v,):
                if isinstance(x, float) and not math.isfinite(x) and not (unbounded and x == default):
                    raise bad(f"{sec.name}.{f.name}", f"must be finite, got {short(v)}")


def _check_signs(p: ModelParams, bad) -> None:
    """Fields that must be positive, non-negative or fractions of the noise bound."""
    e, b, m, n, s, sc = p.ego, p.barrier, p.mpc, p.noise, p.sim, p.scenario
    positive = {
        "geometry.length_m": p.geometry.length_m,
        "geometry.width_m": p.geometry.width_m,
        "road.lane_width_m": p.road.lane_width_m,
        "ego.accel_max_mps2": e.accel_max_mps2,
        "ego.slip_max_rad": e.slip_max_rad,
        "ego.speed_max_mps": e.speed_max_mps,
        "ego.heading_max_rad": e.heading_max_rad,
        "ego.l_r_m": e.l_r_m,
        "barrier.ellipse_a_m": b.ellipse_a_m,
        "barrier.ellipse_b_m": b.ellipse_b_m,
        "mpc.dt_max_s": m.dt_max_s,
        "mpc.dt_min_s": m.dt_min_s,
        "mpc.eps_y_m": m.eps_y_m,
        "mpc.tol": m.tol,
        "sim.control_period_s": s.control_period_s,
        "sim.max_time_s": s.max_time_s,
        "noise.front_y_gap_window_m": n.front_y_gap_window_m,
    }
    for key, v in positive.items():
        if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
            raise bad(key, f"must be a finite number > 0, got {short(v)}")
    unit_interval = {"noise.structured_share": (n.structured_share, 0.0), "noise.lateral_share": (n.lateral_share, 0.0)}
    unit_interval |= {f"noise.{k}": (getattr(n, k), -1.0) for k in ("front_x_bias", "front_v_bias", "opp_x_bias",
                                                                   "opp_v_bias", "front_y_bias")}
    for key, (v, low) in unit_interval.items():
        if not low <= v <= 1.0:
            raise bad(key, f"must be in [{low:g}, 1] (a fraction of the noise bound), got {short(v)}")
    for name in SEGMENT_FIELDS:
        v = getattr(n, name)
        if len(v) > MAX_SEGMENTS or not all(-1.0 <= x <= 1.0 for x in v):
            raise bad(f"noise.{name}", f"must be at most {MAX_SEGMENTS} values in [-1, 1] (fractions of the noise "
                      f"bound), got {short(list(v))}")
    _check_branches(bad, n)
    nonneg = {
        "mpc.phi_s": m.phi_s,
        "mpc.smooth_weight": m.smooth_weight,
        "noise.pos_far_m": n.pos_far_m,
        "noise.pos_near_m": n.pos_near_m,
        "noise.near_threshold_m": n.near_threshold_m,
        "noise.speed_rel": n.speed_rel,
        "noise.scale": n.scale,
        "scenario.ego_speed_mps": sc.ego_speed_mps,
        "scenario.front_speed_mps": sc.front_speed_mps,
        "scenario.front_accel_onset_s": sc.front_accel_onset_s,
        "scenario.front_accel_duration_s": 0.0 if sc.front_accel_duration_s == math.inf else sc.front_accel_duration_s,
        "scenario.front_speed_max_mps": sc.front_speed_max_mps,
        "ego.speed_min_mps": e.speed_min_mps,
        "sim.settle_s": s.settle_s,
    }
    for key, v in nonneg.items():
        if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
            raise bad(key, f"must be a finite number >= 0, got {short(v)}")


def _check_mpc_and_sim(p: ModelParams, bad) -> None:
    e, m, s = p.ego, p.mpc, p.sim
    if e.accel_min_mps2 >= 0:
        raise bad("ego.accel_min_mps2", f"must be < 0 (braking), got {e.accel_min_mps2}")
    if e.y_min_m >= e.y_max_m:
        raise bad("ego.y_min_m", f"must be below ego.y_max_m ({e.y_max_m}), got {e.y_min_m}")
    if m.dt_min_s >= m.dt_max_s:
        raise bad("mpc.dt_min_s", f"must be below mpc.dt_max_s ({m.dt_max_s}), got {m.dt_min_s}")
    if not 2 <= m.horizon <= MAX_HORIZON:
        raise bad("mpc.horizon", f"must be >= 2 and <= {MAX_HORIZON} (the paper's N is 50), got {m.horizon}")
    if m.max_iter < 1:
        raise bad("mpc.max_iter", f"must be >= 1, got {m.max_iter}")
    if m.max_iter_cold < 1:
        raise bad("mpc.max_iter_cold", f"must be >= 1, got {m.max_iter_cold}")
    if m.infeasible_recheck_steps < 1:
        raise bad("mpc.infeasible_recheck_steps", f"must be >= 1 (1: IPOPT on every failure), "
                  f"got {m.infeasible_recheck_steps}")
    if m.infeasible_recheck_max_steps < m.infeasible_recheck_steps:
        raise bad("mpc.infeasible_recheck_max_steps", f"must be >= mpc.infeasible_recheck_steps "
                  f"({m.infeasible_recheck_steps}), got {m.infeasible_recheck_max_steps} "
                  "(set both; equal: a fixed period)")
    if m.abandon_rule not in ABANDON_RULES:
        raise bad("mpc.abandon_rule", f"unknown rule {short(m.abandon_rule)}; valid: {', '.join(ABANDON_RULES)}")
    if m.q2_solve not in Q2_SOLVE_POLICIES:
        raise bad("mpc.q2_solve", f"unknown policy {short(m.q2_solve)}; valid: {', '.join(Q2_SOLVE_POLICIES)}")
    if type(m.abandon_after_failures) is not int or m.abandon_after_failures < 1:
        raise bad("mpc.abandon_after_failures", f"must be an integer >= 1 (consecutive failed Q1 solves), "
                  f"got {short(m.abandon_after_failures)}")
    if not 1 <= s.substeps <= MAX_SUBSTEPS:
        raise bad("sim.substeps", f"must be >= 1 and <= {MAX_SUBSTEPS}, got {s.substeps}")
    if s.max_time_s < s.control_period_s:
        raise bad("sim.max_time_s",
                  f"must be at least one control period (sim.control_period_s = {s.control_period_s:.4g})")
    if s.max_time_s / s.control_period_s > MAX_CONTROL_STEPS:
        raise bad("sim.max_time_s", f"is more than {MAX_CONTROL_STEPS:,} control periods of sim.control_period_s = "
                  f"{s.control_period_s:.4g} s")
    if s.stop_at and s.stop_at not in REQUIREMENT_NAMES:
        raise bad("sim.stop_at", f"unknown requirement {short(s.stop_at)}; valid: {', '.join(REQUIREMENT_NAMES)}")
    if m.controller not in CONTROLLERS:
        raise bad("mpc.controller", f"unknown controller {short(m.controller)}; valid: {', '.join(CONTROLLERS)}")
    if m.backend not in BACKEND_NAMES:
        raise bad("mpc.backend", f"unknown solver backend {short(m.backend)}; valid: {', '.join(BACKEND_NAMES)}")
    if type(m.infeasibility_audit_every) is not int or m.infeasibility_audit_every < 1:
        raise bad("mpc.infeasibility_audit_every",
                  f"must be an integer >= 1, got {short(m.infeasibility_audit_every)}")


def _check_barrier_and_scenario(p: ModelParams, bad) -> None:
    e, b, n, sc = p.ego, p.barrier, p.noise, p.scenario
    if n.kind not in ("paper", "none"):
        raise bad("noise.kind", f"unknown noise model {short(n.kind)}; valid: paper, none")
    if not b.lambdas_m or any(not (isinstance(x, int | float) and math.isfinite(x) and x > 0) for x in b.lambdas_m):
        raise bad("barrier.lambdas_m", f"needs one or more values, all > 0, got {short(list(b.lambdas_m))}")
    if (b.epsilon is None) == (b.lambda0 is None):
        raise bad("barrier.epsilon", "set exactly one of barrier.epsilon and barrier.lambda0")
    if b.epsilon is not None and not (math.isfinite(b.epsilon) and b.epsilon >= 0):
        raise bad("barrier.epsilon", f"must be >= 0 (the level eps of the VL-CBF), got {b.epsilon}")
    if b.lambda0 is not None and not (math.isfinite(b.lambda0) and b.lambda0 <= 0):
        raise bad("barrier.lambda0", f"must be <= 0 (Theorem 2 needs lambda_0 <= 0), got {b.lambda0}")
    if not (e.speed_min_mps <= sc.ego_speed_mps <= e.speed_max_mps):
        raise bad(
            "scenario.ego_speed_mps",
            f"{sc.ego_speed_mps:.4g} m/s is outside the ego speed range [ego.speed_min_mps, "
            f"ego.speed_max_mps] = [{e.speed_min_mps:.4g}, {e.speed_max_mps:.4g}] m/s",
        )
    if sc.front_speed_mps > sc.front_speed_max_mps:
        raise bad(
            "scenario.front_speed_mps",
            f"{sc.front_speed_mps:.4g} m/s is above scenario.front_speed_max_mps ({sc.front_speed_max_mps:.4g})",
        )
    if sc.front_x_m <= sc.ego_x_m:
        raise bad("scenario.front_x_m", f"the front vehicle must start ahead of the ego (x > scenario.ego_x_m = "
                  f"{sc.ego_x_m:.4g})")


def _check_start_outside_level(p: ModelParams, bad) -> None:
    """The ego must start outside the level set h >= eps of veh_f's ellipse (Theorem 2's premise)."""
    b, sc = p.barrier, p.scenario
    level = "barrier.epsilon" if b.epsilon is not None else "barrier.lambda0"
    try:
        eps = Level.of_barrier(b).epsilon
        h0 = ((sc.ego_x_m - sc.front_x_m) / b.ellipse_a_m) ** 2 - 1.0
    except (ArithmeticError, ValueError) as err:  # e.g. an overflow from an absurd lambda0
        raise bad(level, f"cannot compute the level eps ({err})") from None
    if not (h0 >= eps):
        raise bad(
            "scenario.front_x_m",
            f"infeasible scenario: the ego starts inside the level set h >= eps of the front "
            f"vehicle's ellipse (h0 = {h0:.4g} < eps = {eps:.4g}, from {level}); start further behind",
        )


def _validate_front_and_opposing(p: ModelParams, bad) -> None:
    b, sc, o = p.barrier, p.scenario, p.opposing
    rng = sc.front_accel_range_mps2
    if rng and (len(rng) != 2 or not (0 <= rng[0] < rng[1]) or not all(math.isfinite(x) for x in rng)):
        raise bad("scenario.front_accel_range_mps2",
                  f"must be [lo, hi] with 0 <= lo < hi (alpha_f is drawn in (lo, hi]), got {short(list(rng))}")
    if sc.front_accel_mps2 < 0:
        raise bad("scenario.front_accel_mps2", f"must be >= 0 (the front vehicle never switches sign), got "
                  f"{sc.front_accel_mps2}")
    if not (math.isfinite(b.decel_max_mps2) and b.decel_max_mps2 > 0):
        raise bad("barrier.decel_max_mps2", f"must be > 0 (a_l of h_eo), got {b.decel_max_mps2}")
    if not (math.isfinite(b.opp_epsilon_m) and b.opp_epsilon_m >= 0):
        raise bad("barrier.opp_epsilon_m", f"must be >= 0 (the level of h_eo, m), got {b.opp_epsilon_m}")
    for key, lam in (("barrier.opp_lambdas_m", b.opp_lambdas_m), ("opposing.lambdas_m", o.lambdas_m)):
        if not lam or any(not (isinstance(x, int | float) and math.isfinite(x) and x > 0) for x in lam):
            raise bad(key, f"needs one or more values, all > 0, got {short(list(lam))}")
    if o.kind not in OPPOSING_KINDS:
        raise bad("opposing.kind", f"unknown opposing vehicle {short(o.kind)}; valid: {', '.join(OPPOSING_KINDS)}")
    for key in ("speed_mps", "accel_mps2", "epsilon_m"):
        v = getattr(o, key)
        if not (math.isfinite(v) and v >= 0):
            raise bad(f"opposing.{key}", f"must be a finite number >= 0, got {short(v)}")
    for key in ("speed_limit_mps", "accel_max_mps2", "brake_max_mps2", "cruise_gain_per_s", "detect_range_m"):
        v = getattr(o, key)
        if not (math.isfinite(v) and v > 0):
            raise bad(f"opposing.{key}", f"must be a finite number > 0, got {short(v)}")
    if o.kind != "none":
        if o.speed_mps > o.speed_limit_mps:
            raise bad("opposing.speed_mps", f"{o.speed_mps:.4g} m/s is above opposing.speed_limit_mps "
                      f"({o.speed_limit_mps:.4g})")
        if o.x_m <= sc.front_x_m:
            raise bad("opposing.x_m", f"the opposing vehicle must start ahead of the front vehicle "
                      f"(x > scenario.front_x_m = {sc.front_x_m:.4g}), got {o.x_m:.4g}")
    if o.spawn not in SPAWN_MODES:
        raise bad("opposing.spawn", f"unknown spawn rule {short(o.spawn)}; valid: {', '.join(SPAWN_MODES)}")
    if not (math.isfinite(o.spawn_gap_m) and o.spawn_gap_m > p.geometry.length_m):
        raise bad("opposing.spawn_gap_m", f"must be a finite gap > the vehicle length ({p.geometry.length_m:.4g} m), "
                  f"got {short(o.spawn_gap_m)}")
    if not (math.isfinite(o.spawn_delay_s) and o.spawn_delay_s >= 0):
        raise bad("opposing.spawn_delay_s", f"must be a finite number >= 0, got {short(o.spawn_delay_s)}")
    for draw in DRAWS:  # every per-episode draw's range within the bounds its registry entry gives
        _check_range(bad, draw.range_field, field_value(p, draw.range_field), lo_min=draw.lowest(p),
                     hi_max=draw.highest(p))
    if not (math.isfinite(o.spawn_delay_sd_s) and o.spawn_delay_sd_s >= 0):
        raise bad("opposing.spawn_delay_sd_s", f"must be a finite number >= 0, got {short(o.spawn_delay_sd_s)}")
    if o.spawn_delay_sd_s > 0:
        _check_normal_range(bad, o)


def _check_normal_range(bad, o) -> None:
    """A normal spawn delay needs a range holding a share of its mass that double precision can draw from
    (the range may lie in a tail: [1.9, 8] s around 1.5 s is the normal conditioned on a late arrival)."""
    if not o.spawn_delay_range_s:
        raise bad("opposing.spawn_delay_sd_s", "a normal spawn delay needs opposing.spawn_delay_range_s = [lo, hi] "
                  "to truncate it to")
    _, share, _ = normal_masses(o.spawn_delay_s, o.spawn_delay_sd_s, *o.spawn_delay_range_s)
    if not share > MIN_NORMAL_SHARE:
        raise bad("opposing.spawn_delay_sd_s", f"the range {list(o.spawn_delay_range_s)} s holds {share:.3g} of "
                  f"the normal({o.spawn_delay_s:.4g}, {o.spawn_delay_sd_s:.4g}) spawn delay, less than "
                  f"{MIN_NORMAL_SHARE:g}")


def _check_branches(bad, n) -> None:
    """noise.key_seed and the noise branches (set by a splitting search): integers in range, steps increasing."""
    if not -1 <= n.key_seed < 2**31:
        raise bad("noise.key_seed", f"must be -1 or an integer from 0 to 2^31 - 1, got {short(n.key_seed)}")
    steps, ids = n.branch_after_steps, n.branch_ids
    if len(steps) != len(ids):
        raise bad("noise.branch_ids", f"must have one id per noise.branch_after_steps ({len(steps)}), got {len(ids)}")
    if len(steps) > MAX_BRANCHES:
        raise bad("noise.branch_after_steps", f"at most {MAX_BRANCHES} branches, got {len(steps)}")
    if not all(float(x).is_integer() and x >= 0 for x in steps) or any(
            b <= a for a, b in zip(steps, steps[1:], strict=False)):
        raise bad("noise.branch_after_steps",
                  f"must be increasing integer control steps >= 0, got {short(list(steps))}")
    if not all(float(x).is_integer() and 0 <= x < 2**31 for x in ids):
        raise bad("noise.branch_ids", f"must be integers in [0, 2^31), got {short(list(ids))}")


def _check_range(bad, key: str, rng: tuple[float, ...], *, lo_min: float, hi_max: float = math.inf) -> None:
    """An optional (lo, hi) range drawn in (lo, hi]: empty, or two finite numbers lo_min <= lo < hi <= hi_max."""
    if not rng:
        return
    ok = len(rng) == 2 and all(math.isfinite(v) for v in rng) and lo_min <= rng[0] < rng[1] <= hi_max
    if not ok:
        limit = f" <= {hi_max:.4g}" if math.isfinite(hi_max) else ""
        raise bad(key, f"must be [lo, hi] with {lo_min:.4g} <= lo < hi{limit} (drawn in (lo, hi]), "
                  f"got {short(list(rng))}")


def short(value: Any, limit: int = 60) -> str:
    """``repr(value)`` cut to ``limit`` characters (messages stay one short line)."""
    text = f"{value:.6g}" if isinstance(value, float) else repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


# ------------------------------------------------------------------------ parameters from a record

#: Model fields that are options no more, with the value whose behaviour is now built in (the fast path's
#: attempt order per controller family, :mod:`mcverify.solver.attempts`; the banded LU; Q2 as in the paper).
#: A recorded run that set one of them to this value ran what today's code runs; any other value ran
#: something this code cannot, so such a run is refused (:func:`params_from_record`).
RETIRED_FIELDS: dict[str, Any] = {
    "mpc.infeasibility": "phase1_mpcdc",
    "mpc.ipm_restoration": "mpcdc",
    "mpc.ipm_central_attempt": "mpcdc",
    "mpc.ipm_central_first": "mpcdc",
    "mpc.ipm_after_hard_attempt": "lower_mu",
    "mpc.ipm_after_hard_solves": 1,
    "mpc.ipm_central_retry": "mpcdc",
    "mpc.kkt_factorization": "lu",
    "mpc.q2_stoppable": "off",
}


#: Model fields added since runs were first recorded, with the value that does what the code before them did
#: (a drawn burst onset or duration: not drawn). A recorded run that lacks one of them ran exactly that, so it
#: is rebuilt with it; any other missing field is refused (:func:`params_from_record`).
INTRODUCED_FIELDS: dict[str, Any] = {
    "scenario.front_accel_onset_range_s": (),
    "scenario.front_accel_duration_range_s": (),
}


def params_from_record(record: Any, where: str) -> ModelParams:
    """The :class:`ModelParams` a run recorded (``dataclasses.asdict`` of them, as in its manifest), exactly: every
    field of today's model must be there (none is filled in from today's defaults) but those added since with a value
    that does what the code before them did (:data:`INTRODUCED_FIELDS`), and a field the model no longer has is
    accepted only at the value now built in (:data:`RETIRED_FIELDS`). Anything else is a
    :class:`CampaignError` naming the field."""
    if not isinstance(record, dict):
        raise CampaignError(f"{where}: no recorded model parameters (made by an older version)")
    sections = {}
    for sec in dataclasses.fields(ModelParams):
        given = record.get(sec.name)
        if not isinstance(given, dict):
            raise CampaignError(f"{where}: the recorded parameters lack the section {sec.name!r}")
        cls = sec.default_factory
        values = {}
        for f in dataclasses.fields(cls):
            if f.name not in given and f"{sec.name}.{f.name}" in INTRODUCED_FIELDS:
                values[f.name] = INTRODUCED_FIELDS[f"{sec.name}.{f.name}"]
                continue
            if f.name not in given:
                raise CampaignError(f"{where}: the recorded parameters lack {sec.name}.{f.name}, which this code "
                                    "needs (made by an older version); rerun the campaign")
            v = given[f.name]
            values[f.name] = tuple(v) if isinstance(v, list) else v
        for name in sorted(set(given) - {f.name for f in dataclasses.fields(cls)}):
            key = f"{sec.name}.{name}"
            if key not in RETIRED_FIELDS:
                raise CampaignError(f"{where}: the recorded parameters have {key}, which this code does not know")
            if given[name] != RETIRED_FIELDS[key]:
                raise CampaignError(f"{where}: the run set {key} = {short(given[name])}, an option since deleted "
                                    f"(only {short(RETIRED_FIELDS[key])} remains); it cannot be rebuilt with this code")
        sections[sec.name] = cls(**values)
    for name in sorted(set(record) - set(sections)):
        raise CampaignError(f"{where}: the recorded parameters have a section {name!r} this code does not know")
    return ModelParams(**sections)
