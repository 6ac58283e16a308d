"""The simulated world in JAX: true states, perception, physics and every safety check.

Waymax/Brax style: immutable pytrees with named fields (:class:`Plant`, :class:`SafetyTrace`),
pure functions ``observe(plant, key, step, params)`` and
``advance(plant, trace, u, active, params) -> (plant, trace, substeps)``, batched by ``vmap``,
time within a control period by ``lax.scan`` over RK4 sub-steps (zero-order hold). Every number
of the model enters as a runtime argument (:class:`PlantParams`), never as a compiled-in constant.

Bit-for-bit reproducibility: XLA rewrites algebra differently for different batch shapes (for
example ``(x / a)**2`` became ``x*x * (1/a**2)`` in one shape and not in another), so the same
episode would differ in its last bits between a chunk of 8 and a replay of 1, and the closed loop
amplifies last bits. Hence every call runs exactly one compiled executable of fixed width
:data:`LANES` (:class:`mcverify.sim.lanes.LaneGroups` pads and splits), with the CPU ISA capped below
FMA (see ``mcverify/sim/__init__.py``): an episode's numbers do not depend on the chunk size, its
position in the chunk or the other episodes.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mcverify import levels
from mcverify.model import ModelParams
from mcverify.sim import agents, barriers, geometry, noise, vehicles
from mcverify.sim import schedule as schedule_mod
from mcverify.sim import tilt as tilt_mod

Array = jax.Array

#: Width of every vmapped plant call (episodes per lane group). 8 float64 lanes are two AVX vectors.
LANES = 8
OPP_NONE, OPP_AUTONOMOUS, OPP_HUMAN = 0, 1, 2
_OPP_KINDS = {"none": OPP_NONE, "autonomous": OPP_AUTONOMOUS, "human": OPP_HUMAN}
#: Where a missing opposing vehicle is parked (far ahead, at rest): its checks are masked anyway.
_NO_OPP_X_M = 1.0e6
#: A veh_o beyond this x is parked (absent, or not yet spawned): no check sees it.
_PARKED_BEYOND_X_M = 0.5 * _NO_OPP_X_M
#: Noise streams of :func:`mcverify.sim.noise.step_key` within a control step.
STREAM_FRONT, STREAM_OPP = 0, 1


class PlantParams(NamedTuple):
    """Every number the plant and the checks use, as runtime scalars (one cell; see
    :func:`plant_params`). Units in the names; ``opp_lambdas`` is veh_o's Lambda_o, (m_o + 1,)."""

    control_period_s: Array
    dt_sub_s: Array
    l_r_m: Array
    length_m: Array
    width_m: Array
    lane_line_y_m: Array
    opp_lane_y_m: Array
    ellipse_a_m: Array
    ellipse_b_m: Array
    front_speed_max_mps: Array
    opp_kind: Array
    opp_accel_mps2: Array
    opp_speed_limit_mps: Array
    opp_cruise_mps: Array
    opp_gain_per_s: Array
    opp_lambdas: Array
    decel_max_mps2: Array
    opp_accel_max_mps2: Array
    opp_brake_max_mps2: Array
    ego_speed_max_mps: Array
    ego_accel_min_mps2: Array
    ego_accel_max_mps2: Array
    ego_slip_max_rad: Array
    noise: noise.NoiseParams  # the perception noise (bounds, structured disturbances)


def plant_params(p: ModelParams) -> PlantParams:
    """The runtime numbers of a cell's plant."""
    o, road = p.opposing, p.road
    f = lambda v: jnp.asarray(v, dtype=float)  # noqa: E731
    return PlantParams(
        control_period_s=f(p.sim.control_period_s),
        dt_sub_s=f(p.sim.control_period_s / p.sim.substeps),
        l_r_m=f(p.ego.l_r_m),
        length_m=f(p.geometry.length_m),
        width_m=f(p.geometry.width_m),
        lane_line_y_m=f(0.5 * (road.ego_lane_y_m + road.opp_lane_y_m)),
        opp_lane_y_m=f(road.opp_lane_y_m),
        ellipse_a_m=f(p.barrier.ellipse_a_m),
        ellipse_b_m=f(p.barrier.ellipse_b_m),
        front_speed_max_mps=f(p.scenario.front_speed_max_mps),
        opp_kind=jnp.asarray(_OPP_KINDS[o.kind], dtype=jnp.int32),
        opp_accel_mps2=f(o.accel_mps2),
        opp_speed_limit_mps=f(o.speed_limit_mps),
        opp_cruise_mps=f(o.speed_mps),
        opp_gain_per_s=f(o.cruise_gain_per_s),
        opp_lambdas=f([levels.lambda0_from_epsilon(o.lambdas_m, o.epsilon_m), *o.lambdas_m]),
        decel_max_mps2=f(p.barrier.decel_max_mps2),
        opp_accel_max_mps2=f(o.accel_max_mps2),
        opp_brake_max_mps2=f(o.brake_max_mps2),
        ego_speed_max_mps=f(p.ego.speed_max_mps),
        ego_accel_min_mps2=f(p.ego.accel_min_mps2),
        ego_accel_max_mps2=f(p.ego.accel_max_mps2),
        ego_slip_max_rad=f(p.ego.slip_max_rad),
        noise=noise.NoiseParams.of(p.noise, p.sim.max_time_s),
    )


class Plant(NamedTuple):
    """True state of one episode (batched along a leading axis by vmap).

    ego: (4,) [x_m, y_m, psi_rad, speed_mps]; front: (2,) [x_m, speed_mps] on the ego lane centre;
    opp: (2,) [x_m, v_mps] on the opposing lane centre, v <= 0 (road frame);
    front_accel_mps2: () this episode's alpha_f; front_onset_s, front_duration_s: () when its burst starts and
    how long it lasts (drawn per episode, :data:`mcverify.draws.DRAWS`); t_s: () time since the episode started;
    tilt_log_ratio: () the sum of log(tilted / nominal density) over the tilted steps so far (the
    episode's likelihood ratio follows from it, :func:`~mcverify.sim.tilt.episode_log_lr`); tilt_sums:
    (9,) the sums of the tilted units per (band, unit), row-major; tilt_counts: (3,) the tilted steps per
    band (all 0 unless a :class:`~mcverify.sim.tilt.NoiseTilt` is in use).
    """

    ego: Array
    front: Array
    opp: Array
    front_accel_mps2: Array
    front_onset_s: Array
    front_duration_s: Array
    t_s: Array
    tilt_log_ratio: Array
    tilt_sums: Array
    tilt_counts: Array


class SafetyTrace(NamedTuple):
    """Running per-episode safety metrics, updated at every sub-step (all scalars).

    Front: min_h_front (h_ef, dimensionless), min_dist_front_m (signed Euclidean distance from the
    ego c.g. to the ellipse h_ef = 0, negative inside), min_gap_front_m (footprint gap, 0 on
    contact), collision_front (footprints overlapped). Lane use: first/last_opp_lane_s, the first
    and last sub-step with the ego footprint across the lane line (NaN if never). Opposing:
    collision_opp; min_gap_opp_m, the footprint gap while the ego borrows the opposing lane and veh_o
    is ahead of it (the paper's "min dist. with veh_o"; inf if never); min_gap_opp_any_m, the gap at
    any time; min_h_opp, h_eo (m) while borrowing with veh_o ahead (inf if never).
    Limits of the ego (the MPC keeps them at its nodes; the plant is checked at every sub-step, the
    held input once per control period): the largest excess over the speed limit, the acceleration
    bounds and the slip bound (<= 0 when the limit held), each with the time it was reached (NaN
    while no excess was positive).
    """

    min_h_front: Array
    min_dist_front_m: Array
    min_gap_front_m: Array
    collision_front: Array
    first_opp_lane_s: Array
    last_opp_lane_s: Array
    collision_opp: Array
    min_gap_opp_m: Array
    min_gap_opp_any_m: Array
    min_h_opp: Array
    speed_excess_mps: Array
    speed_excess_t_s: Array
    accel_excess_mps2: Array
    accel_excess_t_s: Array
    slip_excess_rad: Array
    slip_excess_t_s: Array


def _worse(best: Array, best_t: Array, excess: Array, t: Array) -> tuple[Array, Array]:
    """The larger excess and its time (the time stays NaN until an excess is positive)."""
    later = (excess > best) & (excess > 0.0)
    return jnp.maximum(best, excess), jnp.where(later, t, best_t)


def input_excess(u: Array, pp: PlantParams) -> tuple[Array, Array]:
    """How far the held input (alpha, beta) lies beyond the ego's acceleration and slip bounds."""
    accel = jnp.maximum(u[0] - pp.ego_accel_max_mps2, pp.ego_accel_min_mps2 - u[0])
    return accel, jnp.abs(u[1]) - pp.ego_slip_max_rad


class Substep(NamedTuple):
    """What ``advance`` reports at each sub-step (recorded episodes: trajectories)."""

    t_s: Array
    ego: Array
    front: Array
    opp: Array
    h_front: Array
    dist_front_m: Array
    gap_front_m: Array
    collision_front: Array
    h_opp: Array
    gap_opp_m: Array
    collision_opp: Array


class _Checks(NamedTuple):
    h_front: Array
    dist_front_m: Array
    gap_front_m: Array
    hit_front: Array
    borrowing: Array
    hit_opp: Array
    gap_opp_m: Array
    h_opp: Array
    opp_relevant: Array


# ------------------------------------------------------------------------------ single episode


def checks(ego: Array, front: Array, opp: Array, u: Array, pp: PlantParams) -> _Checks:
    """Every safety quantity at one instant (the ego's input u enters h_eo through v_e^x)."""
    fx = front[0]
    h = barriers.h_ellipse(ego[0], ego[1], fx, 0.0, pp.ellipse_a_m, pp.ellipse_b_m)
    dist = geometry.ellipse_signed_distance_m(ego[0] - fx, ego[1], pp.ellipse_a_m, pp.ellipse_b_m)
    ego_box = geometry.footprint_corners(ego[0], ego[1], ego[2], pp.length_m, pp.width_m)
    front_box = geometry.footprint_corners(fx, 0.0, 0.0, pp.length_m, pp.width_m)
    opp_box = geometry.footprint_corners(opp[0], pp.opp_lane_y_m, 0.0, pp.length_m, pp.width_m)
    present = (pp.opp_kind != OPP_NONE) & (opp[0] < _PARKED_BEYOND_X_M)  # not yet spawned: absent
    borrowing = agents.ego_top_edge_m(ego, pp.length_m, pp.width_m) > pp.lane_line_y_m
    vx_e = vehicles.ego_derivative(ego, u, pp.l_r_m)[0]
    return _Checks(
        h_front=h,
        dist_front_m=dist,
        gap_front_m=geometry.rectangle_gap_m(ego_box, front_box),
        hit_front=geometry.rectangles_overlap(ego_box, front_box),
        borrowing=borrowing,
        hit_opp=present & geometry.rectangles_overlap(ego_box, opp_box),
        gap_opp_m=jnp.where(present, geometry.rectangle_gap_m(ego_box, opp_box), jnp.inf),
        h_opp=barriers.h_longitudinal(ego[0], vx_e, opp[0], opp[1], pp.decel_max_mps2),
        opp_relevant=present & borrowing & (ego[0] < opp[0]),
    )


def initial_trace(plant: Plant, pp: PlantParams) -> SafetyTrace:
    c = checks(plant.ego, plant.front, plant.opp, jnp.zeros(2), pp)
    t0 = jnp.where(c.borrowing, plant.t_s, jnp.nan)
    speed = plant.ego[3] - pp.ego_speed_max_mps
    return SafetyTrace(
        c.h_front, c.dist_front_m, c.gap_front_m, c.hit_front, t0, t0, c.hit_opp,
        jnp.where(c.opp_relevant, c.gap_opp_m, jnp.inf), c.gap_opp_m, jnp.where(c.opp_relevant, c.h_opp, jnp.inf),
        speed, jnp.where(speed > 0.0, plant.t_s, jnp.nan), -jnp.inf, jnp.nan, -jnp.inf, jnp.nan,
    )


def observe(plant: Plant, key: Array, step: Array, pp: PlantParams) -> tuple[Array, Array]:
    """What the planner measures at this control step (Sec. VI-A noise on the other vehicles).

    Returns (front (3,) [x, y, v], opp (2,) [x, v]); the ego's own state is known exactly.
    """
    c = checks(plant.ego, plant.front, plant.opp, jnp.zeros(2), pp)
    return _measure_front(plant, key, step, pp, c.gap_front_m), _measure_opp(plant, key, step, pp, c.gap_opp_m)


def _measure_front(plant: Plant, key: Array, step: Array, pp: PlantParams, gap_m: Array,
                   unit: Array | None = None) -> Array:
    """veh_f measured (3,) [x, y, v], from the step's own draws or from ``unit`` (3,) (a noise tilt's)."""
    nz = pp.noise
    fsx, fsv = nz.front.offsets(plant.t_s, nz.episode_s)
    fsy = nz.lateral.offset(plant.t_s, gap_m, nz.episode_s)
    return jnp.stack(noise.measure(noise.step_key(key, step, STREAM_FRONT), plant.front[0], 0.0, plant.front[1],
                                   gap_m, nz.bounds, share=nz.share, x_offset=fsx, v_offset=fsv, unit=unit,
                                   y_share=nz.lateral_share, y_offset=fsy))


def _measure_opp(plant: Plant, key: Array, step: Array, pp: PlantParams, gap_m: Array) -> Array:
    """veh_o measured (2,) [x, v]."""
    nz = pp.noise
    osx, osv = nz.opp.offsets(plant.t_s, nz.episode_s)
    ox, _, ov = noise.measure(noise.step_key(key, step, STREAM_OPP), plant.opp[0], pp.opp_lane_y_m, plant.opp[1],
                              gap_m, nz.bounds, share=nz.share, x_offset=osx, v_offset=osv)
    return jnp.stack([ox, ov])


def observe_tilted(plant: Plant, key: Array, step: Array, pp: PlantParams, tilt: tilt_mod.TiltParams,
                   live: Array) -> tuple[Array, Array, Plant]:
    """:func:`observe` with veh_f's noise drawn from a :class:`~mcverify.sim.tilt.NoiseTilt` at the
    tilted steps (importance sampling); returns the measurements and the plant with its likelihood
    ratio and tilt statistics updated.

    tilt: the tilt's runtime numbers (:meth:`mcverify.sim.tilt.NoiseTilt.params`); live: () whether the
    episode still uses its measurements (a stopped episode's later draws change nothing, so they are not
    counted: its likelihood ratio does not depend on how long its chunk runs). Away from the tilted steps
    every draw is :func:`observe`'s, bit for bit (the step's own units go through the same measurement).
    """
    c = checks(plant.ego, plant.front, plant.opp, jnp.zeros(2), pp)
    theta, split_m, gap_max_m, band_steps, defensive, theta_max = tilt
    gap = c.gap_front_m
    band = jnp.where(gap > split_m, 0, jnp.where(gap > pp.noise.bounds.near_threshold_m, 1, 2))
    tilted = (live & (pp.noise.bounds.scale > 0) & (gap <= gap_max_m) & (plant.tilt_counts[band] < band_steps))
    raw = noise.unit_draws(noise.step_key(key, step, STREAM_FRONT))
    # one draw per episode (not per step) picks the mixture's component
    nominal = jax.random.uniform(jax.random.fold_in(key, tilt_mod.STREAM_TILT), (), dtype=float) < defensive
    z, log_ratio = tilt_mod.tilted_units(raw, nominal, jnp.clip(theta[band], -theta_max, theta_max))
    front = _measure_front(plant, key, step, pp, gap, unit=jnp.where(tilted, z, raw))
    one_hot = (jnp.arange(3) == band) & tilted
    return front, _measure_opp(plant, key, step, pp, c.gap_opp_m), plant._replace(
        tilt_log_ratio=plant.tilt_log_ratio + jnp.where(tilted, log_ratio, 0.0),
        tilt_sums=plant.tilt_sums + jnp.where(jnp.repeat(one_hot, 3), jnp.tile(z, 3), 0.0),
        tilt_counts=plant.tilt_counts + one_hot.astype(float),
    )


def observe_scheduled(plant: Plant, key: Array, step_input: schedule_mod.ScheduleStep,
                      pp: PlantParams) -> tuple[Array, Array, Array]:
    """:func:`observe` with the error given by an error schedule instead of drawn (:mod:`mcverify.sim.schedule`):
    each vehicle's measurement error is its share times the step's units, scaled by the bounds as
    :func:`~mcverify.sim.noise.measure` scales its draws; the structured disturbances are not applied.
    Returns (front (3,), opp (2,), the units (5,) applied, before the shares). ``key`` is unused (no draw)."""
    c = checks(plant.ego, plant.front, plant.opp, jnp.zeros(2), pp)
    units = schedule_mod.step_units(step_input, c.gap_front_m)
    front_unit = step_input.shares[0] * units[jnp.array(schedule_mod.FRONT_CHANNELS)]
    opp_x, opp_v = (step_input.shares[1] * units[i] for i in schedule_mod.OPP_CHANNELS)
    front = jnp.stack(noise.measure(key, plant.front[0], 0.0, plant.front[1], c.gap_front_m, pp.noise.bounds,
                                    unit=front_unit))
    ox, _, ov = noise.measure(key, plant.opp[0], pp.opp_lane_y_m, plant.opp[1], c.gap_opp_m, pp.noise.bounds,
                              unit=jnp.stack([opp_x, 0.0, opp_v]))
    return front, jnp.stack([ox, ov]), units


def opposing_accel(plant: Plant, u: Array, pp: PlantParams) -> Array:
    """veh_o's acceleration for this control period (its controller samples at the ego's rate)."""
    auto = agents.autonomous_accel(
        plant.opp, plant.ego, u,
        cruise_speed_mps=pp.opp_cruise_mps, gain_per_s=pp.opp_gain_per_s, lambdas=pp.opp_lambdas,
        decel_max_mps2=pp.decel_max_mps2, accel_max_mps2=pp.opp_accel_max_mps2,
        brake_max_mps2=pp.opp_brake_max_mps2, l_r_m=pp.l_r_m,
        ego_in_opposing_lane=agents.ego_top_edge_m(plant.ego, pp.length_m, pp.width_m) > pp.lane_line_y_m,
    )
    human = agents.human_accel(plant.opp[1], pp.opp_accel_mps2, pp.opp_speed_limit_mps, pp.control_period_s)
    alpha = jnp.where(pp.opp_kind == OPP_AUTONOMOUS, auto, jnp.where(pp.opp_kind == OPP_HUMAN, human, 0.0))
    return agents.stop_at_rest(plant.opp[1], alpha, pp.control_period_s)


def _double_integrator(xv: Array, accel: Array, dt: Array) -> Array:
    return jnp.stack([xv[0] + xv[1] * dt + 0.5 * accel * dt**2, xv[1] + accel * dt])


def advance(plant: Plant, trace: SafetyTrace, u: Array, active: Array, pp: PlantParams, substeps: int):
    """Run one control period under zero-order hold; every check at every sub-step.

    Finished episodes (``active`` False) stay frozen. Returns (plant, trace, Substep (substeps, ...)).
    """
    alpha_o = opposing_accel(plant, u, pp)
    dt = pp.dt_sub_s
    accel_excess, slip_excess = input_excess(u, pp)  # held for the whole period
    accel_best = _worse(trace.accel_excess_mps2, trace.accel_excess_t_s, accel_excess, plant.t_s)
    slip_best = _worse(trace.slip_excess_rad, trace.slip_excess_t_s, slip_excess, plant.t_s)

    def body(carry, i):
        ego, front, opp, tr = carry
        t = plant.t_s + i * dt
        ego_n = vehicles.rk4_step(lambda x, uu: vehicles.ego_derivative(x, uu, pp.l_r_m), ego, u, dt)
        a_f = agents.front_accel(t, plant.front_accel_mps2, plant.front_onset_s, plant.front_duration_s, front[1],
                                 pp.front_speed_max_mps, dt)
        front_n = _double_integrator(front, a_f, dt)
        opp_n = _double_integrator(opp, alpha_o, dt)
        t_n = plant.t_s + (i + 1) * dt
        c = checks(ego_n, front_n, opp_n, u, pp)
        tr = SafetyTrace(
            jnp.minimum(tr.min_h_front, c.h_front),
            jnp.minimum(tr.min_dist_front_m, c.dist_front_m),
            jnp.minimum(tr.min_gap_front_m, c.gap_front_m),
            tr.collision_front | c.hit_front,
            jnp.where(c.borrowing & jnp.isnan(tr.first_opp_lane_s), t_n, tr.first_opp_lane_s),
            jnp.where(c.borrowing, t_n, tr.last_opp_lane_s),
            tr.collision_opp | c.hit_opp,
            jnp.where(c.opp_relevant, jnp.minimum(tr.min_gap_opp_m, c.gap_opp_m), tr.min_gap_opp_m),
            jnp.minimum(tr.min_gap_opp_any_m, c.gap_opp_m),
            jnp.where(c.opp_relevant, jnp.minimum(tr.min_h_opp, c.h_opp), tr.min_h_opp),
            *_worse(tr.speed_excess_mps, tr.speed_excess_t_s, ego_n[3] - pp.ego_speed_max_mps, t_n),
            *accel_best, *slip_best,
        )
        sub = Substep(t_n, ego_n, front_n, opp_n, c.h_front, c.dist_front_m, c.gap_front_m, c.hit_front,
                      c.h_opp, c.gap_opp_m, c.hit_opp)
        return (ego_n, front_n, opp_n, tr), sub

    (ego, front, opp, tr), subs = jax.lax.scan(body, (plant.ego, plant.front, plant.opp, trace), jnp.arange(substeps))
    new_plant = plant._replace(ego=ego, front=front, opp=opp, t_s=plant.t_s + pp.control_period_s)
    keep = lambda new, old: jnp.where(active, new, old)  # noqa: E731 - finished episodes stay frozen
    return jax.tree.map(keep, new_plant, plant), jax.tree.map(keep, tr, trace), subs


# ------------------------------------------------------------------------- compiled, batched


@functools.lru_cache(maxsize=8)
def compiled(substeps: int):
    """(observe, advance, initial_trace), each jitted and vmapped over :data:`LANES` episodes.

    Cached per sub-step count (the scan length is the only compile-time number): every cell of every
    campaign with the same ``sim.substeps`` runs the same executables.
    """
    obs = jax.jit(jax.vmap(observe, in_axes=(0, 0, None, None)))
    adv = jax.jit(jax.vmap(functools.partial(advance, substeps=substeps), in_axes=(0, 0, 0, 0, None)))
    ini = jax.jit(jax.vmap(initial_trace, in_axes=(0, None)))
    return obs, adv, ini


@functools.lru_cache(maxsize=1)
def compiled_tilted():
    """:func:`observe_tilted`, jitted and vmapped over :data:`LANES` episodes (importance sampling only)."""
    return jax.jit(jax.vmap(observe_tilted, in_axes=(0, 0, None, None, None, 0)))


@functools.lru_cache(maxsize=1)
def compiled_scheduled():
    """:func:`observe_scheduled`, jitted and vmapped over :data:`LANES` episodes (episodes run with error schedules)."""
    return jax.jit(jax.vmap(observe_scheduled, in_axes=(0, 0, 0, None)))


def initial_plant(p: ModelParams, front_accels_mps2: Sequence[float],
                  opp_speeds_mps: Sequence[float] | None = None, front_onsets_s: Sequence[float] | None = None,
                  front_durations_s: Sequence[float] | None = None) -> Plant:
    """The campaign's start (paper Sec. VI-B) for episodes with these alpha_f (and veh_o speeds,
    default ``opposing.speed_mps``; burst onsets and durations, default ``scenario.front_accel_onset_s`` and
    ``scenario.front_accel_duration_s``), batched. veh_o is parked out of reach when there is none or
    when it appears later (``opposing.spawn = "lane_entry"``, :meth:`mcverify.sim.lanes.LaneGroups.place_opposing`)."""
    n = len(front_accels_mps2)
    s, o = p.scenario, p.opposing
    ego = jnp.tile(jnp.array([s.ego_x_m, p.road.ego_lane_y_m, 0.0, s.ego_speed_mps]), (n, 1))
    front = jnp.tile(jnp.array([s.front_x_m, s.front_speed_mps]), (n, 1))
    if o.kind == "none" or o.spawn != "start":
        opp = jnp.tile(jnp.array([_NO_OPP_X_M, 0.0], dtype=float), (n, 1))
    else:
        speeds = [o.speed_mps] * n if opp_speeds_mps is None else list(opp_speeds_mps)
        opp = jnp.array([[o.x_m, -v] for v in speeds], dtype=float)
    onsets = [s.front_accel_onset_s] * n if front_onsets_s is None else list(front_onsets_s)
    durations = [s.front_accel_duration_s] * n if front_durations_s is None else list(front_durations_s)
    per_episode = lambda v: jnp.asarray(v, dtype=float)  # noqa: E731
    return Plant(ego, front, opp, per_episode(front_accels_mps2), per_episode(onsets), per_episode(durations),
                 jnp.zeros(n), jnp.zeros(n), jnp.zeros((n, 9)), jnp.zeros((n, 3)))


def footprint_top_y_m(ego: np.ndarray, p: ModelParams) -> np.ndarray:
    """(n,) the highest y of each ego footprint (its corner nearest the opposing lane), m.

    ego: (n, 4) [x, y, psi, v]. Used on the host for the spawn rule: the footprint has entered the
    opposing lane once this exceeds the lane line (y = lane_width / 2)."""
    g = p.geometry
    psi = ego[:, 2]
    return ego[:, 1] + 0.5 * g.length_m * np.abs(np.sin(psi)) + 0.5 * g.width_m * np.cos(psi)
