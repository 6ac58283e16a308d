"""Synthetic run folders for the report tests: a real manifest from a campaign dict, and
``episodes.parquet`` / trajectory files that follow the data contracts, drawn from known
probabilities instead of simulated (no solver, milliseconds)."""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from mcverify import files, schema, store
from mcverify.campaign import runner
from mcverify.campaign.spec import campaign_from_dict
from mcverify.cell import Cell
from mcverify.episode.row import identity

#: Probabilities of a synthetic cell: P(unsafe), P(overtook | not error), P(went back), P(error).
Probs = dict[str, float]


def default_probs(cell: Cell) -> Probs:
    return {"unsafe": 0.0, "overtook": 0.8, "went_back": 0.15, "error": 0.0}


def episode_rows(cell: Cell, seed: int, probs: Probs, *, opposing: bool, crn: bool) -> list[dict[str, Any]]:
    """One row per episode with every column of the episodes.parquet contract."""
    rows = []
    for e in range(cell.episodes):
        # like the real runner: keys from (seed, cell-free episode id) under common random numbers
        rng = np.random.default_rng([seed, e] if crn else [seed, cell.index, e])
        u = rng.random(6)
        error = u[0] < probs.get("error", 0.0)
        unsafe = (not error) and u[1] < probs["unsafe"]
        if error:
            outcome = "error"
        elif u[2] < probs["overtook"]:
            outcome = "overtook"
        elif u[2] < probs["overtook"] + probs["went_back"]:
            outcome = "went_back"
        else:
            outcome = "timeout"
        min_dist = (-0.3 if unsafe else 0.2) + 1.2 * u[3]
        min_h = ((1.0 + min_dist / 6.9) ** 2 - 1.0) if min_dist > -6.9 else -1.0
        collision = bool(unsafe and u[4] < 0.3)
        row: dict[str, Any] = {
            **identity(cell, seed, e),
            "sample_front_accel_mps2": float(1.0 + 2.0 * u[5]),
            "outcome": outcome,
            "overtook": outcome == "overtook",
            "went_back": outcome == "went_back",
            "timeout": outcome == "timeout",
            "end_time_s": math.nan if error else 8.0 + 4.0 * u[4],
            "overtake_time_s": 5.0 + 1.5 * u[4] if outcome == "overtook" else math.nan,
            "lane_borrow_time_s": 4.0 + u[5] if outcome in ("overtook", "went_back") else math.nan,
            "collision_front": collision,
            "min_h_front": math.nan if error else min_h,
            "min_dist_front_m": math.nan if error else min_dist,
            "min_gap_front_m": math.nan if error else min_dist + 0.5,
            "ellipse_violation": bool(unsafe),
            "safe": not unsafe and not error,
            "h0_front": 60.0,
            "epsilon": cell.epsilon,
            "lambda0": cell.lambda0,
            "invariance_breach": bool(min_h < cell.epsilon) if not error else False,
            "invariance_margin": min_h - cell.epsilon if not error else math.nan,
            "steps": 400,
            "q1_fail_steps": int(10 * u[5]),
            "q2_fail_steps": int(3 * u[4]),
            "both_infeasible_steps": int(unsafe),
            "both_certified_infeasible_steps": int(unsafe and u[4] < 0.5),
            "both_unsolved_uncertified_steps": int(unsafe and u[4] >= 0.5),
            "both_infeasible_longest_run": int(unsafe),
            "q1_fail_certified_steps": int(10 * u[5]) // 2,
            "q1_fail_presumed_steps": 0,
            "q1_fail_iteration_limit_steps": int(10 * u[5]) - int(10 * u[5]) // 2,
            "q1_fail_other_steps": 0,
            "q1_held_steps": 0,
            "went_back_q1_failure": "iteration_limit" if outcome == "went_back" else "",
            "fallback_steps": int(unsafe),
            "q2_driven_steps": 30 if outcome == "went_back" else 0,
            "switched_to_q2_at_s": 3.0 if outcome == "went_back" else math.nan,
            "solves": 800,
            "iterations_mean": 25.0 + u[4],
            "iterations_max": 90,
            "solve_time_mean_s": 0.03,
            "solve_time_max_s": 0.2,
            "solver_statuses": json.dumps({"Infeasible_Problem_Detected": int(10 * u[5]), "Solve_Succeeded": 790}),
            "first_unsafe_s": 4.0 + u[4] if unsafe else math.nan,
            "first_unsafe_cause": ("planned" if u[4] < 0.5 else "held") if unsafe else "",
            "held_steps": int(unsafe and u[4] >= 0.5) * 5,
            "q1_rescue_steps": 0,
            "went_back_reason": "q1_not_solved" if outcome == "went_back" else "",
            "table_one_rows": json.dumps({"1": 300, "2": 100}),
            "cold_retries": int(3 * u[5]),
        }
        if opposing:
            borrowed = outcome in ("overtook", "went_back")
            row |= {
                "controller": cell.controller,
                "opposing_kind": "human",
                "collision_opp": bool(unsafe and not collision),
                "min_gap_opp_m": (5.0 + 80.0 * u[3]) if borrowed else math.nan,
                "min_gap_opp_any_m": 3.0 + 80.0 * u[3],
                "opp_invariance_breach": bool(borrowed and u[3] < 0.05),
                "min_h_opp": (3.0 + 50.0 * u[3]) if borrowed else math.nan,
            }
        rows.append(row)
    return rows


def trajectory(n: int = 400, *, opposing: bool = True, went_back: bool = False) -> dict[str, np.ndarray]:
    """A plausible overtake (or an abandoned one): sub-step columns of the trajectory contract."""
    t = np.linspace(0.0, 9.0, n)
    ego_x = 10.0 + 10.0 * t + 0.45 * t**2
    front_x = 64.0 + 7.0 * t
    bump = np.exp(-(((ego_x - front_x) / 12.0) ** 2))
    ego_y = 3.5 * bump * (0.5 if went_back else 1.0)
    if went_back:
        ego_x = np.minimum(ego_x, front_x - 5.0)
    d = np.hypot((ego_x - front_x) / 6.9, ego_y / 2.6)
    out = {
        "t_s": t, "ego_x_m": ego_x, "ego_y_m": ego_y, "ego_psi_rad": np.gradient(ego_y, ego_x) * 0.8,
        "ego_speed_mps": 10.0 + 0.9 * t, "front_x_m": front_x, "front_y_m": np.zeros(n),
        "front_speed_mps": np.full(n, 7.0),
        "opp_x_m": 300.0 - 12.0 * t if opposing else np.full(n, np.nan),
        "opp_y_m": np.full(n, 3.5 if opposing else np.nan),
        "opp_speed_mps": np.full(n, 12.0 if opposing else np.nan),
        "alpha_mps2": np.full(n, 0.9), "beta_rad": np.zeros(n), "h_front": d**2 - 1.0,
        "dist_front_m": d - 1.0, "gap_front_m": d - 0.5,
        "h_opp": np.where(ego_y > 1.75, 200.0 - 20.0 * t, np.nan) if opposing else np.full(n, np.nan),
        "gap_opp_m": np.where(ego_y > 1.75, 250.0 - 20 * t, np.nan) if opposing else np.full(n, np.nan),
        "active_problem": np.where(t < 4.0, 1, 2).astype(np.int8), "mode": np.zeros(n, dtype=np.int64),
    }
    return out


def plans(traj: Mapping[str, np.ndarray], *, opposing: bool = True, nodes: int = 50) -> dict[str, np.ndarray]:
    """Q1 and Q2 plans of 50 nodes at five snapshot times."""
    cols: dict[str, list] = {k: [] for k in ("t_s", "problem", "node", "t_node_s", "x_m", "y_m", "speed_mps",
                                             "opp_x_m")}
    for when in np.linspace(0.0, 8.0, 5):
        k = int(np.searchsorted(traj["t_s"], when))
        x0, fx = float(traj["ego_x_m"][k]), float(traj["front_x_m"][k])
        for problem, goal, lateral in (("Q1", fx + 15.0, 3.5), ("Q2", fx - 15.0, 0.8)):
            s = np.linspace(0.0, 1.0, nodes)
            cols["t_s"] += [float(when)] * nodes
            cols["problem"] += [problem] * nodes
            cols["node"] += list(range(nodes))
            cols["t_node_s"] += list(when + 6.0 * s)
            cols["x_m"] += list(x0 + (goal - x0) * s)
            cols["y_m"] += list(lateral * np.sin(np.pi * s))
            cols["speed_mps"] += list(10.0 + 5 * s)
            cols["opp_x_m"] += list(300.0 - 12.0 * (when + 6.0 * s)) if opposing else [math.nan] * nodes
    return {k: np.asarray(v) for k, v in cols.items()}


def make_run(
    run_dir: Path,
    raw: Mapping[str, Any],
    *,
    probs: Callable[[Cell], Probs] = default_probs,
    opposing: bool = False,
    trajectories: bool = True,
    plans_files: bool = True,
    trajectory_cells: tuple[int, ...] | None = None,
    seed: int | None = None,
) -> Path:
    """Write a synthetic run folder: manifest.json (as the runner writes it), episodes.parquet and,
    with ``trajectories``, the first episode of every cell (or of ``trajectory_cells``) under
    trajectories/."""
    camp = campaign_from_dict(raw, seed=seed)
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    files.write_json_atomic(run_dir / store.MANIFEST, runner.manifest_for(camp, 8, {}))
    rows = []
    for cell in camp.cells:
        rows += episode_rows(cell, camp.seed, probs(cell), opposing=opposing, crn=camp.common_random_numbers)
    pq.write_table(pa.Table.from_pylist(rows, schema=schema.arrow_schema(rows[0])), run_dir / store.EPISODES)
    if trajectories:
        (run_dir / "trajectories").mkdir(exist_ok=True)
        for cell in camp.cells:
            if trajectory_cells is not None and cell.index not in trajectory_cells:
                continue
            traj = trajectory(opposing=opposing, went_back=cell.index % 2 == 1)
            stem = run_dir / "trajectories" / f"episode-{cell.episode_offset:06d}"
            pq.write_table(pa.table(traj), f"{stem}.parquet")
            if plans_files:
                pq.write_table(pa.table(plans(traj, opposing=opposing)), f"{stem}-plans.parquet")
    return run_dir


TABLE3 = {
    "campaign": {"name": "t3", "seed": 3, "episodes": 30},
    "model": {"opposing": {"kind": "autonomous"}},
    "grid": {"scenario.front_accel_range_mps2": [[1, 3], [3, 5], [5, 7]]},
    "reference": {
        "table": "III",
        "source": "Yuan et al., Table III",
        "cells": {
            "front_accel_range_mps2=[1,3]": {"overtook.k": 29, "min_dist_front_m.min": 1.27,
                                             "min_gap_opp_m.min": 18.31, "safe.k": 30},
            "front_accel_range_mps2=[3,5]": {"overtook.k": 11, "min_dist_front_m.min": 1.24,
                                             "min_gap_opp_m.min": 5.52, "safe.k": 30},
            "front_accel_range_mps2=[5,7]": {"overtook.k": 0, "min_dist_front_m.min": 1.31,
                                             "min_gap_opp_m.min": 72.41, "safe.k": 30},
        },
    },
}

TABLE4 = {
    "campaign": {"name": "t4", "seed": 4, "episodes": 30, "common_random_numbers": True},
    "model": {"opposing": {"kind": "human"}},
    "axes": {
        "scenario": {"A": {"scenario.front_speed_kmh": 30}, "B": {"scenario.front_speed_kmh": 25}},
        "method": {
            "MPC-DC": {"mpc.controller": "mpcdc"},
            "VL-CBF eps=0.3": {"barrier.epsilon": 0.3},
            "VL-CBF eps=0.5": {"barrier.epsilon": 0.5},
        },
    },
    "reference": {
        "table": "IV",
        "cells": {
            "scenario=A,method=MPC-DC": {"min_dist_front_m.min": -0.15, "min_gap_opp_m.min": 0.31, "safe.k": 0},
            "scenario=A,method=VL-CBF eps=0.3": {"min_dist_front_m.min": 0.76, "min_gap_opp_m.min": 85.66,
                                                  "safe.k": 30},
            "scenario=A,method=VL-CBF eps=0.5": {"min_dist_front_m.min": 0.99, "min_gap_opp_m.min": 86.07,
                                                  "safe.k": 30},
            "scenario=B,method=MPC-DC": {"min_dist_front_m.min": 0.37, "min_gap_opp_m.min": 36.46, "safe.k": 19},
            "scenario=B,method=VL-CBF eps=0.3": {"min_dist_front_m.min": 0.77, "min_gap_opp_m.min": 42.51,
                                                  "safe.k": 30},
            "scenario=B,method=VL-CBF eps=0.5": {"min_dist_front_m.min": 1.02, "min_gap_opp_m.min": 41.55,
                                                  "safe.k": 30},
        },
    },
}

EPS_SWEEP = {
    "campaign": {"name": "eps", "seed": 5, "episodes": 40},
    "axes": {"noise": {"paper": {"noise.scale": 1.0}, "3x paper": {"noise.scale": 3.0}}},
    "grid": {"barrier.epsilon": [0.0, 0.1, 0.2, 0.3, 0.5]},
}

LAMBDA0_GRID = {
    "campaign": {"name": "l0", "seed": 6, "episodes": 30},
    "grid": {"barrier.lambda0": [-0.05, -0.3135, -0.8],
             "scenario.front_accel_range_mps2": [[1, 3], [3, 5], [5, 7]]},
}


def eps_probs(cell: Cell) -> Probs:
    """Violations fall with ε and rise with the noise: p = 0.3 (1 - ε/0.5)^2 x noise scale / 3."""
    scale = cell.params.noise.scale
    return {"unsafe": 0.3 * (1 - cell.epsilon / 0.5) ** 2 * scale / 3, "overtook": 0.7, "went_back": 0.25}
