"""Campaign-level figures of a run, drawn from its summary (one entry per cell).

Rates per cell with their intervals (:func:`rates_per_cell`), a rate against a numeric axis such as
ε on a log scale with intervals and bounds (:func:`rate_vs_axis`), a heat map of a rate over two axes with the counts
written in (:func:`rate_heatmap`) and minimum-distance histograms per cell
(:func:`distance_histograms`). Sizes and saving: :mod:`mcverify.reporting.figure_common`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle
from matplotlib.ticker import MaxNLocator

from mcverify.reporting.figure_common import MAX_PANELS, inches, panel_grid, save, subplots
from mcverify.reporting.tables import fmt_p

#: Outline and label colour of a cell with at least one unsafe episode.
UNSAFE = "crimson"
_OUTCOME_COLOURS = {"overtook": "tab:green", "went_back": "tab:orange", "timeout": "tab:gray",
                    "stopped": "tab:red", "error": "black"}


def unsafe_cell(cell: Mapping[str, Any]) -> bool:
    """Whether at least one of the cell's simulated episodes was unsafe (its safe count k < n)."""
    r = cell["rates"].get("safe")
    return bool(r and r["n"] and r["k"] < r["n"])


def _unsafe_legend(fig: Figure, cells: Sequence[Mapping[str, Any]], text: str) -> None:
    """A legend line at the figure's foot for the cells drawn as unsafe (none if none is)."""
    n = sum(unsafe_cell(c) for c in cells)
    if n:
        fig.text(0.01, 0.005, f"{text} ({n} of {len(cells)} cells)", color=UNSAFE, fontsize=8, ha="left",
                 va="bottom")


def rates_per_cell(cells: Sequence[Mapping[str, Any]], path: Path) -> dict[str, int]:
    """Left: safe, collision and ellipse-violation rates per cell with their two-sided intervals
    (points and bars). Right: the share of each outcome per cell, with the counts."""
    n = len(cells)
    height = min(0.32 * n + 1.8, 0.32 * MAX_PANELS + 1.8)
    fig, (ax, ax2) = subplots(1, 2, figsize=inches(12, height), sharey=True, gridspec_kw={"width_ratios": [1.3, 1]})
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
    ax.set_yticks(y, [("⚠ " if unsafe_cell(c) else "") + c["cell"] for c in cells], fontsize=8)
    for tick, c in zip(ax.get_yticklabels(), cells, strict=True):
        if unsafe_cell(c):
            tick.set_color(UNSAFE)
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
    fig.tight_layout(rect=(0, 0.25 / height, 1, 1))
    _unsafe_legend(fig, cells, "⚠ red name: a cell with at least one unsafe episode")
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
    bound: str = "exact one-sided",
) -> dict[str, int]:
    """One panel per ``(metric, title)``: the probability against ``x_values`` (one per cell) on a log
    scale, one line per group label (``groups``, one per cell). A cell with events is a point k/n with
    its two-sided interval as a bar; a cell without any is drawn as what it is, a bound: ▼ at its
    one-sided upper bound (``upper_one_sided``, named by ``bound``) with a dotted line down to the axis
    (the probability is somewhere below).
    A log scale because the curve's interest is where it falls off: 0.3 and 0.003 must both read."""
    fig, axes = subplots(1, len(metrics), figsize=inches(6 * len(metrics), 4.2), squeeze=False)
    xs, gs = np.asarray(x_values, dtype=float), list(groups)
    colours = matplotlib.colormaps.get_cmap("tab10")
    floor = _log_floor(cells, [m for m, _ in metrics])
    names = list(dict.fromkeys(gs))
    # groups side by side around each x value, so that equal bounds of two groups do not hide each other
    dodge = 0.012 * (float(np.ptp(xs)) or 1.0)
    for ax, (metric, title) in zip(axes[0], metrics, strict=True):
        for gi, group in enumerate(names):
            idx = sorted((i for i, g in enumerate(gs) if g == group and cells[i]["rates"].get(metric, {}).get("n")),
                         key=lambda i: xs[i])
            if idx:
                shift = (gi - (len(names) - 1) / 2) * dodge
                _draw_group(ax, xs[idx] + shift, [cells[i]["rates"][metric] for i in idx], colours(gi % 10),
                            group or "all cells", floor)
        ax.set_yscale("log")
        ax.set_ylim(floor, 1.0)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel(x_label or x_axis)
        ax.set_ylabel(f"probability, {level:.0%} interval")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8, loc="best")
    fig.suptitle(f"●: k/n with its two-sided {level:.0%} interval; ▼: no event, {bound} {level:.0%} upper bound "
                 "(a bound, not an estimate)", fontsize=9)
    fig.tight_layout()
    return save(fig, path)


def _log_floor(cells: Sequence[Mapping[str, Any]], metrics: Sequence[str]) -> float:
    """The bottom of the log axis: a third of the smallest positive number drawn (a lower interval end
    of a cell with events, or an upper bound of one without), at most 0.1."""
    drawn = [v for c in cells for m in metrics if (r := c["rates"].get(m)) and r.get("n")
             for v in ((r["low"], r["rate"]) if r["k"] else (r["upper_one_sided"],)) if v > 0]
    return min([0.1, *drawn]) / 3.0


def _draw_group(ax, x: np.ndarray, rates: Sequence[Mapping[str, Any]], colour, label: str, floor: float) -> None:
    """One group's cells: points with interval bars joined by a line where events occurred; bounds
    (▼ and a dotted line down) where none did."""
    seen = [j for j, r in enumerate(rates) if r["k"] > 0]
    zero = [j for j, r in enumerate(rates) if r["k"] == 0]
    if seen:
        est = np.array([rates[j]["rate"] for j in seen])
        low = np.array([max(rates[j]["low"], floor) for j in seen])
        high = np.array([rates[j]["high"] for j in seen])
        ax.errorbar(x[seen], est, yerr=[est - low, high - est], fmt="o-", color=colour, ms=4, lw=1.3, capsize=3,
                    label=label)
    if zero:
        bound = np.array([rates[j]["upper_one_sided"] for j in zero])
        ax.vlines(x[zero], floor, bound, colors=[colour], linestyles="dotted", lw=1.1)
        ax.plot(x[zero], bound, "v", color=colour, ms=6, label=None if seen else label)


def estimate_vs_axis(
    estimates: Sequence[Mapping[str, Any]],
    x_values: Sequence[float],
    groups: Sequence[str],
    path: Path,
    *,
    level: float,
    target: str,
    x_label: str,
) -> dict[str, int]:
    """The estimated rate of ``target`` per cell (one record per cell, in cell order, with
    ``estimate``, ``low`` and ``high``; an empty record for a cell not estimated) against
    ``x_values``, one line per group, with its interval as error bars on a log scale; a cell whose
    estimate is 0 shows its upper end as ▼ (a bound, not an estimate). Serves crude Monte Carlo
    (``summary.json`` ``estimates``) and the splitting and importance folders alike."""
    fig, ax = subplots(figsize=inches(7, 4.4))
    xs, gs = np.asarray(x_values, dtype=float), list(groups)
    colours = matplotlib.colormaps.get_cmap("tab10")
    lowest = 1.0
    for gi, group in enumerate(dict.fromkeys(gs)):
        idx = sorted((i for i, g in enumerate(gs) if g == group and _finite(estimates[i].get("estimate"))),
                     key=lambda i: xs[i])
        colour = colours(gi % 10)
        pos = [i for i in idx if estimates[i]["estimate"] > 0]
        if pos:
            est = np.array([estimates[i]["estimate"] for i in pos], dtype=float)
            low = np.array([max(_value(estimates[i].get("low"), 0.0), 1e-12) for i in pos])
            high = np.array([_value(estimates[i].get("high"), est[k]) for k, i in enumerate(pos)])
            ax.errorbar(xs[pos], est, yerr=[est - np.minimum(low, est), np.maximum(high, est) - est], fmt="o-",
                        color=colour, ms=4, lw=1.2, capsize=3, label=group or "all cells")
            lowest = min(lowest, float(np.minimum(low, est).min()))
        # an estimate of 0 shows its interval's upper end; one whose interval is [0, 0] has nothing to show
        zero = [i for i in idx if estimates[i]["estimate"] == 0 and _value(estimates[i].get("high"), 0.0) > 0]
        if zero:
            ax.plot(xs[zero], [estimates[i]["high"] for i in zero], "v", color=colour, ms=6,
                    label=None if pos else (group or "all cells"))
            lowest = min(lowest, min(estimates[i]["high"] for i in zero))
    if lowest >= 1.0:
        raise ValueError("no cell has an estimate")
    ax.set_yscale("log")
    ax.set_ylim(bottom=lowest / 3)
    ax.set_xlabel(x_label)
    ax.set_ylabel(f"P({target}) with {level:.0%} interval")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8, loc="best")
    ax.set_title(f"estimated P({target}); ▼: upper end where the estimate is 0", fontsize=9)
    fig.tight_layout()
    return save(fig, path)


def _finite(x: Any) -> bool:
    return x is not None and math.isfinite(float(x))


def _value(x: Any, default: float) -> float:
    """``x`` as a float, ``default`` where it is missing (None in JSON) or not finite."""
    return float(x) if _finite(x) else default


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
    fig, ax = subplots(figsize=size)
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
        if unsafe_cell(c):  # black, not red: it must show on the red end of the colour map too
            ax.add_patch(Rectangle((j - 0.46, i - 0.46), 0.92, 0.92, fill=False, edgecolor="black", lw=2.5, zorder=3))
            ax.text(j - 0.42, i - 0.40, "⚠", ha="left", va="top", fontsize=10, color="black", zorder=4)
    cmap = matplotlib.colormaps.get_cmap("RdYlGn" if higher_is_better else "RdYlGn_r").with_extremes(bad="white")
    im = ax.imshow(np.ma.masked_invalid(grid), cmap=cmap, vmin=0.0, vmax=1.0, aspect="auto")
    ax.set_xticks(range(len(col_labels)), tick_labels[1] if tick_labels else col_labels, fontsize=8)
    ax.set_yticks(range(len(row_labels)), tick_labels[0] if tick_labels else row_labels, fontsize=8)
    ax.set_xlabel(col_axis)
    ax.set_ylabel(row_axis)
    ax.set_title(title, fontsize=10)
    fig.colorbar(im, ax=ax, label=f"{metric.replace('_', ' ')} rate")
    fig.tight_layout(rect=(0, 0.25 / size[1], 1, 1))
    _unsafe_legend(fig, cells, "⚠ black outline: a cell with at least one unsafe episode")
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
    fig, axes = panel_grid(len(names), 4, 3.0, 2.3, sharex=True)
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
