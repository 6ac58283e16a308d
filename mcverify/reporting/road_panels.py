"""Road panels: one moment of an episode drawn to scale (metres are metres).

:func:`road_panel` draws, on equal axes, the two lanes, each vehicle as its true footprint (a
rectangle of the model's ``geometry.length_m`` x ``geometry.width_m`` at its position and heading)
with its name written on it, veh_f where the planner measured it (a dotted outline), the safety
ellipse h_ef = 0 around veh_f, the ego's path so far, the
latest Q1/Q2 plans solved by then and veh_o's predicted positions, the time, and, on the panel of
the first unsafe moment (:mod:`mcverify.reporting.unsafe_event`), a red frame, a marker and the
cause. :func:`windows` gives every panel of a figure the same width (one scale for all of them);
:func:`legend_handles` one legend entry per thing drawn. Used by the run's snapshots and by the
replay figure (:mod:`mcverify.reporting.episode_figures`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.lines import Line2D
from matplotlib.patches import Ellipse, Polygon

from mcverify.reporting.figure_common import column
from mcverify.reporting.unsafe_event import UnsafeEvent

EGO, FRONT, OPP = "tab:green", "tab:red", "tab:blue"
Q1_COLOUR, Q2_COLOUR = "tab:green", "tab:orange"
UNSAFE = "crimson"
#: A veh_o beyond this x (m) is parked: absent, or not spawned yet (as ``sim.plant`` places it).
PARKED_BEYOND_X_M = 5.0e5
#: Metres of road shown behind the rearmost of the ego and the ellipse, and ahead of the rest.
_BEHIND_M, _AHEAD_M = 8.0, 12.0
#: Width of every panel's window (m): at least, at most.
_MIN_WIDTH_M, _MAX_WIDTH_M = 60.0, 240.0

Trajectory = Mapping[str, np.ndarray]


def index_at(t: np.ndarray, when: float) -> int:
    """The last sub-step at or before ``when`` (the first one if ``when`` precedes it)."""
    return int(np.clip(np.searchsorted(t, when, side="right") - 1, 0, len(t) - 1))


def box(ax: Axes, x: float, y: float, psi: float, p: Mapping[str, Any], colour: str, *, name: str = "",
        alpha: float = 0.65, zorder: int = 4, outline: bool = False) -> None:
    """The vehicle's footprint: a ``length_m`` x ``width_m`` rectangle centred at (x, y) (m),
    turned by ``psi`` (rad), with ``name`` written on it; ``outline``: a dotted outline only (where
    the planner measured the vehicle)."""
    half_l, half_w = 0.5 * p["geometry"]["length_m"], 0.5 * p["geometry"]["width_m"]
    local = np.array([[half_l, -half_w], [half_l, half_w], [-half_l, half_w], [-half_l, -half_w]])
    c, s = math.cos(psi), math.sin(psi)
    corners = np.column_stack([x + local[:, 0] * c - local[:, 1] * s, y + local[:, 0] * s + local[:, 1] * c])
    if outline:
        ax.add_patch(Polygon(corners, closed=True, fill=False, edgecolor=colour, lw=0.9, ls=":", zorder=zorder))
        return
    ax.add_patch(Polygon(corners, closed=True, facecolor=colour, edgecolor="black", lw=0.4, alpha=alpha,
                         zorder=zorder))
    if name:
        ax.text(x, y, name, ha="center", va="center", fontsize=6, color="white", fontweight="bold",
                zorder=7, clip_on=True)  # above the plans' dots


def road(ax: Axes, p: Mapping[str, Any], *, y_low_m: float | None = None, y_high_m: float | None = None) -> None:
    """The ego lane (y = 0 at its centre) and the opposing lane above, the lane line dashed; the
    view spans both lanes, widened to ``y_low_m`` / ``y_high_m`` (e.g. the ellipse's extent)."""
    lane = p["road"]["lane_width_m"]
    ax.axhspan(-lane / 2, lane / 2, color="0.93", zorder=0)
    ax.axhspan(lane / 2, 1.5 * lane, color="0.85", zorder=0)
    ax.axhline(lane / 2, color="white", ls=(0, (6, 6)), lw=1.5, zorder=0)
    low = min(-lane / 2 - 0.3, (y_low_m - 0.2) if y_low_m is not None else math.inf)
    high = max(1.5 * lane + 0.3, (y_high_m + 0.2) if y_high_m is not None else -math.inf)
    ax.set_ylim(low, high)


def plan_time(plans: Mapping[str, np.ndarray] | None, when: float) -> float | None:
    """The latest time at or before ``when`` (s) at which plans were stored, None if none."""
    times = column(plans, "t_s")
    if times is None:
        return None
    earlier = times[np.isfinite(times) & (times <= when + 1e-9)]
    return float(earlier.max()) if earlier.size else None


def windows(traj: Trajectory, plans: Mapping[str, np.ndarray] | None, p: Mapping[str, Any],
            times: Sequence[float]) -> tuple[list[float], float]:
    """Per time, the left edge of its window (m), and the one width of all windows (m): wide enough
    for the ego, veh_f's ellipse and the plans shown at the widest moment."""
    t = np.asarray(traj["t_s"], dtype=float)
    ego_x, front_x = np.asarray(traj["ego_x_m"], float), np.asarray(traj["front_x_m"], float)
    a_m = p["barrier"]["ellipse_a_m"]
    lefts, spans = [], []
    for when in times:
        k = index_at(t, when)
        left = min(ego_x[k], front_x[k] - a_m) - _BEHIND_M
        right = max(front_x[k] + a_m, ego_x[k])
        shown = plan_time(plans, when)
        if shown is not None:
            sel = (plans["t_s"] == shown) & np.isfinite(plans["x_m"].astype(float))
            if sel.any():
                right = max(right, float(np.max(plans["x_m"][sel].astype(float))))
        lefts.append(left)
        spans.append(right - left)
    width = float(np.clip(max(spans, default=_MIN_WIDTH_M) + _AHEAD_M, _MIN_WIDTH_M, _MAX_WIDTH_M))
    return lefts, width


def panel_height_in(p: Mapping[str, Any], width_m: float, width_in: float) -> float:
    """Inches one road panel needs at equal scale in a figure ``width_in`` wide (with tick labels)."""
    lane, b_m = p["road"]["lane_width_m"], p["barrier"]["ellipse_b_m"]
    span_m = 1.5 * lane + 0.3 - min(-lane / 2 - 0.3, -b_m - 0.2)  # as :func:`road` sets it (veh_f on y = 0)
    return 0.94 * width_in * span_m / width_m + 0.42


def road_panel(ax: Axes, traj: Trajectory, plans: Mapping[str, np.ndarray] | None, p: Mapping[str, Any],
               when: float, x0: float, width_m: float, *, event: UnsafeEvent | None = None) -> None:
    """The road at time ``when`` (s) in the window [x0, x0 + width_m] (m); ``event`` marks the
    first unsafe moment when this panel shows it (see the module docstring)."""
    t = np.asarray(traj["t_s"], dtype=float)
    k = event.index if event is not None else index_at(t, when)
    ego_x, ego_y = np.asarray(traj["ego_x_m"], float), np.asarray(traj["ego_y_m"], float)
    psi, front_y = column(traj, "ego_psi_rad"), column(traj, "front_y_m")
    opp_x, opp_y = column(traj, "opp_x_m"), column(traj, "opp_y_m")
    front_x = np.asarray(traj["front_x_m"], float)
    a_m, b_m = p["barrier"]["ellipse_a_m"], p["barrier"]["ellipse_b_m"]
    lane = p["road"]["lane_width_m"]
    fy = float(front_y[k]) if front_y is not None else 0.0
    road(ax, p, y_low_m=fy - b_m)
    ax.set_xlim(x0, x0 + width_m)
    ax.plot(ego_x[: k + 1], ego_y[: k + 1], color="black", lw=1.2, zorder=3)
    ax.add_patch(Ellipse((front_x[k], fy), 2 * a_m, 2 * b_m, fill=False, ls="--", lw=1, color=FRONT, zorder=2))
    box(ax, front_x[k], fy, 0.0, p, FRONT, name="veh_f")
    meas_x, meas_y = column(traj, "meas_front_x_m"), column(traj, "meas_front_y_m")
    if meas_x is not None and meas_y is not None and np.isfinite(meas_x[k]) and np.isfinite(meas_y[k]):
        box(ax, float(meas_x[k]), float(meas_y[k]), 0.0, p, FRONT, zorder=5, outline=True)  # what the planner saw
    box(ax, ego_x[k], ego_y[k], float(psi[k]) if psi is not None else 0.0, p, EGO, name="ego", zorder=5)
    if opp_x is not None and np.isfinite(opp_x[k]):
        parked = opp_x[k] >= PARKED_BEYOND_X_M
        if not parked:
            oy = float(opp_y[k]) if opp_y is not None and np.isfinite(opp_y[k]) else lane
            box(ax, opp_x[k], oy, math.pi, p, OPP, name="veh_o")
        if parked or opp_x[k] > x0 + width_m:  # not in the window: say where it is
            where = "not on the road yet" if parked else f"at x = {opp_x[k]:.0f} m →"
            ax.text(0.995, 0.93, f"veh_o {where}", transform=ax.transAxes, ha="right", va="top", fontsize=7,
                    color=OPP)
    shown = plan_time(plans, when)
    if shown is not None:
        _plans(ax, plans, shown, lane)
    stamp = f"t = {t[k]:.2f} s" + (f" (plans of {shown:.2f} s)" if shown is not None and shown < t[k] - 0.05 else "")
    ax.text(0.005, 0.93, stamp, transform=ax.transAxes, fontsize=8, va="top")
    if event is not None:
        _mark(ax, traj, event, opp_x, opp_y, lane)
    ax.set_aspect("equal", adjustable="box")
    ax.tick_params(labelsize=7)
    ax.set_yticks([0.0, lane])


def _plans(ax: Axes, plans: Mapping[str, np.ndarray], when: float, lane: float) -> None:
    problems = plans.get("problem")
    for name, colour in (("Q1", Q1_COLOUR), ("Q2", Q2_COLOUR)):
        sel = plans["t_s"] == when
        if problems is not None:
            sel &= problems == name
        if not sel.any():
            continue
        ax.plot(plans["x_m"][sel].astype(float), plans["y_m"][sel].astype(float), ".", ms=3, color=colour,
                alpha=0.75, zorder=6)
        opp_plan = plans.get("opp_x_m")
        if name == "Q1" and opp_plan is not None and np.isfinite(opp_plan[sel].astype(float)).any():
            ax.plot(opp_plan[sel].astype(float), np.full(int(sel.sum()), lane), ".", ms=3, color=OPP, alpha=0.6,
                    zorder=6)


def _mark(ax: Axes, traj: Trajectory, event: UnsafeEvent, opp_x, opp_y, lane: float) -> None:
    """Red frame, a cross where it happened (the ego c.g. for the ellipse, midway to the other
    vehicle for a collision) and the cause written in."""
    k = event.index
    x, y = float(traj["ego_x_m"][k]), float(traj["ego_y_m"][k])
    if event.constraint == "collision_front":
        fy = column(traj, "front_y_m")
        x, y = (x + float(traj["front_x_m"][k])) / 2, (y + (float(fy[k]) if fy is not None else 0.0)) / 2
    elif event.constraint == "collision_opp" and opp_x is not None:
        oy = float(opp_y[k]) if opp_y is not None and np.isfinite(opp_y[k]) else lane
        x, y = (x + float(opp_x[k])) / 2, (y + oy) / 2
    ax.plot([x], [y], marker="X", ms=9, color=UNSAFE, mec="white", mew=0.8, zorder=8)
    for spine in ax.spines.values():
        spine.set_edgecolor(UNSAFE)
        spine.set_linewidth(2.0)
    then = f"; {event.then()}" if event.later else ""
    ax.text(0.5, 0.93, f"first unsafe: {event.label()}{then}", transform=ax.transAxes, ha="center", va="top",
            fontsize=8, color=UNSAFE, fontweight="bold",
            bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none", "pad": 1.0})


def legend_handles(traj: Trajectory, plans: Mapping[str, np.ndarray] | None,
                   event: UnsafeEvent | None) -> list[Line2D]:
    """One legend entry per thing :func:`road_panel` draws for this episode."""
    box_kw = {"marker": "s", "ls": "", "ms": 9, "alpha": 0.65, "mec": "black", "mew": 0.4}
    handles = [
        Line2D([], [], color=EGO, label="ego", **box_kw),
        Line2D([], [], color=FRONT, label="veh_f (front)", **box_kw),
        Line2D([], [], color=FRONT, ls="--", label="safety ellipse h_ef = 0"),
    ]
    if column(traj, "meas_front_x_m") is not None:
        handles.append(Line2D([], [], color=FRONT, marker="s", ls="", ms=9, mfc="none", mec=FRONT,
                                  label="veh_f as measured"))
    if column(traj, "opp_x_m") is not None:
        handles.append(Line2D([], [], color=OPP, label="veh_o (opposing)", **box_kw))
    handles.append(Line2D([], [], color="black", label="ego path"))
    if column(plans, "t_s") is not None:
        kinds = set(np.asarray(plans["problem"]).tolist()) if "problem" in plans else {"Q1", "Q2"}
        handles += [Line2D([], [], color=colour, marker=".", ls="", label=label) for name, colour, label in
                    (("Q1", Q1_COLOUR, "Q1 plan (overtake)"), ("Q2", Q2_COLOUR, "Q2 plan (go back)")) if name in kinds]
        if column(plans, "opp_x_m") is not None:
            handles.append(Line2D([], [], color=OPP, marker=".", ls="", label="veh_o predicted"))
    if event is not None:
        handles.append(Line2D([], [], color=UNSAFE, marker="X", ls="", ms=8, label="first unsafe moment"))
    return handles
