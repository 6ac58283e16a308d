"""The one-episode figure ``mcverify replay`` writes (drawing code: :mod:`mcverify.reporting.episode_figures`)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from mcverify.analysis import robustness
from mcverify.cell import Cell
from mcverify.reporting import episode_figures


def episode_figure(
    traj: Mapping[str, np.ndarray],
    cell: Cell,
    row: Mapping[str, Any],
    path: Path,
    plans: Mapping[str, np.ndarray] | None = None,
) -> Path:
    """Road panels to scale at a few labelled moments (and at the first unsafe one, with its cause),
    h_ef(t) against ε, and the speeds, for one episode (``traj``: sub-step columns as in
    ``trajectories/episode-NNNNNN.parquet``; ``plans``: its ``-plans.parquet`` columns, if stored;
    ``row``: its ``episodes.parquet`` row). Columns the trajectory lacks are left out of the drawing."""
    dist = row.get("min_dist_front_m", math.nan)
    h = row.get("min_h_front", math.nan)
    safety = "safe" if row.get("safe") else "UNSAFE"
    gap_opp = row.get("min_gap_opp_any_m", math.nan)
    opp = f" · min gap veh_o {gap_opp:.2f} m" if gap_opp is not None and math.isfinite(gap_opp) else ""
    title = (
        f"{cell.name} · episode {row.get('episode_id')} · {row.get('outcome')} · {safety} · "
        f"min dist. to ellipse {dist:.2f} m · min h_ef {h:.3f}{opp}"
    )
    # an episode ended at its first violation (falsify's stop_episodes) gets a panel at its end: the
    # violating step, which need not be a safety event (a Theorem 5 step); one that ran on gets a panel
    # at its first step without a plan (Theorem 5), if it had one, named in the title
    stop = float(np.asarray(traj["t_s"])[-1]) if row.get("stopped_at_violation") and len(traj["t_s"]) else None
    no_plan = None if stop is not None else theorem5_moment(traj, row, cell)
    if no_plan is not None:
        title += f" · {no_plan[1]} at {no_plan[0]:.2f} s"
    episode_figures.episode_overview(traj, cell.params, cell.epsilon, Path(path), title=title, plans=plans,
                                     moment=stop if no_plan is None else no_plan[0])
    return Path(path)


#: What the planner lacked at a step that broke Theorem 5, per requirement (the figure's title).
_NO_PLAN = {"theorem5_certified": "Q1 and Q2 certified infeasible", "theorem5": "neither Q1 nor Q2 solved"}


def theorem5_moment(traj: Mapping[str, np.ndarray], row: Mapping[str, Any], cell: Cell) -> tuple[float, str] | None:
    """When an episode first broke Theorem 5 (s) and how: its first step at which IPOPT certified both Q1 and
    Q2 infeasible, else its first step with neither solved; None if it kept the theorem (or its trajectory
    cannot say). A safety event gets its own panel anyway; this one shows the planner without any plan."""
    for name, what in _NO_PLAN.items():
        t_s = robustness.first_violation_s(row, traj, name, control_period_s=cell.params.sim.control_period_s)
        if math.isfinite(t_s):
            return t_s, what
    return None
