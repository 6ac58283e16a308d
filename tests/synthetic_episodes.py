"""Cheap, deterministic stand-ins for the closed-loop simulation, injected through the executors'
episode-function interface (``fn(cell, episode_ids, seed, common_random_numbers, record)``).

They exercise the real executors, scheduler, store and runner without hours of IPOPT: each row has
the columns of a real episode row, with values drawn from (seed, cell, episode id) only, so any
mix-up of episodes, repeats or losses shows up. Failure injection (an exception, a worker killed
by SIGKILL, a NaN metric, a failure only on the first try) is keyed by global episode id.
Module-level functions (and ``functools.partial`` of them) so that spawned workers can unpickle them.
"""

from __future__ import annotations

import json
import os
import signal
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mcverify.campaign.work import episode_done
from mcverify.episode.recording import EpisodeRecording
from mcverify.episode.row import identity


@dataclass
class Result:
    rows: list[dict]
    recordings: dict[int, EpisodeRecording] = field(default_factory=dict)


def row(cell, seed: int, episode: int, common_random_numbers: bool = False) -> dict:
    """One synthetic episode row: a subset of the declared columns (:mod:`mcverify.schema`) with the
    types of :func:`mcverify.episode.row.episode_row`'s."""
    rng = np.random.default_rng([seed, 0 if common_random_numbers else cell.index + 1, episode])
    u = rng.random(12)
    outcome = ("overtook", "went_back", "timeout")[int(u[0] * 3)]
    min_h = float(u[1] * 2.0 - 0.1)
    return {
        **identity(cell, seed, episode),
        "sample_front_accel_mps2": float(u[2]),
        "outcome": outcome,
        "overtook": outcome == "overtook",
        "went_back": outcome == "went_back",
        "timeout": outcome == "timeout",
        "end_time_s": float(5 + 5 * u[3]),
        "overtake_time_s": float(5 + 5 * u[3]) if outcome == "overtook" else float("nan"),
        "lane_borrow_time_s": float(4 * u[4]),
        "collision_front": bool(u[5] < 0.01),
        "min_h_front": min_h,
        "min_dist_front_m": float(u[6]),
        "min_gap_front_m": float(u[7] + 0.5),
        "ellipse_violation": min_h < 0,
        "safe": min_h >= 0 and not bool(u[5] < 0.01),
        "h0_front": 6.4,
        "epsilon": cell.epsilon,
        "lambda0": cell.lambda0,
        "invariance_breach": min_h < cell.epsilon,
        "invariance_margin": min_h - cell.epsilon,
        "steps": int(50 + 100 * u[8]),
        "q1_fail_steps": int(3 * u[9]),
        "q2_fail_steps": int(3 * u[10]),
        "both_infeasible_steps": 0,
        "fallback_steps": 0,
        "q2_driven_steps": int(10 * u[11]),
        "switched_to_q2_at_s": float("nan"),
        "solves": 200,
        "iterations_mean": float(20 + u[8]),
        "iterations_max": 60,
        "solve_time_mean_s": float(u[9]) * 1e-3,  # machine-dependent in real runs
        "solve_time_max_s": float(u[10]) * 1e-2,
        "solver_statuses": json.dumps({"Solve_Succeeded": 200}),
    }


def episodes(cell, episode_ids, seed, common_random_numbers, record) -> Result:
    """Synthetic episodes; a small trajectory (no plans) for each id in ``record``."""
    rows = [row(cell, seed, int(e), common_random_numbers) for e in episode_ids]
    for r in rows:  # as the real rollout does when each episode stops (per-episode progress)
        episode_done(r["cell_episode"], not r["safe"])
    recordings = {
        int(e): EpisodeRecording({"t_s": np.arange(5) * 0.1, "ego_x_m": 10 + np.arange(5.0)})
        for e in episode_ids if e in record
    }
    return Result(rows, recordings)


def faulty(
    cell,
    episode_ids,
    seed,
    common_random_numbers,
    record,
    *,
    raise_on: tuple[int, ...] = (),
    kill_on: tuple[int, ...] = (),
    nan_on: tuple[int, ...] = (),
    once_dir: str | None = None,
    once_on: tuple[int, ...] = (),
    log_dir: str | None = None,
) -> Result:
    """Synthetic episodes with injected failures (global episode ids):

    raise_on: raise RuntimeError every time; kill_on: SIGKILL the worker process every time;
    nan_on: return a NaN min_h_front; once_on: raise the first time only (a marker file in
    ``once_dir`` remembers, across processes); log_dir: one file per call, named by the ids run.
    """
    ids = [cell.episode_offset + int(e) for e in episode_ids]
    if log_dir is not None:
        Path(log_dir, f"call-{os.getpid()}-{'-'.join(map(str, ids))}-{os.urandom(4).hex()}").touch()
    for gid in ids:
        if gid in kill_on:
            os.kill(os.getpid(), signal.SIGKILL)
        if gid in raise_on:
            raise RuntimeError(f"injected failure in episode {gid}")
        if gid in once_on and once_dir is not None:
            marker = Path(once_dir, f"failed-once-{gid}")
            if not marker.exists():
                marker.touch()
                raise MemoryError(f"transient failure in episode {gid}")
    result = episodes(cell, episode_ids, seed, common_random_numbers, record)
    for r in result.rows:
        if r["episode_id"] in nan_on:
            r["min_h_front"] = float("nan")
    return result


def bernoulli(cell, episode_ids, seed, common_random_numbers, record, *, p: float = 0.2) -> Result:
    """Synthetic episodes whose ``collision_front`` is a Bernoulli(p) draw from (seed, cell, episode)
    alone (the other columns as in :func:`row`); for the estimators' tests."""
    result = episodes(cell, episode_ids, seed, common_random_numbers, record)
    for r in result.rows:
        u = np.random.default_rng([seed, 7919, cell.index, int(r["cell_episode"])]).random()
        r["collision_front"] = bool(u < p)
        r["safe"] = r["safe"] and not r["collision_front"]
    return result
