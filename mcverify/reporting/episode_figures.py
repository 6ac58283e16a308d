"""Episode-level figures, drawn from the stored trajectories of a run.

Inputs: ``trajectories/episode-NNNNNN.parquet`` (one row per integration sub-step) and
``...-plans.parquet`` (the Q1/Q2 plans at snapshot times). Road snapshots with the planned Q1
(green) and Q2 (orange) trajectories, the safety ellipse and the predicted opposing trajectory
(:func:`snapshots`), h(t) against its level (:func:`barrier_series`), speed profiles
(:func:`speed_profiles`) and the one-page view of one episode (:func:`episode_overview`). A missing
column is left out of the drawing; a missing file skips the figure (the report says so). Sizes and
saving: :mod:`mcverify.reporting.figure_common`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Ellipse, Polygon  # noqa: E402

from mcverify.reporting.figure_common import column, inches, panel_grid, params_dict, save  # noqa: E402

EGO, FRONT, OPP = "tab:green", "tab:red", "tab:blue"
Q1_COLOUR, Q2_COLOUR = "tab:green", "tab:orange"
#: Background colour per ``active_problem`` code (decision.Source): Q1, Q2, fallback, held MPC-DC plan.
_PROBLEM_COLOURS = {1: Q1_COLOUR, 2: Q2_COLOUR, 3: "tab:red", 4: "tab:purple"}

Trajectory = Mapping[str, np.ndarray]


def _box(ax: plt.Axes, x: float, y: float, psi: float, p: Mapping[str, Any], colour: str, **kw) -> None:
    half_l, half_w = 0.5 * p["geometry"]["length_m"], 0.5 * p["geometry"]["width_m"]
    local = np.array([[half_l, -half_w], [half_l, half_w], [-half_l, half_w], [-half_l, -half_w]])
    c, s = math.cos(psi), math.sin(psi)
    corners = np.column_stack([x + local[:, 0] * c - local[:, 1] * s, y + local[:, 0] * s + local[:, 1] * c])
    ax.add_patch(Polygon(corners, closed=True, color=colour, alpha=kw.pop("alpha", 0.6), lw=0, **kw))


def _road(ax: plt.Axes, p: Mapping[str, Any]) -> None:
    lane = p["road"]["lane_width_m"]
    ax.axhspan(-lane / 2, lane / 2, color="0.93", zorder=0)
    ax.axhspan(lane / 2, 1.5 * lane, color="0.85", zorder=0)
    ax.axhline(lane / 2, color="white", ls=(0, (6, 6)), lw=1.5, zorder=0)
    ax.set_ylim(-lane / 2 - 0.3, 1.5 * lane + 0.3)


def _index_at(t: np.ndarray, when: float) -> int:
    return int(np.clip(np.searchsorted(t, when, side="right") - 1, 0, len(t) - 1))


def snapshot_times(traj: Trajectory, plans: Mapping[str, np.ndarray] | None, n: int = 5) -> list[float]:
    """Up to ``n`` snapshot times, evenly spread: over the stored plan times when plans exist
    (every snapshot then shows its plans), else over the trajectory."""
    if plans is not None and column(plans, "t_s") is not None:
        times = np.unique(column(plans, "t_s")[np.isfinite(column(plans, "t_s"))])
    else:
        times = np.asarray(traj["t_s"], dtype=float)
    if times.size == 0:
        return []
    pick = np.unique(np.linspace(0, times.size - 1, min(n, times.size)).round().astype(int))
    return [float(times[i]) for i in pick]


def snapshots(
    traj: Trajectory,
    plans: Mapping[str, np.ndarray] | None,
    params: Mapping[str, Any],
    path: Path,
    *,
    title: str,
    n_snapshots: int = 5,
) -> dict[str, int]:
    """Road snapshots stacked top to bottom (the paper's Figs. 5-7): the ego (green), the front
    vehicle (red) with its safety ellipse h_ef = 0 (dashed), the opposing vehicle (blue) when there
    is one, the ego's path so far (black), and at each snapshot the planned Q1 (green dots) and Q2
    (orange dots) trajectories and the predicted opposing trajectory (blue dots)."""
    p = params_dict(params)
    t = np.asarray(traj["t_s"], dtype=float)
    times = snapshot_times(traj, plans, n_snapshots)
    ego_x, ego_y = np.asarray(traj["ego_x_m"], float), np.asarray(traj["ego_y_m"], float)
    psi = column(traj, "ego_psi_rad")
    front_x = np.asarray(traj["front_x_m"], float)
    front_y = column(traj, "front_y_m")
    opp_x, opp_y = column(traj, "opp_x_m"), column(traj, "opp_y_m")
    a_m, b_m = p["barrier"]["ellipse_a_m"], p["barrier"]["ellipse_b_m"]
    lane = p["road"]["lane_width_m"]
    plan_t = column(plans, "t_s") if plans is not None else None

    # one window width for every panel: the ego, the ellipse and the plans of the widest snapshot
    lefts, spans = [], []
    for when in times:
        k = _index_at(t, when)
        left = min(ego_x[k], front_x[k] - a_m) - 8.0
        right = max(front_x[k] + a_m, ego_x[k])
        if plan_t is not None:
            sel = (plan_t == when) & np.isfinite(plans["x_m"].astype(float))
            if sel.any():
                right = max(right, float(np.max(plans["x_m"][sel].astype(float))))
        lefts.append(left)
        spans.append(right - left)
    width = float(np.clip(max(spans, default=60.0) + 12.0, 60.0, 240.0))
    header_in, panel_h = 0.75, 12.0 * (2 * lane + 0.6) / width + 0.42
    height = panel_h * len(times) + header_in + 0.45
    fig, axes = plt.subplots(len(times), 1, figsize=inches(12, height), squeeze=False)
    fig.subplots_adjust(left=0.05, right=0.99, top=1 - header_in / height, bottom=0.45 / height, hspace=0.35)
    for ax, when, x0 in zip(axes[:, 0], times, lefts, strict=True):
        k = _index_at(t, when)
        _road(ax, p)
        ax.set_xlim(x0, x0 + width)
        ax.plot(ego_x[: k + 1], ego_y[: k + 1], color="black", lw=1.2, zorder=3)
        fy = float(front_y[k]) if front_y is not None else 0.0
        ax.add_patch(Ellipse((front_x[k], fy), 2 * a_m, 2 * b_m, fill=False, ls="--", lw=1, color=FRONT, zorder=2))
        _box(ax, front_x[k], fy, 0.0, p, FRONT, zorder=4)
        _box(ax, ego_x[k], ego_y[k], float(psi[k]) if psi is not None else 0.0, p, EGO, zorder=5)
        if opp_x is not None and np.isfinite(opp_x[k]):
            oy = float(opp_y[k]) if opp_y is not None and np.isfinite(opp_y[k]) else lane
            _box(ax, opp_x[k], oy, math.pi, p, OPP, zorder=4)
            if opp_x[k] > x0 + width:  # beyond the window: say where it is
                ax.text(0.995, 0.9, f"veh_o at x = {opp_x[k]:.0f} m →", transform=ax.transAxes, ha="right",
                        va="top", fontsize=7, color=OPP)
        if plan_t is not None:
            problems = plans.get("problem")
            for name, colour in (("Q1", Q1_COLOUR), ("Q2", Q2_COLOUR)):
                sel = plan_t == when
                if problems is not None:
                    sel &= problems == name
                if sel.any():
                    ax.plot(plans["x_m"][sel].astype(float), plans["y_m"][sel].astype(float), ".", ms=3,
                            color=colour, alpha=0.75, zorder=6)
                    opp_plan = plans.get("opp_x_m")
                    if name == "Q1" and opp_plan is not None and np.isfinite(opp_plan[sel].astype(float)).any():
                        ax.plot(opp_plan[sel].astype(float), np.full(int(sel.sum()), lane), ".", ms=3, color=OPP,
                                alpha=0.6, zorder=6)
        ax.set_aspect("equal", adjustable="box")
        ax.text(0.005, 0.92, f"t = {when:.2f} s", transform=ax.transAxes, fontsize=8, va="top")
        ax.tick_params(labelsize=7)
        ax.set_yticks([0.0, lane])
    axes[-1, 0].set_xlabel("x (m)")
    handles = [
        plt.Line2D([], [], color=EGO, lw=6, alpha=0.6, label="ego"),
        plt.Line2D([], [], color=FRONT, lw=6, alpha=0.6, label="front vehicle"),
        plt.Line2D([], [], color=FRONT, ls="--", label="safety ellipse h_ef = 0"),
        plt.Line2D([], [], color="black", label="ego path"),
    ]
    if opp_x is not None:
        handles.append(plt.Line2D([], [], color=OPP, lw=6, alpha=0.6, label="opposing vehicle"))
    if plan_t is not None:
        handles += [
            plt.Line2D([], [], color=Q1_COLOUR, marker=".", ls="", label="Q1 plan (overtake)"),
            plt.Line2D([], [], color=Q2_COLOUR, marker=".", ls="", label="Q2 plan (go back)"),
        ]
        if plans.get("opp_x_m") is not None and column(plans, "opp_x_m") is not None:
            handles.append(plt.Line2D([], [], color=OPP, marker=".", ls="", label="predicted opposing"))
    fig.text(0.5, 1 - 0.12 / height, title, ha="center", va="top", fontsize=9)
    fig.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, 1 - 0.32 / height), ncol=len(handles),
               fontsize=7, frameon=False)
    return save(fig, path)


def _shade_problems(ax: plt.Axes, t: np.ndarray, problem: np.ndarray | None) -> None:
    """Background colour per active problem: Q1 green, Q2 orange, fallback red, held plan purple."""
    if problem is None or len(t) == 0:
        return
    start = 0
    for i in range(1, len(t) + 1):
        if i == len(t) or problem[i] != problem[start]:
            colour = _PROBLEM_COLOURS.get(int(problem[start])) if np.isfinite(problem[start]) else None
            if colour:
                ax.axvspan(t[start], t[i - 1], color=colour, alpha=0.08, lw=0)
            start = i


def barrier_panel(
    ax: plt.Axes, traj: Trajectory, level: float, *, opp: bool = False, clip: float | None = None
) -> None:
    """h_ef(t) (or h_eo(t) with ``opp``) along the true trajectory against its level and 0."""
    t = np.asarray(traj["t_s"], dtype=float)
    h = column(traj, "h_opp" if opp else "h_front")
    if h is None:
        ax.text(0.5, 0.5, "no values", transform=ax.transAxes, ha="center", va="center")
        return
    name = "h_eo (m)" if opp else "h_ef"
    ax.plot(t, h, color="black", lw=1.1, label=f"{name}, true state")
    ax.axhline(level, color="tab:blue", ls="--", lw=1, label=f"level {'ε_eo' if opp else 'ε'} = {level:.3g}")
    ax.axhline(0.0, color="tab:red", ls=":", lw=1, label="h = 0 (boundary)")
    finite = h[np.isfinite(h)]
    top = clip if clip is not None else float(finite.max())
    ax.set_ylim(min(-0.1 * max(level, 1e-3), float(finite.min())) - 0.05 * max(abs(top), 1.0), top)
    _shade_problems(ax, t, column(traj, "active_problem"))
    ax.set_xlabel("time (s)", fontsize=8)
    ax.set_ylabel(name + (" (clipped)" if clip is not None and finite.max() > clip else ""), fontsize=8)
    ax.tick_params(labelsize=7)


def speed_panel(ax: plt.Axes, traj: Trajectory, speed_limit_mps: float | None) -> None:
    """Speeds of the ego, front and opposing vehicles (those stored), the measured front speed
    (what the planner saw) faintly, and the ego speed limit."""
    t = np.asarray(traj["t_s"], dtype=float)
    for name, colour, label, kw in (
        ("ego_speed_mps", EGO, "ego", {}),
        ("front_speed_mps", FRONT, "front", {}),
        ("meas_front_speed_mps", FRONT, "front (measured)", {"alpha": 0.3, "lw": 0.7}),
        ("opp_speed_mps", OPP, "opposing", {}),
    ):
        v = column(traj, name)
        if v is not None:
            ax.plot(t, v, color=colour, label=label, **({"lw": 1.2} | kw))
    if speed_limit_mps is not None:
        ax.axhline(speed_limit_mps, color="grey", ls=":", lw=1, label="ego speed limit")
    ax.set_xlabel("time (s)", fontsize=8)
    ax.set_ylabel("speed (m/s)", fontsize=8)
    ax.tick_params(labelsize=7)


def _barrier_clip(level: float) -> float:
    return max(6.0 * level, 2.0)


def barrier_series(
    episodes: Sequence[tuple[str, Trajectory, float]], path: Path, *, opp: bool = False
) -> dict[str, int]:
    """One panel per ``(title, trajectory, level)``: h_ef(t) (``opp``: h_eo(t), m) against its
    level, the active problem shaded (Q1 green, Q2 orange, fallback red, held MPC-DC plan purple)."""
    fig, axes = panel_grid(len(episodes), 2, 6.0, 2.6)
    for ax, (title, traj, level) in zip(axes, episodes, strict=True):
        barrier_panel(ax, traj, level, opp=opp, clip=None if opp else _barrier_clip(level))
        ax.set_title(title, fontsize=8)
    if axes[0].lines:
        axes[0].legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    return save(fig, path)


def speed_profiles(episodes: Sequence[tuple[str, Trajectory, float]], path: Path) -> dict[str, int]:
    """One panel per ``(title, trajectory, ego speed limit)``: the speed profiles."""
    fig, axes = panel_grid(len(episodes), 2, 6.0, 2.6)
    for ax, (title, traj, limit) in zip(axes, episodes, strict=True):
        speed_panel(ax, traj, limit)
        ax.set_title(title, fontsize=8)
    axes[0].legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    return save(fig, path)


def episode_overview(
    traj: Trajectory,
    params: Any,
    level: float,
    path: Path,
    *,
    title: str,
) -> dict[str, int]:
    """One episode on one page: the whole road view with six snapshots of the vehicles and the
    ellipse, h_ef(t) against ε, and the speeds (the figure ``mcverify replay`` writes)."""
    p = params_dict(params)
    fig, axes = plt.subplots(3, 1, figsize=inches(11, 9), gridspec_kw={"height_ratios": [1.3, 1, 1]})
    ax = axes[0]
    _road(ax, p)
    t = np.asarray(traj["t_s"], dtype=float)
    ego_x, ego_y = np.asarray(traj["ego_x_m"], float), np.asarray(traj["ego_y_m"], float)
    front_x = np.asarray(traj["front_x_m"], float)
    front_y = column(traj, "front_y_m")
    psi = column(traj, "ego_psi_rad")
    opp_x = column(traj, "opp_x_m")
    a_m, b_m = p["barrier"]["ellipse_a_m"], p["barrier"]["ellipse_b_m"]
    for k in np.unique(np.linspace(0, len(t) - 1, 6).astype(int)):
        fy = float(front_y[k]) if front_y is not None else 0.0
        ax.add_patch(Ellipse((front_x[k], fy), 2 * a_m, 2 * b_m, fill=False, ls="--", lw=0.8, color=FRONT))
        _box(ax, front_x[k], fy, 0.0, p, FRONT, alpha=0.5)
        _box(ax, ego_x[k], ego_y[k], float(psi[k]) if psi is not None else 0.0, p, EGO, alpha=0.5)
        if opp_x is not None and np.isfinite(opp_x[k]):
            _box(ax, opp_x[k], p["road"]["lane_width_m"], math.pi, p, OPP, alpha=0.5)
        ax.annotate(f"{t[k]:.1f}s", (ego_x[k], ego_y[k] + 1.3), fontsize=7, ha="center")
    ax.plot(ego_x, ego_y, color="black", lw=1.2, label="ego path")
    xs = np.concatenate([ego_x, front_x])
    ax.set_xlim(float(np.min(xs)) - 10, float(np.max(xs)) + 10)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="upper left", fontsize=8)
    barrier_panel(axes[1], traj, level, clip=_barrier_clip(level))
    axes[1].legend(loc="upper right", fontsize=8)
    speed_panel(axes[2], traj, p["ego"]["speed_max_mps"])
    axes[2].legend(loc="lower right", fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return save(fig, path)
