"""Figures of a run, in the spirit of the paper's: matplotlib on the Agg backend (files only).

Campaign-level figures come from the summary and ``episodes.parquet``: rates per cell with their
intervals (:func:`rates_per_cell`), a rate against a numeric axis such as ε with interval bands
(:func:`rate_vs_axis`), a heat map of a rate over two axes with the counts written in
(:func:`rate_heatmap`) and minimum-distance histograms per cell (:func:`distance_histograms`).

Episode-level figures come from the stored trajectories (``trajectories/episode-NNNNNN.parquet``,
one row per integration sub-step, and ``...-plans.parquet``, the Q1/Q2 plans at snapshot times):
road snapshots with the planned Q1 (green) and Q2 (orange) trajectories, the safety ellipse and the
predicted opposing trajectory (:func:`snapshots`), h(t) against its level (:func:`barrier_series`)
and speed profiles (:func:`speed_profiles`). A missing column is left out of the drawing; a
missing file skips the figure (the report says so).

Every figure has a fixed size in pixels (``figsize`` x :data:`DPI`, no tight bounding box) and is
saved without the matplotlib version in the PNG metadata, so the same data give the same bytes.
Each drawing function returns :func:`artist_counts` of what it drew, for tests and the report.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pyarrow as pa  # noqa: E402
import pyarrow.parquet as pq  # noqa: E402
from matplotlib.patches import Ellipse, Polygon  # noqa: E402
from matplotlib.ticker import MaxNLocator  # noqa: E402

from mcverify.model import ModelParams  # noqa: E402
from mcverify.report.tables import fmt_p  # noqa: E402

#: Dots per inch of every figure: pixel size = figsize * DPI.
DPI = 100
#: PNG text chunks: none (matplotlib would write its version; Agg writes no date).
PNG_METADATA: dict[str, Any] = {"Software": None}
#: Most panels in a small-multiples figure (one per cell); more cells skip the figure.
MAX_PANELS = 48

EGO, FRONT, OPP = "tab:green", "tab:red", "tab:blue"
Q1_COLOUR, Q2_COLOUR = "tab:green", "tab:orange"
#: Background colour per ``active_problem`` code (decision.Source): Q1, Q2, fallback, held MPC-DC plan.
_PROBLEM_COLOURS = {1: Q1_COLOUR, 2: Q2_COLOUR, 3: "tab:red", 4: "tab:purple"}
_OUTCOME_COLOURS = {"overtook": "tab:green", "went_back": "tab:orange", "timeout": "tab:gray", "error": "black"}

Trajectory = Mapping[str, np.ndarray]


# ----------------------------------------------------------------------------------------- data


def params_dict(params: Any = None) -> dict[str, dict[str, Any]]:
    """Model parameters as nested dicts (``section -> field -> value``), defaults filled in.

    ``params``: a :class:`ModelParams`, the ``params`` dict of a manifest cell, or None."""
    out = dataclasses.asdict(ModelParams())
    if params is None:
        return out
    given = dataclasses.asdict(params) if dataclasses.is_dataclass(params) else params
    for section, values in given.items():
        if isinstance(values, Mapping):
            out.setdefault(section, {}).update(values)
    return out


def load_table(path: Path) -> dict[str, np.ndarray] | None:
    """A parquet file as ``column -> numpy array`` (strings as object arrays), None if missing."""
    path = Path(path)
    if not path.is_file():
        return None
    t = pq.read_table(path)
    return {name: _np(t.column(name)) for name in t.column_names}


def _np(col: pa.ChunkedArray) -> np.ndarray:
    if pa.types.is_floating(col.type) or pa.types.is_integer(col.type):
        return np.asarray(col.to_numpy(), dtype=np.float64)
    if pa.types.is_boolean(col.type):
        return np.asarray(col.to_pylist(), dtype=bool)
    return np.asarray(col.to_pylist(), dtype=object)


def column(data: Mapping[str, np.ndarray] | None, name: str) -> np.ndarray | None:
    """A numeric column, or None when it is missing or holds no finite value."""
    if data is None or name not in data:
        return None
    x = np.asarray(data[name])
    if x.dtype == object:
        return None
    x = x.astype(np.float64)
    return x if np.isfinite(x).any() else None


# --------------------------------------------------------------------------------------- saving


def artist_counts(fig: plt.Figure) -> dict[str, int]:
    """How much was drawn: axes, lines, patches, collections, images and texts over all axes."""
    counts = {"axes": 0, "lines": 0, "patches": 0, "collections": 0, "images": 0, "texts": 0}
    for ax in fig.axes:
        counts["axes"] += 1
        counts["lines"] += len(ax.lines)
        counts["patches"] += len(ax.patches)
        counts["collections"] += len(ax.collections)
        counts["images"] += len(ax.images)
        counts["texts"] += len(ax.texts)
    return counts


def inches(width_in: float, height_in: float) -> tuple[float, float]:
    """A figure size that is a whole number of pixels at :data:`DPI`, so the PNG's size is
    ``round(x * DPI)`` exactly: half a pixel is added because Agg truncates ``x * DPI``, which
    floating point may put just below the integer."""
    return tuple((round(x * DPI) + 0.5) / DPI for x in (width_in, height_in))  # type: ignore[return-value]


def save(fig: plt.Figure, path: Path) -> dict[str, int]:
    """Write ``fig`` as PNG at :data:`DPI` with fixed metadata, close it, return its artist counts
    and its size in pixels (``width_px``, ``height_px``, as the PNG has them)."""
    counts = artist_counts(fig)
    counts["width_px"], counts["height_px"] = (int(x * DPI) for x in fig.get_size_inches())  # Agg truncates
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI, format="png", metadata=PNG_METADATA)
    plt.close(fig)
    return counts


def _grid(n: int, ncols: int, panel_w: float, panel_h: float, **kw) -> tuple[plt.Figure, list[plt.Axes]]:
    ncols = max(1, min(ncols, n))
    nrows = math.ceil(n / ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=inches(panel_w * ncols, panel_h * nrows + 0.6), squeeze=False, **kw)
    flat = list(axes.ravel())
    for ax in flat[n:]:
        ax.remove()
    return fig, flat[:n]


# -------------------------------------------------------------------------------- campaign level


def rates_per_cell(cells: Sequence[Mapping[str, Any]], path: Path) -> dict[str, int]:
    """Left: safe, collision and ellipse-violation rates per cell with their two-sided intervals
    (points and bars). Right: the share of each outcome per cell, with the counts."""
    n = len(cells)
    height = min(0.32 * n + 1.8, 0.32 * MAX_PANELS + 1.8)
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=inches(12, height), sharey=True, gridspec_kw={"width_ratios": [1.3, 1]})
    y = np.arange(n)
    metrics = (("safe", "tab:green", -0.2), ("collision", "tab:red", 0.0), ("ellipse_violation", "tab:purple", 0.2))
    for name, colour, dy in metrics:
        rs = [c["rates"].get(name) for c in cells]
        ok = [i for i, r in enumerate(rs) if r and r["n"]]
        if not ok:
            continue
        rate = np.array([rs[i]["rate"] for i in ok])
        low = np.array([rs[i]["low"] for i in ok])
        high = np.array([rs[i]["high"] for i in ok])
        ax.errorbar(rate, y[ok] + dy, xerr=[rate - low, high - rate], fmt="o", ms=4, color=colour, capsize=2,
                    lw=1, label=name.replace("_", " "))
    ax.set_xlim(-0.02, 1.02)
    ax.set_yticks(y, [c["cell"] for c in cells], fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("rate (point) with its two-sided interval (bar)")
    ax.grid(axis="x", alpha=0.3)
    ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=3, fontsize=8, frameon=False)
    left = np.zeros(n)
    for outcome, colour in _OUTCOME_COLOURS.items():
        counts = np.array([c["outcomes"].get(outcome, 0) for c in cells], dtype=float)
        totals = np.array([max(c["episodes"], 1) for c in cells], dtype=float)
        if not counts.any():
            continue
        share = counts / totals
        ax2.barh(y, share, left=left, color=colour, alpha=0.8, label=outcome.replace("_", " "))
        for i in np.flatnonzero(counts):
            if share[i] > 0.06:
                ax2.text(left[i] + share[i] / 2, y[i], f"{int(counts[i])}", ha="center", va="center", fontsize=7,
                         color="white")
        left += share
    ax2.set_xlim(0, 1)
    ax2.set_xlabel("share of episodes by outcome (counts written in)")
    ax2.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=4, fontsize=8, frameon=False)
    fig.tight_layout()
    return save(fig, path)


def rate_vs_axis(
    cells: Sequence[Mapping[str, Any]],
    x_axis: str,
    x_values: Sequence[float],
    groups: Sequence[str],
    metrics: Sequence[tuple[str, str]],
    path: Path,
    *,
    level: float,
    x_label: str | None = None,
) -> dict[str, int]:
    """One panel per ``(metric, title)``: the rate against ``x_values`` (one per cell), one line per
    group label (``groups``, one per cell), each with its two-sided interval as a band; zero-event
    points show the exact one-sided upper bound as a marker."""
    fig, axes = plt.subplots(1, len(metrics), figsize=inches(6 * len(metrics), 4.2), squeeze=False)
    xs, gs = np.asarray(x_values, dtype=float), list(groups)
    colours = plt.get_cmap("tab10")
    for ax, (metric, title) in zip(axes[0], metrics, strict=True):
        for gi, group in enumerate(dict.fromkeys(gs)):
            idx = [i for i, g in enumerate(gs) if g == group and cells[i]["rates"].get(metric, {}).get("n")]
            if not idx:
                continue
            idx.sort(key=lambda i: xs[i])
            r = [cells[i]["rates"][metric] for i in idx]
            x = xs[idx]
            colour = colours(gi % 10)
            ax.fill_between(x, [q["low"] for q in r], [q["high"] for q in r], color=colour, alpha=0.18, lw=0)
            ax.plot(x, [q["rate"] for q in r], "o-", color=colour, ms=4, lw=1.4, label=group or "all cells")
            zero = [j for j, q in enumerate(r) if q["k"] == 0]
            if zero:
                ax.plot(x[zero], [r[j]["upper_one_sided"] for j in zero], "v", color=colour, ms=5, alpha=0.8)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel(x_label or x_axis)
        ax.set_ylabel(f"rate with {level:.0%} interval")
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")
    fig.suptitle(f"band: two-sided {level:.0%} interval; ▼: exact one-sided upper bound where no event occurred",
                 fontsize=9)
    fig.tight_layout()
    return save(fig, path)


def rate_heatmap(
    cells: Sequence[Mapping[str, Any]],
    row_axis: str,
    row_labels: Sequence[str],
    col_axis: str,
    col_labels: Sequence[str],
    metric: str,
    path: Path,
    *,
    title: str,
    higher_is_better: bool = True,
    tick_labels: tuple[Sequence[str], Sequence[str]] | None = None,
) -> dict[str, int]:
    """A rate over two axes: colour = rate, each square annotated with k/n and its interval (or
    the one-sided bound when k is 0 or n). Empty squares (no such cell) stay white. Cells are
    placed by their labels; ``tick_labels`` (rows, columns) are the texts shown for them."""
    grid = np.full((len(row_labels), len(col_labels)), np.nan)
    size = inches(max(5.0, 1.9 * len(col_labels) + 2.5), max(3.0, 0.75 * len(row_labels) + 1.6))
    fig, ax = plt.subplots(figsize=size)
    for c in cells:
        lab = c["labels"]
        if lab.get(row_axis) not in row_labels or lab.get(col_axis) not in col_labels:
            continue
        i, j = row_labels.index(lab[row_axis]), col_labels.index(lab[col_axis])
        r = c["rates"].get(metric)
        if not r or not r["n"]:
            continue
        grid[i, j] = r["rate"]
        k, n = r["k"], r["n"]
        if k == 0:
            bound = f"≤ {fmt_p(r['upper_one_sided'])}"
        elif k == n:
            bound = f"≥ {fmt_p(r['lower_one_sided'])}"
        else:
            bound = f"[{fmt_p(r['low'])}, {fmt_p(r['high'])}]"
        good = r["rate"] if higher_is_better else 1 - r["rate"]
        ax.text(j, i, f"{k}/{n}\n{bound}", ha="center", va="center", fontsize=8,
                color="black" if 0.25 < good < 0.9 else "white")
    cmap = plt.get_cmap("RdYlGn" if higher_is_better else "RdYlGn_r").with_extremes(bad="white")
    im = ax.imshow(np.ma.masked_invalid(grid), cmap=cmap, vmin=0.0, vmax=1.0, aspect="auto")
    ax.set_xticks(range(len(col_labels)), tick_labels[1] if tick_labels else col_labels, fontsize=8)
    ax.set_yticks(range(len(row_labels)), tick_labels[0] if tick_labels else row_labels, fontsize=8)
    ax.set_xlabel(col_axis)
    ax.set_ylabel(row_axis)
    ax.set_title(title, fontsize=10)
    fig.colorbar(im, ax=ax, label=f"{metric.replace('_', ' ')} rate")
    fig.tight_layout()
    return save(fig, path)


def distance_histograms(
    names: Sequence[str],
    samples: Sequence[np.ndarray],
    path: Path,
    *,
    x_label: str,
    boundary: float | None = 0.0,
    boundary_label: str = "ellipse boundary",
) -> dict[str, int]:
    """One histogram per cell of a per-episode minimum distance, on shared bins; a line at the
    ``boundary`` (0: the safety ellipse) and the cell's minimum written in."""
    finite = [np.asarray(s, dtype=float)[np.isfinite(s)] for s in samples]
    every = np.concatenate(finite) if finite else np.zeros(0)
    if every.size == 0:
        raise ValueError("no finite value to draw")
    lo, hi = float(every.min()), float(every.max())
    if boundary is not None:
        lo, hi = min(lo, boundary), max(hi, boundary)
    if hi - lo < 1e-9:
        lo, hi = lo - 0.5, hi + 0.5
    pad = 0.04 * (hi - lo)
    bins = np.linspace(lo - pad, hi + pad, int(np.clip(np.sqrt(every.size / max(len(finite), 1)) * 3, 8, 40)) + 1)
    fig, axes = _grid(len(names), 4, 3.0, 2.3, sharex=True)
    for ax, name, x in zip(axes, names, finite, strict=True):
        if x.size:
            ax.hist(x, bins=bins, color="tab:blue", alpha=0.75, histtype="stepfilled")  # one patch: fast
            ax.set_title(f"{name}\nmin {x.min():.2f} · n = {x.size}", fontsize=7)
        else:
            ax.text(0.5, 0.5, "no value", transform=ax.transAxes, ha="center", va="center", fontsize=8)
            ax.set_title(name, fontsize=7)
        if boundary is not None:
            ax.axvline(boundary, color="tab:red", ls=":", lw=1, label=boundary_label)
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        ax.tick_params(labelsize=7)
    for ax in axes[-min(4, len(axes)):]:
        ax.set_xlabel(x_label, fontsize=8)
    fig.tight_layout()
    return save(fig, path)


# --------------------------------------------------------------------------------- episode level


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
    fig, axes = _grid(len(episodes), 2, 6.0, 2.6)
    for ax, (title, traj, level) in zip(axes, episodes, strict=True):
        barrier_panel(ax, traj, level, opp=opp, clip=None if opp else _barrier_clip(level))
        ax.set_title(title, fontsize=8)
    if axes[0].lines:
        axes[0].legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    return save(fig, path)


def speed_profiles(episodes: Sequence[tuple[str, Trajectory, float]], path: Path) -> dict[str, int]:
    """One panel per ``(title, trajectory, ego speed limit)``: the speed profiles."""
    fig, axes = _grid(len(episodes), 2, 6.0, 2.6)
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
