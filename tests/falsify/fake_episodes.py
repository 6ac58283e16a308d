"""A cheap episode function for falsification tests: rows whose margins depend on the cell's
parameters (the searched fields) and on per-episode noise from (seed, episode id) only."""

from __future__ import annotations

import math

import numpy as np

from mcverify.episode.recording import EpisodeRecording
from tests import synthetic_episodes


def episodes(cell, episode_ids, seed, common_random_numbers, record):
    out = synthetic_episodes.episodes(cell, episode_ids, seed, common_random_numbers, record)
    v = cell.params.scenario.front_speed_mps
    o = cell.params.opposing.speed_mps
    for r in out.rows:
        noise = np.random.default_rng([seed, int(r["episode_id"])]).random()
        min_h = 0.6 * abs(v - 8.6) + 0.05 * abs(o - 17.0) - 0.15 + 0.01 * noise
        r.update({"min_h_front": min_h, "collision_front": False, "ellipse_violation": min_h < 0,
                  "min_gap_front_m": 1.0, "safe": min_h >= 0, "opposing_kind": "none",
                  "first_unsafe_s": 3.0 if min_h < 0 else math.nan,
                  "first_unsafe_cause": "planned" if min_h < 0 else ""})
    return out


#: Control steps of a :func:`noisy_walk` episode.
WALK_STEPS = 60


def walk_margins(cell, seed: int, episode: int) -> np.ndarray:
    """h_ef after each control step of a noise-driven random walk keyed as the real engine keys its
    noise: the root is (noise.key_seed, episode) or (seed, cell, episode), and after each step of
    noise.branch_after_steps the increments come from that branch of the root."""
    n = cell.params.noise
    root = [n.key_seed, episode] if n.key_seed >= 0 else [seed, cell.index, episode]
    switches = dict(zip((int(s) for s in n.branch_after_steps), (int(b) for b in n.branch_ids), strict=True))
    branch, xi = -1, np.empty(WALK_STEPS)
    for t in range(WALK_STEPS):
        if t - 1 in switches:
            branch = switches[t - 1]
        xi[t] = np.random.default_rng([*root, branch + 1, t]).standard_normal()
    v = cell.params.scenario.front_speed_mps
    return 0.9 + 0.4 * abs(v - 7.0) + np.cumsum(-0.004 + 0.05 * xi)


def noisy_walk(cell, episode_ids, seed, common_random_numbers, record):
    """Rows and trajectories (one sub-step per control step) of :func:`walk_margins`: an ellipse
    violation is rare for random candidates and driven by the per-step noise."""
    out = synthetic_episodes.episodes(cell, episode_ids, seed, common_random_numbers, record)
    dt = cell.params.sim.control_period_s
    out.recordings = {}
    for r in out.rows:
        e = int(r["cell_episode"])
        _margin_episode(out, r, e, walk_margins(cell, seed, e), dt, e in record)
    return out


def _margin_episode(out, row: dict, e: int, h: np.ndarray, dt: float, recorded: bool, **columns: np.ndarray) -> None:
    """Fill ``row`` from the h_ef series ``h`` (one value per control step) and, if ``recorded``, store
    its trajectory (with ``columns`` added) in ``out.recordings[e]``."""
    min_h = float(h.min())
    row.update({"min_h_front": min_h, "collision_front": False, "ellipse_violation": min_h < 0,
                "min_gap_front_m": 1.0, "safe": min_h >= 0, "opposing_kind": "none",
                "first_unsafe_s": float(dt * (1 + np.flatnonzero(h < 0)[0])) if min_h < 0 else math.nan,
                "first_unsafe_cause": "planned" if min_h < 0 else ""})
    if recorded:
        ones = np.ones(WALK_STEPS)
        out.recordings[e] = EpisodeRecording({
            "t_s": dt * np.arange(1, WALK_STEPS + 1), "h_front": h, "gap_front_m": ones,
            "collision_front": 0 * ones, "gap_opp_m": np.nan * ones, "collision_opp": 0 * ones, **columns})


def turnback_margins(v: float, noise: float) -> tuple[np.ndarray, np.ndarray]:
    """(h_ef per control step, mode per control step) of a deceptive target: below 7.5 m/s veh_f is
    slow enough that the ego turns back at step 30 and the turn-back's margin dips to
    0.15 |v - 6| - 0.01 (violated only within 0.07 m/s of 6 m/s); faster, it overtakes with a margin
    that falls towards 10 m/s but stays >= 0.02. So the requirement's robustness (min h_ef) points to
    10 m/s everywhere but next to the violations."""
    t = np.arange(WALK_STEPS)
    if v < 7.5:
        dip = 0.1 * abs(v - 6.0) - 0.005 + 0.001 * noise
        h = np.where(t < 30, 0.9, 0.2 + (dip - 0.2) * np.exp(-0.5 * ((t - 45) / 5.0) ** 2))
        return h, np.where(t < 30, 0, 1)
    return 0.9 - (0.898 - 0.002 * (10.0 - v)) * np.exp(-0.5 * ((t - 30) / 5.0) ** 2), np.zeros(WALK_STEPS, dtype=int)


def turnback(cell, episode_ids, seed, common_random_numbers, record):
    """Rows and trajectories (``mode`` included) of :func:`turnback_margins` for the guide tests."""
    out = synthetic_episodes.episodes(cell, episode_ids, seed, common_random_numbers, record)
    dt = cell.params.sim.control_period_s
    out.recordings = {}
    for r in out.rows:
        e = int(r["cell_episode"])
        noise = np.random.default_rng([seed, cell.index, e]).random()
        h, mode = turnback_margins(cell.params.scenario.front_speed_mps, noise)
        _margin_episode(out, r, e, h, dt, e in record, mode=mode.astype(np.float64))
    return out


def ladder_margins(cell, seed: int, episode: int) -> tuple[np.ndarray, np.ndarray]:
    """(h_ef, unsolved) per control step of a violation reached by a ladder of unsolved steps, as on
    the closed loop (docs/rare_events.md, "A score that traps"): from step 10 the planner fails both
    problems with probability 0.05 after a solved step and 0.3 after an unsolved one; h_ef stays near
    0.5 (its small noise says nothing of the ladder) until a run of 5 unsolved steps, then falls to
    -0.2 for good. Keyed by the noise root and branches as :func:`walk_margins`."""
    n = cell.params.noise
    root = [n.key_seed, episode] if n.key_seed >= 0 else [seed, cell.index, episode]
    switches = dict(zip((int(s) for s in n.branch_after_steps), (int(b) for b in n.branch_ids), strict=True))
    branch, h, unsolved, run, fell = -1, np.empty(WALK_STEPS), np.zeros(WALK_STEPS, dtype=bool), 0, False
    for t in range(WALK_STEPS):
        if t - 1 in switches:
            branch = switches[t - 1]
        u, xi = np.random.default_rng([*root, branch + 1, t]).random(2)
        unsolved[t] = t >= 10 and u < (0.3 if run else 0.05)
        run = run + 1 if unsolved[t] else 0
        fell = fell or run >= 5
        h[t] = -0.2 if fell else 0.5 + 0.02 * xi
    return h, unsolved


def ladder(cell, episode_ids, seed, common_random_numbers, record):
    """Rows and trajectories (``q1_solved``, ``q2_solved`` included) of :func:`ladder_margins`."""
    out = synthetic_episodes.episodes(cell, episode_ids, seed, common_random_numbers, record)
    dt = cell.params.sim.control_period_s
    out.recordings = {}
    for r in out.rows:
        e = int(r["cell_episode"])
        h, unsolved = ladder_margins(cell, seed, e)
        solved = (~unsolved).astype(np.float64)
        _margin_episode(out, r, e, h, dt, e in record, q1_solved=solved, q2_solved=solved)
    return out


def scheduled(schedules_dir, cell, episode_ids, seed, common_random_numbers, record):
    """Rows whose margin is a deterministic function of each episode's stored error schedule (and veh_f's
    speed): veh_f measured far (front_x > 0) and away from the ego (front_y > 0) lowers it. The runner
    passes the run's schedule folder first (``reads_schedules``)."""
    from pathlib import Path  # noqa: PLC0415

    from mcverify.episode.schedule_file import read_schedule, schedule_path  # noqa: PLC0415

    out = synthetic_episodes.episodes(cell, episode_ids, seed, common_random_numbers, record)
    v = cell.params.scenario.front_speed_mps
    for r in out.rows:
        units = np.asarray(read_schedule(schedule_path(Path(schedules_dir), int(r["episode_id"]))).units)
        min_h = 0.35 + 0.05 * abs(v - 7.0) - 0.2 * units[:, 0].mean() - 0.2 * units[:, 1].mean()
        r.update({"min_h_front": float(min_h), "collision_front": False, "ellipse_violation": bool(min_h < 0),
                  "min_gap_front_m": 1.0, "safe": bool(min_h >= 0), "opposing_kind": "none",
                  "first_unsafe_s": 3.0 if min_h < 0 else math.nan,
                  "first_unsafe_cause": "planned" if min_h < 0 else ""})
    return out


scheduled.reads_schedules = True
