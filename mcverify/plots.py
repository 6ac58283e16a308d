"""Figures (matplotlib, Agg backend: files only, no display needed)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Ellipse, Rectangle  # noqa: E402

from mcverify.campaign import Cell  # noqa: E402

_PROBLEM_COLOURS = {1: "tab:green", 2: "tab:orange", 3: "tab:red"}


def episode_figure(traj: dict[str, np.ndarray], cell: Cell, row: dict, path: Path) -> Path:
    """Road view with snapshots and the safety ellipse, h_ef(t) against eps, and speeds."""
    p = cell.params
    t = traj["t_s"]
    fig, axes = plt.subplots(3, 1, figsize=(11, 9), gridspec_kw={"height_ratios": [1.3, 1, 1]})
    _road_panel(axes[0], traj, p)
    ax = axes[1]
    ax.plot(t, traj["h_front"], color="k", lw=1.2, label="h_ef (true state)")
    ax.axhline(cell.epsilon, color="tab:blue", ls="--", lw=1, label=f"level ε = {cell.epsilon:.2f}")
    ax.axhline(0.0, color="tab:red", ls=":", lw=1, label="ellipse boundary h = 0")
    hmax = max(5.0 * max(cell.epsilon, 0.2), 1.0)
    ax.set_ylim(min(-0.2, float(np.nanmin(traj["h_front"])) - 0.1), hmax)
    ax.set_ylabel("h_ef (clipped view)")
    _shade_problems(ax, t, traj["active_problem"])
    ax.legend(loc="upper right", fontsize=8)
    ax = axes[2]
    ax.plot(t, traj["ego_speed_mps"], color="tab:green", label="ego speed")
    ax.plot(t, traj["front_speed_mps"], color="tab:red", label="front speed")
    ax.plot(t, traj["meas_front_speed_mps"], color="tab:red", alpha=0.3, lw=0.8, label="front speed (measured)")
    ax.axhline(p.ego.speed_max_mps, color="grey", ls=":", lw=1, label="ego speed limit")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("speed (m/s)")
    ax.legend(loc="lower right", fontsize=8)
    title = (
        f"{cell.name} · episode {row['episode_id']} · {row['outcome']} · safe={row['safe']} · "
        f"min dist. to ellipse {row['min_dist_front_m']:.2f} m · min h {row['min_h_front']:.3f}"
    )
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _road_panel(ax, traj: dict[str, np.ndarray], p) -> None:
    lane = p.road.lane_width_m
    x_all = np.concatenate([traj["ego_x_m"], traj["front_x_m"]])
    x0, x1 = float(x_all.min()) - 10, float(x_all.max()) + 10
    ax.axhspan(-lane / 2, lane / 2, color="0.93")
    ax.axhspan(lane / 2, 1.5 * lane, color="0.86")
    ax.axhline(lane / 2, color="w", ls="--", lw=1.5)
    n = len(traj["t_s"])
    for k in np.linspace(0, n - 1, 6).astype(int):
        ex, ey, psi = traj["ego_x_m"][k], traj["ego_y_m"][k], traj["ego_psi_rad"][k]
        fx = traj["front_x_m"][k]
        ax.add_patch(_box(ex, ey, psi, p, "tab:green"))
        ax.add_patch(_box(fx, 0.0, 0.0, p, "tab:red"))
        ax.add_patch(Ellipse((fx, 0.0), 2 * p.barrier.ellipse_a_m, 2 * p.barrier.ellipse_b_m,
                             fill=False, ls="--", lw=0.8, color="tab:red"))
        ax.annotate(f"{traj['t_s'][k]:.1f}s", (ex, ey + 1.2), fontsize=7, ha="center")
    ax.plot(traj["ego_x_m"], traj["ego_y_m"], color="k", lw=1.2, label="ego path")
    ax.set_xlim(x0, x1)
    ax.set_ylim(-lane / 2 - 0.5, 1.5 * lane + 0.5)
    ax.set_aspect("auto")
    ax.set_ylabel("y (m)")
    ax.set_xlabel("x (m)")
    ax.legend(loc="upper left", fontsize=8)


def _box(x, y, psi, p, colour) -> Rectangle:
    L, W = p.geometry.length_m, p.geometry.width_m
    c, s = np.cos(psi), np.sin(psi)
    corner = (x - (L / 2) * c + (W / 2) * s, y - (L / 2) * s - (W / 2) * c)
    return Rectangle(corner, L, W, angle=np.degrees(psi), color=colour, alpha=0.5)


def _shade_problems(ax, t: np.ndarray, problem: np.ndarray) -> None:
    if len(t) == 0:
        return
    start = 0
    for i in range(1, len(t) + 1):
        if i == len(t) or problem[i] != problem[start]:
            colour = _PROBLEM_COLOURS.get(int(problem[start]))
            if colour:
                ax.axvspan(t[start], t[i - 1], color=colour, alpha=0.08, lw=0)
            start = i
