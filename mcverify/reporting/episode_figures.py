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

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from mcverify.model import kept_level
from mcverify.reporting import road_panels, unsafe_event
from mcverify.reporting.figure_common import column, inches, panel_grid, params_dict, save
from mcverify.reporting.road_panels import EGO, FRONT, OPP, Q1_COLOUR, Q2_COLOUR, UNSAFE
from mcverify.reporting.unsafe_event import UnsafeEvent

#: Background colour per ``active_problem`` code (decision.Source): Q1, Q2, fallback, held MPC-DC plan.
_PROBLEM_COLOURS = {1: Q1_COLOUR, 2: Q2_COLOUR, 3: "tab:red", 4: "tab:purple"}
#: Width of the stacked road figures (in).
_ROAD_WIDTH_IN = 12.0

Trajectory = Mapping[str, np.ndarray]


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


def _with_moment(times: list[float], moment: float | None, event: UnsafeEvent | None) -> list[float]:
    """``times`` with ``moment`` added (in order) when it is finite and no panel is at it already."""
    if moment is None or not np.isfinite(moment):
        return times
    shown = [*times, *([event.t_s] if event is not None else [])]
    if any(abs(w - moment) < 1e-9 for w in shown):
        return times
    return sorted([*times, float(moment)])


def _with_event(times: list[float], event: UnsafeEvent | None) -> list[tuple[float, UnsafeEvent | None]]:
    """The snapshot times in order, the first unsafe moment added as its own panel."""
    moments: list[tuple[float, UnsafeEvent | None]] = [(w, None) for w in times]
    if event is not None:
        moments = [m for m in moments if abs(m[0] - event.t_s) > 1e-9] + [(event.t_s, event)]
    return sorted(moments, key=lambda m: m[0])


def _road_stack(fig_height_extra_in: float, traj: Trajectory, plans: Mapping[str, np.ndarray] | None,
                p: Mapping[str, Any], times: list[float], event: UnsafeEvent | None, *, bottom_in: float = 0.45,
                ) -> tuple[Figure, list[Axes], float]:
    """A figure whose top holds one road panel per moment (equal scale, one window width), with
    ``fig_height_extra_in`` inches left free below them; returns the figure, the road axes and the
    free height's top in figure coordinates."""
    moments = _with_event(times, event)
    lefts, width = road_panels.windows(traj, plans, p, [m[0] for m in moments])
    header_in = 0.8
    panel_h = road_panels.panel_height_in(p, width, _ROAD_WIDTH_IN)
    roads_in = panel_h * len(moments)
    height = header_in + roads_in + bottom_in + fig_height_extra_in
    fig = Figure(figsize=inches(_ROAD_WIDTH_IN, height))
    top = 1 - header_in / height
    road_bottom = (fig_height_extra_in + bottom_in) / height
    grid = fig.add_gridspec(len(moments), 1, left=0.05, right=0.99, top=top, bottom=road_bottom, hspace=0.35)
    axes = []
    for i, ((when, ev), x0) in enumerate(zip(moments, lefts, strict=True)):
        ax = fig.add_subplot(grid[i, 0])
        road_panels.road_panel(ax, traj, plans, p, when, x0, width, event=ev)
        axes.append(ax)
    axes[-1].set_xlabel("x (m)", fontsize=8)
    handles = road_panels.legend_handles(traj, plans, event)
    fig.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, 1 - 0.34 / height),
               ncol=min(len(handles), 9), fontsize=7, frameon=False)
    return fig, axes, (fig_height_extra_in) / height


def snapshots(
    traj: Trajectory,
    plans: Mapping[str, np.ndarray] | None,
    params: Mapping[str, Any],
    path: Path,
    *,
    title: str,
    n_snapshots: int = 5,
    moment: float | None = None,
) -> dict[str, int]:
    """Road snapshots stacked top to bottom (the paper's Figs. 5-7), drawn to scale: the ego, veh_f
    with its safety ellipse h_ef = 0 (dashed) and veh_o when there is one, each as its footprint and
    named, the ego's path so far (black), the planned Q1 (green dots) and Q2 (orange dots)
    trajectories and veh_o's predicted positions (blue dots). An unsafe episode gets one more panel
    at its first unsafe moment, framed in red with the cause written in
    (:mod:`mcverify.reporting.road_panels`), and one at ``moment`` (s; e.g. when a counterexample
    first violated its requirement, which need not be a safety event) unless a panel shows it already."""
    p = params_dict(params)
    event = unsafe_event.first_unsafe_event(traj)
    times = _with_moment(snapshot_times(traj, plans, n_snapshots), moment, event)
    fig, _, _ = _road_stack(0.0, traj, plans, p, times, event)
    fig.text(0.5, 1 - 0.12 / fig.get_size_inches()[1], title, ha="center", va="top", fontsize=9)
    return save(fig, path)


def _shade_problems(ax: Axes, t: np.ndarray, problem: np.ndarray | None) -> None:
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
    ax: Axes, traj: Trajectory, level: float | None, *, opp: bool = False, clip: float | None = None
) -> None:
    """h_ef(t) (or h_eo(t) with ``opp``) along the true trajectory against its level and 0; ``level``
    None: the controller keeps none (plain MPC-DC keeps h >= 0, :func:`mcverify.model.kept_level`)."""
    t = np.asarray(traj["t_s"], dtype=float)
    h = column(traj, "h_opp" if opp else "h_front")
    if h is None:
        ax.text(0.5, 0.5, "no values", transform=ax.transAxes, ha="center", va="center")
        return
    name = "h_eo (m)" if opp else "h_ef"
    ax.plot(t, h, color="black", lw=1.1, label=f"{name}, true state")
    if level is not None:
        ax.axhline(level, color="tab:blue", ls="--", lw=1, label=f"level {'ε_eo' if opp else 'ε'} = {level:.3g}")
    ax.axhline(0.0, color="tab:red", ls=":", lw=1,
               label="h = 0 (boundary)" if level is not None else "h = 0 (boundary; MPC-DC\nkeeps h ≥ 0, no level ε)")
    finite = h[np.isfinite(h)]
    top = clip if clip is not None else float(finite.max())
    ax.set_ylim(min(-0.1 * max(level or 0.0, 1e-3), float(finite.min())) - 0.05 * max(abs(top), 1.0), top)
    _shade_problems(ax, t, column(traj, "active_problem"))
    event = unsafe_event.first_unsafe_event(traj)
    if event is not None:
        mark_event(ax, event)
    ax.set_xlabel("time (s)", fontsize=8)
    ax.set_ylabel(name + (" (clipped)" if clip is not None and finite.max() > clip else ""), fontsize=8)
    ax.tick_params(labelsize=7)


def mark_event(ax: Axes, event: UnsafeEvent, *, text: bool = True) -> None:
    """A red vertical line at the first unsafe moment (s), its cause written beside it: to its right,
    or to its left when the moment lies in the right part of the panel (where the text would run out)."""
    ax.axvline(event.t_s, color=UNSAFE, lw=1.2, label="first unsafe moment")
    if text:
        low, high = ax.get_xlim()
        right = event.t_s > low + 0.55 * (high - low)
        ax.text(event.t_s, 0.96, f"{event.label()} " if right else f" {event.label()}",
                transform=ax.get_xaxis_transform(), fontsize=7, color=UNSAFE, ha="right" if right else "left",
                va="top", clip_on=True, bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none", "pad": 1.0})


def speed_panel(ax: Axes, traj: Trajectory, speed_limit_mps: float | None) -> None:
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
        if v is not None and name == "opp_speed_mps" and column(traj, "opp_x_m") is not None:
            v = np.where(column(traj, "opp_x_m") < road_panels.PARKED_BEYOND_X_M, v, np.nan)  # not spawned yet
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
        barrier_panel(ax, traj, level, opp=opp, clip=None if opp else _barrier_clip(level or 0.0))
        ax.set_title(title, fontsize=8)
    _legend_below(fig, axes)
    return save(fig, path)


def _legend_below(fig: Figure, axes: Sequence[Axes]) -> None:
    """One legend for all panels, below them, so that it hides no curve and no label (each entry once:
    a panel with a level line or an unsafe moment adds its own)."""
    entries: dict[str, Any] = {}
    for ax in axes:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            entries.setdefault(label, handle)
    height = fig.get_size_inches()[1]
    fig.tight_layout(rect=(0.0, 0.45 / height if entries else 0.0, 1.0, 1.0))
    if entries:
        fig.legend(list(entries.values()), list(entries), loc="lower center", ncol=min(len(entries), 5), fontsize=7,
                   frameon=False)


def speed_profiles(episodes: Sequence[tuple[str, Trajectory, float]], path: Path) -> dict[str, int]:
    """One panel per ``(title, trajectory, ego speed limit)``: the speed profiles."""
    fig, axes = panel_grid(len(episodes), 2, 6.0, 2.6)
    for ax, (title, traj, limit) in zip(axes, episodes, strict=True):
        speed_panel(ax, traj, limit)
        ax.set_title(title, fontsize=8)
    _legend_below(fig, axes)
    return save(fig, path)


def episode_overview(
    traj: Trajectory,
    params: Any,
    level: float,
    path: Path,
    *,
    title: str,
    plans: Mapping[str, np.ndarray] | None = None,
    moment: float | None = None,
) -> dict[str, int]:
    """One episode on one page (the figure ``mcverify replay`` writes): road panels to scale at
    four moments (and at the first unsafe one, marked with its cause, and at ``moment`` as in
    :func:`snapshots`), h_ef(t) against ε, and the speeds, the first unsafe moment marked in both."""
    p = params_dict(params)
    event = unsafe_event.first_unsafe_event(traj)
    times = _with_moment(snapshot_times(traj, plans, 4), moment, event)
    series_in = 2 * 2.4 + 0.5
    fig, _, free_top = _road_stack(series_in, traj, plans, p, times, event, bottom_in=0.3)
    height = fig.get_size_inches()[1]
    grid = fig.add_gridspec(2, 1, left=0.07, right=0.83, top=free_top - 0.2 / height, bottom=0.5 / height,
                            hspace=0.45)
    ax_h, ax_v = fig.add_subplot(grid[0, 0]), fig.add_subplot(grid[1, 0], sharex=None)
    barrier_panel(ax_h, traj, kept_level(p["mpc"]["controller"], level), clip=_barrier_clip(level))
    speed_panel(ax_v, traj, p["ego"]["speed_max_mps"])
    if event is not None:
        mark_event(ax_v, event, text=False)
    for ax in (ax_h, ax_v):  # beside the panel, not on it: it hid the unsafe moment's label
        ax.legend(loc="upper left", bbox_to_anchor=(1.005, 1.0), fontsize=7, borderaxespad=0.0)
    fig.text(0.5, 1 - 0.12 / height, title, ha="center", va="top", fontsize=9)
    return save(fig, path)
