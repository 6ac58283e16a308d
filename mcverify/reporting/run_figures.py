"""Which figures a run gets, drawn into ``RUN_DIR/figures/`` from stored data only.

Every run gets the rates per cell and the minimum-distance histograms. A grid with a numeric axis
of two or more values (ε, λ₀, a noise scale, ...) gets the rates against that axis with interval
bands; a grid over exactly two axes gets heat maps of the safe and overtaking rates with the counts
written in. Cells with a stored trajectory (``trajectories/episode-NNNNNN.parquet``, else
``replay/episode-NNNNNN.parquet`` from ``mcverify replay``; the lowest episode id of the cell) get
road snapshots, h(t) and speed profiles. A figure that cannot be drawn is listed with the reason.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from mcverify.analysis import summary
from mcverify.analysis.metrics import METRICS
from mcverify.model import kept_level
from mcverify.reporting import cell_figures, episode_figures, figure_common
from mcverify.reporting.paper_tables import pretty_label
from mcverify.reporting.tables import bound_name, method_name

FIGURES_DIR = "figures"
TRAJECTORY_DIRS = ("trajectories", "replay")
#: Most cells that get trajectory figures (snapshots are one file per cell).
MAX_TRAJECTORY_CELLS = 12

_EPISODE_FILE = re.compile(r"^episode-(\d+)\.parquet$")


@dataclass(frozen=True)
class FigureResult:
    """A figure of the report: ``file`` relative to the run folder (None when ``skipped`` says why
    it was not drawn), its ``title`` and ``caption``, and what was drawn (:func:`figure_common.artist_counts`)."""

    key: str
    title: str
    caption: str
    file: str | None = None
    skipped: str = ""
    drawn: Mapping[str, int] = field(default_factory=dict)


@dataclass(frozen=True)
class StoredEpisode:
    episode_id: int
    cell_index: int
    trajectory: str  # relative to the run folder
    plans: str | None


def find_trajectories(run_dir: Path, episode_cells: Mapping[int, int]) -> dict[int, StoredEpisode]:
    """Per cell index, the stored trajectory of its lowest episode id (``trajectories/`` first,
    then ``replay/``). ``episode_cells`` maps episode id -> cell index."""
    best: dict[int, tuple[int, int, StoredEpisode]] = {}  # cell -> (folder rank, episode id, file)
    for rank, sub in enumerate(TRAJECTORY_DIRS):
        folder = Path(run_dir) / sub
        if not folder.is_dir():
            continue
        for f in sorted(folder.iterdir()):
            m = _EPISODE_FILE.match(f.name)
            if not m or int(m.group(1)) not in episode_cells:
                continue
            eid = int(m.group(1))
            cell = episode_cells[eid]
            plans = folder / f"episode-{m.group(1)}-plans.parquet"
            here = StoredEpisode(eid, cell, f"{sub}/{f.name}", f"{sub}/{plans.name}" if plans.is_file() else None)
            if cell not in best or (rank, eid) < best[cell][:2]:
                best[cell] = (rank, eid, here)
    return {cell: entry[2] for cell, entry in sorted(best.items())}


def numeric_axes(cells: Sequence[Mapping[str, Any]], axes: Mapping[str, Sequence[str]]) -> dict[str, list[float]]:
    """Varying axes whose every cell has a numeric value (:func:`summary.axis_value`): axis ->
    value per cell."""
    out = {}
    for axis in axes:
        values = [summary.axis_value(c, axis) for c in cells]
        if all(v is not None for v in values):
            out[axis] = values
    return out


def sweep_axis(cells: Sequence[Mapping[str, Any]], axes: Mapping[str, Sequence[str]]) -> str | None:
    """The axis to plot rates against: ε, else λ₀, else the numeric axis with most values (>= 2: an ε
    sweep of two levels gets its figure too)."""
    numeric = numeric_axes(cells, axes)
    candidates = [a for a in numeric if len(axes[a]) >= 2]
    for preferred in ("epsilon", "lambda0"):
        if preferred in candidates:
            return preferred
    return max(candidates, key=lambda a: len(axes[a]), default=None)


def write_figures(
    run_dir: Path, summ: Mapping[str, Any], table: pa.Table, manifest: Mapping[str, Any]
) -> list[FigureResult]:
    """Draw every figure of the run into ``RUN_DIR/figures`` (old PNGs there are removed first)."""
    run_dir = Path(run_dir)
    out = run_dir / FIGURES_DIR
    out.mkdir(parents=True, exist_ok=True)
    for old in sorted(out.glob("*.png")) + sorted(out.glob("*.svg")) + sorted(out.glob("*.pdf")):
        old.unlink()
    cells = summ["cells"]
    axes = summ["axes"]
    level = summ["confidence_level"]
    results: list[FigureResult] = []

    def draw(key: str, heading: str, caption: str, fn, *args, **kw) -> None:
        rel = f"{FIGURES_DIR}/{key}.png"
        try:
            drawn = fn(*args, out / f"{key}.png", **kw)
        except ValueError as err:  # nothing to draw (e.g. no finite value): say so
            results.append(FigureResult(key, heading, caption, None, f"not drawn: {err}"))
            return
        results.append(FigureResult(key, heading, caption, rel, "", drawn))

    if not cells:
        return [FigureResult("rates", "Rates per cell", "", None, "not drawn: the run has no cell")]
    if len(cells) > figure_common.MAX_PANELS:
        results.append(FigureResult("rates", "Rates per cell", "", None,
                                    f"not drawn: {len(cells)} cells, more than {figure_common.MAX_PANELS}"))
    else:
        draw("rates", "Rates per cell",
             f"Left: safe, collision and ellipse-violation rates per cell (points) with their two-sided {level:.0%} "
             f"{method_name(summ['interval_method'])} intervals (bars). Right: share of the cell's episodes by "
             "outcome, with counts.",
             cell_figures.rates_per_cell, cells)

    x_axis = sweep_axis(cells, axes)
    if x_axis:
        others = [a for a in axes if a != x_axis]
        groups = [", ".join(pretty_label(a, c["labels"].get(a, "")) for a in others) for c in cells]
        metrics = [(m, METRICS[m].label) for m in ("collision", "ellipse_violation", "invariance_breach")
                   if any(m in c["rates"] for c in cells)]
        x_label = {"epsilon": "level ε of the VL-CBF", "lambda0": "λ₀"}.get(x_axis, x_axis)
        draw(f"rate-vs-{x_axis}", f"Probabilities against {x_label}",
             f"Probability per cell against {x_label} (log scale), one line per {', '.join(others) or 'campaign'}: "
             f"a point is k/n with its two-sided {level:.0%} {method_name(summ['interval_method'])} interval; ▼ with "
             f"a dotted line marks a cell without any event at {bound_name(summ['interval_method'])} {level:.0%} upper "
             "bound.",
             cell_figures.rate_vs_axis, cells, x_axis, numeric_axes(cells, axes)[x_axis], groups, metrics,
             level=level, x_label=x_label, bound=bound_name(summ["interval_method"]).removeprefix("the "))

    est = summ.get("estimates")
    if x_axis and est:  # a run of `mcverify estimate`: its estimates against the sweep axis
        spec = est["spec"]
        x_label = {"epsilon": "level ε of the VL-CBF", "lambda0": "λ₀"}.get(x_axis, x_axis)
        by_index = {e["cell_index"]: e for e in est["cells"]}
        others = [a for a in axes if a != x_axis]
        groups = [", ".join(pretty_label(a, c["labels"].get(a, "")) for a in others) for c in cells]
        draw(f"estimate-vs-{x_axis}", f"Estimated {spec['target']} probability against {x_label}",
             f"{est['method_description']}; the bars are the anytime-valid {spec['level']:.0%} interval at the "
             "stopping episode (log scale), ▼ the interval's upper end where no event occurred.",
             cell_figures.estimate_vs_axis, [by_index.get(c["cell_index"], {}) for c in cells],
             numeric_axes(cells, axes)[x_axis], groups, level=float(spec["level"]), target=spec["target"],
             x_label=x_label)

    if len(axes) == 2:
        a, b = list(axes)
        row_axis, col_axis = (a, b) if len(axes[a]) >= len(axes[b]) else (b, a)
        for metric, better in (("safe", True), ("overtook", True)):
            label = METRICS[metric].label
            draw(f"heatmap-{metric}", f"{label.capitalize()} rate per {row_axis} × {col_axis}",
                 f"Colour: {label} rate; each square: k/n and the two-sided {level:.0%} "
                 f"{method_name(summ['interval_method'])} interval (≥ l or ≤ u: {bound_name(summ['interval_method'])} "
                 "bound when every or no episode counts).",
                 cell_figures.rate_heatmap, cells, row_axis, axes[row_axis], col_axis, axes[col_axis], metric,
                 title=f"{label} rate", higher_is_better=better,
                 tick_labels=([pretty_label(row_axis, x) for x in axes[row_axis]],
                              [pretty_label(col_axis, x) for x in axes[col_axis]]))

    _histograms(cells, table, draw)
    results += _trajectory_figures(run_dir, cells, table, manifest, out)
    return results


def _histograms(cells: Sequence[Mapping[str, Any]], table: pa.Table, draw) -> None:
    if len(cells) > figure_common.MAX_PANELS:
        return
    idx = np.asarray(table.column("cell_index").to_numpy()) if table.num_rows else np.zeros(0)
    valid = np.array([o != "error" for o in table.column("outcome").to_pylist()]) if "outcome" in table.column_names \
        else np.ones(table.num_rows, dtype=bool)
    specs = (
        ("min-dist-front", "min_dist_front_m", "Minimum distance to the front vehicle's safety ellipse per cell",
         "min dist. with veh_f (m)", 0.0, "ellipse boundary",
         "Histogram per cell of the per-episode minimum signed distance from the ego c.g. to the safety ellipse "
         "h_ef = 0 (the paper's \"min dist. with veh_f\"); the dotted line is the ellipse, negative is inside."),
        ("min-gap-opp", "min_gap_opp_m", "Minimum distance to the opposing vehicle per cell",
         "min dist. with veh_o (m)", 0.0, "contact",
         "Histogram per cell of the per-episode minimum bumper gap to the opposing vehicle while the ego reached "
         "into the opposing lane (the paper's \"min dist. with veh_o\"); episodes that never did have no value."),
    )
    for key, col, title, xlabel, boundary, blabel, caption in specs:
        if col not in table.column_names or not any(col in c["values"] for c in cells):
            continue  # e.g. no opposing vehicle in any cell
        x = np.array([np.nan if v is None else float(v) for v in table.column(col).to_pylist()], dtype=float)
        samples = [x[(idx == c["cell_index"]) & valid] for c in cells]
        draw(key, title, caption, cell_figures.distance_histograms, [c["cell"] for c in cells], samples,
             x_label=xlabel, boundary=boundary, boundary_label=blabel)


def _trajectory_figures(
    run_dir: Path, cells: Sequence[Mapping[str, Any]], table: pa.Table, manifest: Mapping[str, Any], out: Path
) -> list[FigureResult]:
    results: list[FigureResult] = []
    ids = table.column("episode_id").to_pylist() if table.num_rows else []
    cidx = table.column("cell_index").to_pylist() if table.num_rows else []
    stored = find_trajectories(run_dir, dict(zip(ids, cidx, strict=True)))
    params = {int(c["index"]): c.get("params") for c in manifest.get("cells", [])}
    rows = {eid: i for i, eid in enumerate(ids)}
    if not stored:
        return [FigureResult("trajectories", "Trajectory snapshots, h(t) and speed profiles", "", None,
                             "not drawn: no stored trajectory in trajectories/ or replay/ (`mcverify replay RUN_DIR "
                             "EPISODE_ID` stores one)")]
    chosen = [c for c in cells if c["cell_index"] in stored][:MAX_TRAJECTORY_CELLS]
    without = [c["cell"] for c in cells if c["cell_index"] not in stored]
    beyond = [c["cell"] for c in cells if c["cell_index"] in stored][MAX_TRAJECTORY_CELLS:]
    series_h, series_opp, series_v = [], [], []
    for c in chosen:
        ep = stored[c["cell_index"]]
        traj = figure_common.load_table(run_dir / ep.trajectory)
        plans = figure_common.load_table(run_dir / ep.plans) if ep.plans else None
        p = figure_common.params_dict(params.get(c["cell_index"]))
        row = table.slice(rows[ep.episode_id], 1).to_pylist()[0]
        key = f"snapshots-cell-{c['cell_index']:03d}"
        head = f"{c['cell']} · episode {ep.episode_id} · {row.get('outcome')} · safe = {row.get('safe')}"
        needed = ("t_s", "ego_x_m", "ego_y_m", "front_x_m")
        if traj is None or any(n not in traj for n in needed) or len(traj["t_s"]) == 0:
            results.append(FigureResult(key, f"Snapshots: {c['cell']}", "", None,
                                        f"not drawn: {ep.trajectory} lacks one of {', '.join(needed)}"))
            continue
        plan_note = (f"planned Q1 (green dots) and Q2 (orange dots) trajectories from {ep.plans}, in road "
                     f"coordinates: veh_f is drawn where it is at that time and moves on along the plan, so a Q2 "
                     f"plan drawn past veh_f still ends behind where the planner predicts veh_f will be"
                     if plans is not None else "planned trajectories not stored for this episode (no plans file)")
        try:
            drawn = episode_figures.snapshots(traj, plans, p, out / f"{key}.png", title=head)
            results.append(FigureResult(
                key, f"Snapshots: {c['cell']}",
                f"Episode {ep.episode_id} ({ep.trajectory}) at up to five times, drawn to scale: ego (green), veh_f "
                f"(red) with its safety ellipse (dashed), veh_o (blue) if any, each as its footprint, the ego's path "
                f"so far (black); {plan_note}; blue dots: veh_o's predicted trajectory where stored. An unsafe "
                f"episode gets one more panel, framed in red, at its first unsafe moment with its cause.",
                f"{FIGURES_DIR}/{key}.png", "", drawn))
        except (KeyError, ValueError) as err:
            results.append(FigureResult(key, f"Snapshots: {c['cell']}", "", None, f"not drawn: {err}"))
        title = f"{c['cell']} · episode {ep.episode_id}"
        if figure_common.column(traj, "h_front") is not None:
            series_h.append((title, traj, kept_level(p["mpc"]["controller"], float(c["epsilon"]))))
        if figure_common.column(traj, "h_opp") is not None:
            series_opp.append((title, traj, float(p["barrier"]["opp_epsilon_m"])))
        series_v.append((title, traj, float(p["ego"]["speed_max_mps"])))
    notes = []
    if without:
        notes.append(f"no stored trajectory for {len(without)} cell(s): {'; '.join(without)}")
    if beyond:
        notes.append(f"only the first {MAX_TRAJECTORY_CELLS} cells with a trajectory are drawn; left out: "
                     f"{'; '.join(beyond)}")
    note = (" (" + "; ".join(notes) + ")") if notes else ""
    for key, title, series, caption, fn, kw in (
        ("barrier-h-ef", "h_ef(t) against its level ε", series_h,
         "h_ef along the true trajectory of each cell's stored episode, against the level ε (dashed; none for "
         "plain MPC-DC, which keeps h ≥ 0) and the ellipse h = 0 (dotted); the view is clipped above; background: "
         "what drove the ego (Q1 green, Q2 orange, fallback red, a held MPC-DC plan purple; MPC-DC's own plans "
         "count as Q1)." + note,
         episode_figures.barrier_series, {}),
        ("barrier-h-eo", "h_eo(t) against its level", series_opp,
         "h_eo (m) while the ego borrows the opposing lane, against its level (dashed)." + note,
         episode_figures.barrier_series, {"opp": True}),
        ("speeds", "Speed profiles", series_v,
         "Speeds of the ego (green), front (red; measured, faint) and opposing (blue) vehicles in each cell's stored "
         "episode, with the ego's speed limit (dotted)." + note, episode_figures.speed_profiles, {}),
    ):
        if not series:
            if key != "barrier-h-eo":
                results.append(FigureResult(key, title, caption, None, "not drawn: the stored trajectories lack the "
                                            "columns it needs"))
            continue
        results.append(FigureResult(key, title, caption, f"{FIGURES_DIR}/{key}.png", "",
                                    fn(series, out / f"{key}.png", **kw)))
    return results
