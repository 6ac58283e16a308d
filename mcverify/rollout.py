"""Closed-loop rollout of a batch of disturbed episodes.

Time is split at the planner's sampling instants. One control step is:

1. ``observe`` (JAX, vmapped): every episode's planner measures the front vehicle with perception
   noise drawn from keys that depend only on (episode key, step), never on the batch;
2. the host solves Q1 and Q2 for the whole batch (cached CasADi kernel, warm-started per episode)
   and :func:`mcverify.decision.decide` picks the input (Algorithm 1);
3. ``advance`` (JAX, vmapped, ``lax.scan`` over sub-steps): the plant runs under zero-order hold
   with fine RK4 sub-steps and every safety check is evaluated at every sub-step.

Episodes that finish are frozen (masked) while the rest of the batch goes on. All episode results
are a pure function of (campaign cell, seed, episode id): the batch size and the other episodes in
the batch do not enter them (tests check this against a loop of single episodes).
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mcverify import barriers, geometry, noise, vehicles
from mcverify.campaign import Cell
from mcverify.decision import Mode, Source, decide
from mcverify.model import ModelParams
from mcverify.solver import MpcSolution, MpcSolver

Array = jax.Array

Q1, Q2 = +1, -1  # the OCP's direction parameter: goal ahead of / behind the front vehicle


# ------------------------------------------------------------------------------------- pytrees


class Plant(NamedTuple):
    """True state of one episode (batched along a leading axis by vmap).

    ego: (4,) [x_m, y_m, psi_rad, speed_mps]; front: (2,) [x_m, speed_mps] (the front vehicle
    keeps to the ego lane centre, y = 0); front_accel_mps2: () its acceleration once
    ``t_s >= front_accel_onset_s``; t_s: () time since the episode started.
    """

    ego: Array
    front: Array
    front_accel_mps2: Array
    t_s: Array


class SafetyTrace(NamedTuple):
    """Running per-episode safety metrics, updated at every sub-step (all scalars).

    min_h_front: min of h_ef along the true trajectory (dimensionless);
    min_dist_front_m: min signed Euclidean distance from the ego c.g. to the h_ef = 0 ellipse
    (negative inside); min_gap_front_m: min distance between the two footprints (0 on contact);
    collision_front: the footprints overlapped at some sub-step;
    first_opp_lane_s / last_opp_lane_s: first and last sub-step time at which the ego footprint
    reached into the opposing lane (NaN if never).
    """

    min_h_front: Array
    min_dist_front_m: Array
    min_gap_front_m: Array
    collision_front: Array
    first_opp_lane_s: Array
    last_opp_lane_s: Array


class Substep(NamedTuple):
    """What ``advance`` reports at each sub-step when recording a trajectory (replay)."""

    t_s: Array
    ego: Array
    front: Array
    h_front: Array
    dist_front_m: Array
    gap_front_m: Array
    collision_front: Array


# ------------------------------------------------------------------------------- JAX kernels


@dataclass(frozen=True)
class PlantKernels:
    """The jitted, vmapped JAX functions of one parameter set (built once per cell, cached)."""

    observe: Callable[..., Array]
    advance: Callable[..., tuple[Plant, SafetyTrace, Substep]]
    initial_trace: Callable[[Plant], SafetyTrace]


@functools.lru_cache(maxsize=32)
def plant_kernels(params: ModelParams) -> PlantKernels:
    """Build (and cache per parameter set) the batched JAX step functions."""
    geo, bar, road, sim, scen = params.geometry, params.barrier, params.road, params.sim, params.scenario
    l_r = params.ego.l_r_m
    dt_sub = sim.control_period_s / sim.substeps
    half_lane = road.lane_width_m / 2.0

    def front_xy(front: Array) -> tuple[Array, Array]:
        return front[0], jnp.zeros_like(front[0])

    def checks(ego: Array, front: Array) -> tuple[Array, Array, Array, Array, Array]:
        fx, fy = front_xy(front)
        h = barriers.h_ellipse(ego[0], ego[1], fx, fy, bar.ellipse_a_m, bar.ellipse_b_m)
        dist = geometry.ellipse_signed_distance_m(ego[0] - fx, ego[1] - fy, bar.ellipse_a_m, bar.ellipse_b_m)
        ego_box = geometry.footprint_corners(ego[0], ego[1], ego[2], geo.length_m, geo.width_m)
        front_box = geometry.footprint_corners(fx, fy, 0.0, geo.length_m, geo.width_m)
        hit = geometry.rectangles_overlap(ego_box, front_box)
        gap = geometry.rectangle_gap_m(ego_box, front_box)
        in_opp = jnp.max(ego_box[:, 1]) > half_lane
        return h, dist, gap, hit, in_opp

    def initial_trace(plant: Plant) -> SafetyTrace:
        h, dist, gap, hit, in_opp = checks(plant.ego, plant.front)
        t0 = jnp.where(in_opp, plant.t_s, jnp.nan)
        return SafetyTrace(h, dist, gap, hit, t0, t0)

    def observe(plant: Plant, key: Array, step: Array) -> Array:
        """Measured front vehicle [x, y, v] at this control step (perception noise, Sec. VI-A)."""
        fx, fy = front_xy(plant.front)
        _, _, gap, _, _ = checks(plant.ego, plant.front)
        k = noise.step_key(key, step, 0)
        mx, my, mv = noise.measure_vehicle(k, fx, fy, plant.front[1], gap, params.noise)
        return jnp.stack([mx, my, mv])

    def front_substep(front: Array, accel_on: Array, t: Array) -> Array:
        # The front vehicle accelerates from the onset time on, up to its speed cap, never
        # switching sign (the paper's assumption on veh_f). Exact double-integrator update.
        a = jnp.where(t >= scen.front_accel_onset_s, accel_on, 0.0)
        a = jnp.minimum(a, jnp.maximum(scen.front_speed_max_mps - front[1], 0.0) / dt_sub)
        return jnp.stack([front[0] + front[1] * dt_sub + 0.5 * a * dt_sub**2, front[1] + a * dt_sub])

    def advance(plant: Plant, trace: SafetyTrace, u: Array, active: Array):
        """Run one control period under zero-order hold; checks at every sub-step."""

        def body(carry, i):
            ego, front, tr = carry
            t = plant.t_s + i * dt_sub
            ego_n = vehicles.rk4_step(lambda x, uu: vehicles.ego_derivative(x, uu, l_r), ego, u, dt_sub)
            front_n = front_substep(front, plant.front_accel_mps2, t)
            t_n = plant.t_s + (i + 1) * dt_sub
            h, dist, gap, hit, in_opp = checks(ego_n, front_n)
            tr = SafetyTrace(
                jnp.minimum(tr.min_h_front, h),
                jnp.minimum(tr.min_dist_front_m, dist),
                jnp.minimum(tr.min_gap_front_m, gap),
                tr.collision_front | hit,
                jnp.where(in_opp & jnp.isnan(tr.first_opp_lane_s), t_n, tr.first_opp_lane_s),
                jnp.where(in_opp, t_n, tr.last_opp_lane_s),
            )
            return (ego_n, front_n, tr), Substep(t_n, ego_n, front_n, h, dist, gap, hit)

        (ego, front, tr), subs = jax.lax.scan(
            body, (plant.ego, plant.front, trace), jnp.arange(sim.substeps)
        )
        new_plant = Plant(ego, front, plant.front_accel_mps2, plant.t_s + sim.control_period_s)
        keep = lambda new, old: jnp.where(active, new, old)  # noqa: E731 - finished episodes stay frozen
        return jax.tree.map(keep, new_plant, plant), jax.tree.map(keep, tr, trace), subs

    return PlantKernels(
        observe=jax.jit(jax.vmap(observe)),
        advance=jax.jit(jax.vmap(advance)),
        initial_trace=jax.jit(jax.vmap(initial_trace)),
    )


# --------------------------------------------------------------------------------- keys


def episode_key(seed: int, cell_index: int | None, episode_id: int) -> Array:
    """The root key of one episode: (seed, cell, episode id), or (seed, episode id) for common
    random numbers across cells (paired comparisons)."""
    key = jax.random.PRNGKey(seed)
    if cell_index is not None:
        key = jax.random.fold_in(key, cell_index)
    return jax.random.fold_in(key, episode_id)


#: fold_in stream of the per-episode scenario draws, apart from the per-step noise streams.
SCENARIO_STREAM = 1_000_000


def sample_scenario(key: Array, params: ModelParams) -> dict[str, float]:
    """Per-episode scenario values drawn from the episode key.

    alpha_f: ``scenario.front_accel_range_mps2`` = (lo, hi) draws it uniformly in (lo, hi] (the
    paper's Table III ranges are left-open); otherwise the fixed ``front_accel_mps2``.
    """
    sc = params.scenario
    if sc.front_accel_range_mps2:
        lo, hi = sc.front_accel_range_mps2
        unit = jax.random.uniform(jax.random.fold_in(key, SCENARIO_STREAM), (), dtype=float)  # [0, 1)
        accel = hi - (hi - lo) * float(unit)  # (lo, hi]
    else:
        accel = sc.front_accel_mps2
    return {"front_accel_mps2": float(accel)}


# ------------------------------------------------------------------------------ host loop


@dataclass
class EpisodeLog:
    """Host-side bookkeeping of one episode: decisions, solver statistics, outcome."""

    episode_id: int
    mode: Mode = Mode.OVERTAKE
    done: bool = False
    outcome: str = "running"
    end_time_s: float = math.nan
    overtake_time_s: float = math.nan
    steps: int = 0
    q1_fail_steps: int = 0
    q2_fail_steps: int = 0
    both_infeasible_steps: int = 0
    fallback_steps: int = 0
    q2_driven_steps: int = 0
    switched_to_q2_at_s: float = math.nan
    iterations: list[int] = field(default_factory=list)
    solve_times_s: list[float] = field(default_factory=list)
    statuses: dict[str, int] = field(default_factory=dict)
    warm: dict[int, object] = field(default_factory=dict)

    def record_solve(self, sol: MpcSolution) -> None:
        self.iterations.append(sol.iterations)
        self.solve_times_s.append(sol.solve_time_s)
        self.statuses[sol.status] = self.statuses.get(sol.status, 0) + 1


@dataclass
class ChunkResult:
    rows: list[dict]
    trajectories: dict[int, dict[str, np.ndarray]] = field(default_factory=dict)


def run_episodes(
    cell: Cell,
    episode_ids: Sequence[int],
    seed: int,
    solver: MpcSolver,
    *,
    common_random_numbers: bool = False,
    record: bool = False,
    on_step: Callable[[int], None] | None = None,
) -> ChunkResult:
    """Simulate ``episode_ids`` of ``cell`` as one vmapped batch; one metrics row per episode.

    With ``record=True`` the full-resolution trajectory of every episode is returned as well.
    """
    p = cell.params
    kern = plant_kernels(p)
    n = len(episode_ids)
    cell_key = None if common_random_numbers else cell.index
    keys = jnp.stack([episode_key(seed, cell_key, int(e)) for e in episode_ids])
    samples = [sample_scenario(k, p) for k in keys]
    plant = _initial_plant(p, samples)
    trace = kern.initial_trace(plant)
    h0 = np.asarray(trace.min_h_front).copy()
    logs = [EpisodeLog(int(e)) for e in episode_ids]
    rec = _Recorder(n) if record else None
    n_steps = int(math.ceil(p.sim.max_time_s / p.sim.control_period_s - 1e-9))

    for step in range(n_steps):
        t_s = step * p.sim.control_period_s
        measured = np.asarray(kern.observe(plant, keys, jnp.full((n,), step)))
        ego = np.asarray(plant.ego)
        u = np.zeros((n, 2))
        sources = np.zeros(n, dtype=np.int8)
        for b, log in enumerate(logs):
            if log.done:
                continue
            if _converged(log, ego[b], measured[b], p):
                log.done, log.end_time_s = True, t_s
                log.outcome = "overtook" if log.mode is Mode.OVERTAKE else "went_back"
                if log.mode is Mode.OVERTAKE:
                    log.overtake_time_s = t_s
                continue
            u[b], sources[b] = _control_step(log, ego[b], measured[b], cell, solver, t_s)
        active = np.array([not log.done for log in logs])
        if not active.any():
            break
        plant, trace, subs = kern.advance(plant, trace, jnp.asarray(u), jnp.asarray(active))
        if rec is not None:
            rec.add(subs, u, sources, measured, active, np.array([lg.mode for lg in logs]))
        if on_step is not None:
            on_step(step)
    for log in logs:
        if not log.done:
            log.done, log.outcome, log.end_time_s = True, "timeout", n_steps * p.sim.control_period_s

    rows = [
        _episode_row(cell, seed, log, samples[b], jax.tree.map(lambda a, b=b: a[b], trace), h0[b])
        for b, log in enumerate(logs)
    ]
    trajectories = rec.per_episode(episode_ids) if rec is not None else {}
    return ChunkResult(rows, trajectories)


def _initial_plant(p: ModelParams, samples: list[dict[str, float]]) -> Plant:
    n = len(samples)
    s = p.scenario
    ego = jnp.tile(jnp.array([s.ego_x_m, 0.0, 0.0, s.ego_speed_mps]), (n, 1))
    front = jnp.tile(jnp.array([s.front_x_m, s.front_speed_mps]), (n, 1))
    accel = jnp.array([smp["front_accel_mps2"] for smp in samples])
    return Plant(ego, front, accel, jnp.zeros(n))


def _converged(log: EpisodeLog, ego: np.ndarray, front_meas: np.ndarray, p: ModelParams) -> bool:
    """The paper's convergence test on the *measured* state (what the controller knows).

    Q1: x_e >= x_f + phi v_f and |y_e - y_g| <= eps_y; Q2: x_e <= x_f - phi v_f, same lateral test.
    """
    goal_y = p.road.ego_lane_y_m
    if abs(ego[1] - goal_y) > p.mpc.eps_y_m:
        return False
    offset = p.mpc.phi_s * front_meas[2]
    if log.mode is Mode.OVERTAKE:
        return bool(ego[0] >= front_meas[0] + offset)
    return bool(ego[0] <= front_meas[0] - offset)


def _control_step(
    log: EpisodeLog, ego: np.ndarray, front_meas: np.ndarray, cell: Cell, solver: MpcSolver, t_s: float
) -> tuple[np.ndarray, Source]:
    """Solve Q1 and Q2 for one episode, decide (Algorithm 1), return the input to apply."""
    sols: dict[int, MpcSolution] = {}
    for direction in (Q1, Q2):
        if direction == Q1 and log.mode is Mode.GO_BACK:
            continue  # the overtake was abandoned for good: Q1 is no longer solved
        sol = solver.solve(ego, front_meas, direction, cell.lambda0, log.warm.get(direction))
        log.record_solve(sol)
        if sol.success:
            log.warm[direction] = sol.warm
        else:
            log.warm.pop(direction, None)  # never restart from a stale point
        sols[direction] = sol
    q1_ok = Q1 in sols and sols[Q1].success
    q2_ok = sols[Q2].success
    log.steps += 1
    log.q1_fail_steps += int(Q1 in sols and not q1_ok)
    log.q2_fail_steps += int(not q2_ok)
    log.both_infeasible_steps += int(not q1_ok and not q2_ok)
    before = log.mode
    log.mode, source = decide(log.mode, q1_ok, q2_ok)
    if before is Mode.OVERTAKE and log.mode is Mode.GO_BACK:
        log.switched_to_q2_at_s = t_s
    if source is Source.FALLBACK:
        log.fallback_steps += 1
        return fallback_input(ego, cell.params), source
    log.q2_driven_steps += int(source is Source.Q2)
    return sols[Q1 if source is Source.Q1 else Q2].u_plan[0], source


def fallback_input(ego: np.ndarray, p: ModelParams) -> np.ndarray:
    """Neither problem solved: brake (without reversing) and steer back towards the ego lane."""
    e = p.ego
    accel = max(e.accel_min_mps2, -ego[3] / p.sim.control_period_s)
    beta = float(np.clip(-(0.3 * (ego[1] - p.road.ego_lane_y_m) + 1.0 * ego[2]), -e.slip_max_rad, e.slip_max_rad))
    return np.array([accel, beta])


def _episode_row(
    cell: Cell, seed: int, log: EpisodeLog, sample: dict[str, float], tr: SafetyTrace, h0: float
) -> dict:
    eps = cell.epsilon
    min_h = float(tr.min_h_front)
    first, last = float(tr.first_opp_lane_s), float(tr.last_opp_lane_s)
    collision = bool(tr.collision_front)
    iters = np.array(log.iterations or [0])
    times = np.array(log.solve_times_s or [0.0])
    return {
        "episode_id": cell.episode_offset + log.episode_id,
        "cell_episode": log.episode_id,
        "cell": cell.name,
        "cell_index": cell.index,
        "seed": seed,
        **{f"sample_{k}": v for k, v in sample.items()},
        "outcome": log.outcome,
        "overtook": log.outcome == "overtook",
        "went_back": log.outcome == "went_back",
        "timeout": log.outcome == "timeout",
        "end_time_s": log.end_time_s,
        "overtake_time_s": log.overtake_time_s,
        "lane_borrow_time_s": (last - first) if math.isfinite(first) else math.nan,
        "collision_front": collision,
        "min_h_front": min_h,
        "min_dist_front_m": float(tr.min_dist_front_m),
        "min_gap_front_m": float(tr.min_gap_front_m),
        "ellipse_violation": min_h < 0.0,
        "safe": (not collision) and min_h >= 0.0,
        "h0_front": float(h0),
        "epsilon": eps,
        "lambda0": cell.lambda0,
        "invariance_breach": bool(h0 >= eps and min_h < eps),
        "invariance_margin": min_h - eps,
        "steps": log.steps,
        "q1_fail_steps": log.q1_fail_steps,
        "q2_fail_steps": log.q2_fail_steps,
        "both_infeasible_steps": log.both_infeasible_steps,
        "fallback_steps": log.fallback_steps,
        "q2_driven_steps": log.q2_driven_steps,
        "switched_to_q2_at_s": log.switched_to_q2_at_s,
        "solves": len(log.iterations),
        "iterations_mean": float(iters.mean()),
        "iterations_max": int(iters.max()),
        "solve_time_mean_s": float(times.mean()),
        "solve_time_max_s": float(times.max()),
        "solver_statuses": json.dumps(dict(sorted(log.statuses.items()))),
    }


#: Columns that depend on wall-clock time; everything else is reproducible bit for bit.
TIMING_COLUMNS = ("solve_time_mean_s", "solve_time_max_s")


class _Recorder:
    """Collects full-resolution trajectories (replay) from the batched sub-step outputs."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.parts: list[dict[str, np.ndarray]] = []

    def add(self, subs: Substep, u, sources, measured, active, modes) -> None:
        k = np.asarray(subs.t_s).shape[1]
        rep = lambda a: np.repeat(np.asarray(a)[:, None], k, axis=1)  # noqa: E731 - per control step -> per sub-step
        ego, front = np.asarray(subs.ego), np.asarray(subs.front)
        self.parts.append({
            "t_s": np.asarray(subs.t_s),
            "ego_x_m": ego[..., 0], "ego_y_m": ego[..., 1], "ego_psi_rad": ego[..., 2], "ego_speed_mps": ego[..., 3],
            "front_x_m": front[..., 0], "front_y_m": np.zeros_like(front[..., 0]), "front_speed_mps": front[..., 1],
            "alpha_mps2": rep(u[:, 0]), "beta_rad": rep(u[:, 1]),
            "h_front": np.asarray(subs.h_front), "dist_front_m": np.asarray(subs.dist_front_m),
            "gap_front_m": np.asarray(subs.gap_front_m), "collision_front": np.asarray(subs.collision_front),
            "active_problem": rep(sources), "mode": rep(modes),
            "meas_front_x_m": rep(measured[:, 0]), "meas_front_y_m": rep(measured[:, 1]),
            "meas_front_speed_mps": rep(measured[:, 2]),
            "_active": rep(active),
        })

    def per_episode(self, episode_ids: Sequence[int]) -> dict[int, dict[str, np.ndarray]]:
        out = {}
        for b, e in enumerate(episode_ids):
            cols = {k: np.concatenate([p[k][b] for p in self.parts]) for k in self.parts[0]}
            keep = cols.pop("_active").astype(bool)
            out[int(e)] = {k: v[keep] for k, v in cols.items()}
        return out
