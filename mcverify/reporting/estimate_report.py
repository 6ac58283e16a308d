"""What an estimate folder of the splitting or importance method shows besides its table: the
estimates against the campaign's sweep axis (P(target) against ε on ``eps_sweep_rare``, say) and the
self-contained ``report.html``.

Everything here reads the folder's records (the manifest's cells, the cell results of
``estimate.json``), never the simulation, so the report is rebuilt from stored data alone.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from mcverify.analysis import summary
from mcverify.reporting import cell_figures, html
from mcverify.reporting.run_figures import FIGURES_DIR, FigureResult, numeric_axes, sweep_axis
from mcverify.reporting.tables import Table, to_markdown

#: Axis names the figure's x label spells out.
AXIS_LABELS = {"epsilon": "level ε of the VL-CBF", "lambda0": "λ₀"}


def estimate_figure(out: Path, manifest_cells: Sequence[Mapping[str, Any]], results: Sequence[Mapping[str, Any]],
                    *, method: str, target: str, level: float) -> FigureResult | None:
    """Draw ``figures/estimate-vs-AXIS.png``: each estimated cell's estimate and interval against the
    campaign's sweep axis (ε, else λ₀, else the numeric axis with the most values), one line per
    value of the other axes. None when the campaign has no such axis (one cell, or no numeric axis)."""
    axes = summary.varying_axes(manifest_cells)
    x_axis = sweep_axis(manifest_cells, axes)
    if not x_axis:
        return None
    by_index = {int(r["cell_index"]): r for r in results}
    others = [a for a in axes if a != x_axis]
    groups = [", ".join(f"{a}={c['labels'].get(a, '')}" for a in others) for c in manifest_cells]
    x_label = AXIS_LABELS.get(x_axis, x_axis)
    key = f"estimate-vs-{x_axis}"
    interval = next((str(r["interval"]) for r in results if r.get("interval")), "the estimator's interval")
    title = f"Estimated {target} probability against {x_label}"
    caption = (f"{method}: the estimate of each estimated cell (points) with its {level:.0%} interval, {interval} "
               "(bars, log scale); ▼ the interval's upper end where the estimate is 0. Cells not estimated yet are "
               "left out.")
    path = Path(out) / FIGURES_DIR / f"{key}.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        drawn = cell_figures.estimate_vs_axis([by_index.get(int(c["index"]), {}) for c in manifest_cells],
                                              numeric_axes(manifest_cells, axes)[x_axis], groups, path,
                                              level=level, target=target, x_label=x_label)
    except ValueError as err:  # nothing to draw yet (no cell estimated, or every estimate is missing)
        path.unlink(missing_ok=True)
        return FigureResult(key, title, caption, None, f"not drawn: {err}")
    return FigureResult(key, title, caption, f"{FIGURES_DIR}/{key}.png", "", drawn)


def markdown(title: str, intro: str, table: Table, figures: Sequence[FigureResult]) -> str:
    """``report.md``: the title, the estimator's description, the table, the figures with captions."""
    lines = [f"# {title}", "", intro, "", to_markdown(table, heading="##")]
    for f in figures:
        lines += ["", f"## {f.title}", ""]
        lines += [f"![{Path(f.file).stem}]({f.file})", "", f.caption] if f.file else [f.skipped]
    return "\n".join(lines) + "\n"


def html_page(out: Path, title: str, facts: Sequence[tuple[str, str]], table: Table,
              figures: Sequence[FigureResult]) -> str:
    """``report.html``: the facts, the table and the figures embedded (:func:`mcverify.reporting.html.render`)."""
    definitions = [
        ("estimate", "the estimator's value of P(target) in the cell; not a count of episodes"),
        ("interval", "the two-sided interval the estimator gives at the folder's level; its kind (asymptotic, "
                     "Student t on independent runs, normal on a weighted sample) is named in the table's notes"),
        ("control steps", "the closed-loop control steps simulated for the cell, the cost the crude comparison uses"),
    ]
    return html.render(out, facts, [table], figures, definitions, title=title)
