"""A run's report, regenerated from stored data only: ``mcverify report RUN_DIR``.

:func:`write` reads ``manifest.json`` and ``episodes.parquet`` (and any stored trajectories) and
writes, without re-simulating anything:

- ``summary.json``: per-cell statistics (:func:`mcverify.analysis.summary.summarise`), strict JSON (a
  statistic that does not exist is ``null``);
- ``cells.parquet``: the same statistics, one row per cell (:func:`mcverify.analysis.cells.cells_table`);
- ``tables/<key>.md`` and ``tables/<key>.tex``: every table in Markdown and LaTeX (booktabs), the
  paper-style table first when the campaign's ``[reference]`` names one (``paper_tables``);
- ``figures/*.png`` (``report_figures``);
- ``counterexamples.parquet``: every unsafe episode, worst first, with its inputs, margins, first
  unsafe time and cause and replay command (:mod:`mcverify.analysis.counterexamples`), also a table
  of the report with the worst ones drawn (:mod:`~mcverify.reporting.counterexample_report`);
- ``report.md``: the tables, the figures and the definitions; ``report.html``: the same as one
  self-contained page (figures embedded).

The output is a pure function of the stored data and the options: the bootstrap is seeded, no
timestamp or absolute path is rendered, the figures carry fixed metadata, so writing twice gives
the same bytes (``tests/reporting/test_report.py``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from mcverify import files, store
from mcverify.analysis import counterexamples, estimates, stats, summary
from mcverify.analysis.cells import cells_table, json_ready
from mcverify.analysis.columns import Columns, floats
from mcverify.analysis.metrics import METRICS, RATE_METRICS, RATE_NAMES, VALUE_METRICS
from mcverify.analysis.sequential import CONFIDENCE_SEQUENCE
from mcverify.errors import RunError
from mcverify.reporting import counterexample_report, figure_common, html, paper_tables, run_figures
from mcverify.reporting.check_tables import (
    end_state_table,
    findings_table,
    limits_table,
    rate_note,
    solver_table,
    stat_text,
    theorem_table,
    value_of,
)
from mcverify.reporting.run_figures import FigureResult
from mcverify.reporting.tables import (
    DASH,
    Table,
    bound_name,
    fmt_mean_ci,
    fmt_rate,
    method_name,
    to_latex,
    to_markdown,
)

REPORT = "report.md"
HTML = "report.html"
SUMMARY = "summary.json"
CELLS = "cells.parquet"
TABLES_DIR = "tables"

#: The two-sided interval of a fixed-count run's rates.
DEFAULT_METHOD = "clopper-pearson"

#: Kept for callers of the former module: a reference quantity's value in a cell summary.
lookup = paper_tables.lookup


@dataclass(frozen=True)
class Options:
    """How the statistics are computed: two-sided ``level`` and ``method`` of every rate interval
    (``stats.PROPORTION_METHODS``; None: the folder's own, :meth:`for_folder`) and the bootstrap of
    every mean."""

    level: float | None = None
    method: str | None = None
    bootstrap_resamples: int = 2000
    bootstrap_seed: int = 0

    def check(self) -> Options:
        try:
            stats.rate_summary(0, 1, 0.95 if self.level is None else self.level, self.method or DEFAULT_METHOD)
        except ValueError as err:
            raise RunError(f"report options: {err}") from None
        if self.bootstrap_resamples < 1:
            raise RunError(f"report options: bootstrap resamples must be >= 1, got {self.bootstrap_resamples}")
        return self

    def for_folder(self, manifest: Mapping[str, Any]) -> Options:
        """The options with the folder's interval: a fixed-count run's rates get the exact interval (or
        the ``method`` asked for) at ``level`` (default 0.95); an estimate folder's rates get its
        estimator's anytime-valid interval at the estimate's level, the only one valid at its
        data-dependent episode count, and another ``method`` or ``level`` is refused."""
        raw = manifest.get("estimate")
        if not raw:
            return replace(self, level=0.95 if self.level is None else self.level,
                           method=self.method or DEFAULT_METHOD)
        level = float(raw.get("level", 0.95))
        if self.method not in (None, CONFIDENCE_SEQUENCE):
            raise RunError("an estimate folder's rates use its estimator's anytime-valid interval (a confidence "
                           "sequence); --method chooses the interval of a fixed-count run (mcverify run)")
        if self.level is not None and abs(self.level - level) > 1e-12:
            raise RunError(f"this estimate ran at level {level:g} and its rates keep it; --level applies to "
                           "fixed-count runs (mcverify run)")
        return replace(self, level=level, method=CONFIDENCE_SEQUENCE)


def write(
    run_dir: Path,
    *,
    level: float | None = None,
    method: str | None = None,
    bootstrap_resamples: int = 2000,
    bootstrap_seed: int = 0,
    figure_formats: Sequence[str] = (),
    figure_dpi: int = figure_common.DPI,
) -> Path:
    """Regenerate every report file of a finished run folder; returns the path of ``report.md``.

    level / method: the rates' interval of a fixed-count run (default 0.95, exact Clopper-Pearson); an
    estimate folder keeps its estimator's (:meth:`Options.for_folder`).
    figure_formats / figure_dpi: also write every figure as png, svg or pdf at that dpi, for papers
    (:func:`mcverify.reporting.figure_common.exporting`); the PNGs the report embeds do not change.

    Raises :class:`RunError` (one line for the user) when the folder is not a run folder or
    an option is out of range."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise RunError(f"run folder not found: {run_dir}")
    opts = Options(level, method, bootstrap_resamples, bootstrap_seed).check()
    manifest = store.read_json(run_dir / store.MANIFEST)
    opts = opts.for_folder(manifest)
    table = store.read_episodes(run_dir)
    summ = build_summary(manifest, table, opts)
    tables = report_tables(summ, manifest, str(run_dir))
    if not 10 <= figure_dpi <= 1200:
        raise RunError(f"--dpi must be between 10 and 1200, got {figure_dpi}")
    with figure_common.exporting(figure_formats, figure_dpi):
        figs = run_figures.write_figures(run_dir, summ, table, manifest)
    # Counterexamples (issue 19.4): every unsafe episode, worst first, with its replay command.
    cx_records = counterexamples.counterexamples(table, manifest, str(run_dir),
                                                 trajectory=lambda eid: store.read_trajectory(run_dir, eid))
    audits_path = run_dir / store.AUDITS
    audits = store.read_json(audits_path) if audits_path.is_file() else None
    tables.append(counterexample_report.table(cx_records, "safe", table.num_rows, audits=audits,
                                              run_dir=str(run_dir)))
    with figure_common.exporting(figure_formats, figure_dpi):
        figs = [*figs, *counterexample_report.figures(run_dir, cx_records, manifest)]
    _write_parquet(run_dir / counterexample_report.FILE, counterexamples.to_arrow(cx_records))

    files.write_json_atomic(run_dir / SUMMARY, json_ready(summ))
    _write_parquet(run_dir / CELLS, cells_table(summ))
    tdir = run_dir / TABLES_DIR
    tdir.mkdir(exist_ok=True)
    for old in sorted(tdir.glob("*.md")) + sorted(tdir.glob("*.tex")):
        old.unlink()
    for t in tables:
        _write_text(tdir / f"{t.key}.md", to_markdown(t) + "\n")
        _write_text(tdir / f"{t.key}.tex", to_latex(t) + "\n")
    _write_text(run_dir / REPORT, render_markdown(manifest, summ, tables, figs))
    _write_text(run_dir / HTML, html.render(run_dir, facts(manifest, summ), tables, figs, definitions(summ),
                                                   title=_title(manifest)))
    return run_dir / REPORT


def build_summary(manifest: Mapping[str, Any], table: pa.Table, opts: Options = Options()) -> dict[str, Any]:
    """:func:`summary.summarise` of the run, with the campaign's name. For a run of ``mcverify estimate``
    every statistic is over the episodes the estimate used (each cell's episodes up to its stopping
    episode, in episode order; those run after it are cost, counted in ``episodes_run``) and every rate
    carries the estimator's anytime-valid interval, so that the estimate's target reads the same in
    every table, figure and file."""
    opts = opts.for_folder(manifest)
    est = estimates.estimate_summary(table, manifest)
    used = table if est is None else used_episodes(table, est["cells"])
    summ = summary.summarise(
        used,
        manifest,
        level=opts.level,
        method=opts.method,
        bootstrap_resamples=opts.bootstrap_resamples,
        bootstrap_seed=opts.bootstrap_seed,
        **({} if est is None else {"prior": tuple(est["spec"]["prior"])}),
    )
    out = {"campaign": manifest["campaign"]["name"], **summ}
    if est is not None:  # a run of `mcverify estimate`
        out["episodes_run"] = int(table.num_rows)
        out["estimates"] = est
    return out


def used_episodes(table: pa.Table, cells: Sequence[Mapping[str, Any]]) -> pa.Table:
    """The rows an estimate used: per cell those with a cell-local episode id below its
    ``episodes_used``, sorted by cell and episode id."""
    if not table.num_rows:
        return table
    cols = Columns.from_table(table)
    limit = {int(c["cell_index"]): int(c["episodes_used"]) for c in cells}
    idx, ep = floats(cols, "cell_index").astype(int), floats(cols, "cell_episode").astype(int)
    keep = [i for i in np.lexsort((ep, idx)) if ep[i] < limit.get(int(idx[i]), 0)]
    return table.take(pa.array(keep, type=pa.int64()))


# ----------------------------------------------------------------------------------------- tables


def report_tables(summ: Mapping[str, Any], manifest: Mapping[str, Any], run_dir: str = "RUN_DIR") -> list[Table]:
    """Every table of the report, in order: the paper's layout (if the campaign names one), the
    outcomes, the pivot tables of a two-axis grid, distances, times, theorem checks, decisions and
    solver; ``run_dir`` (as given) goes into the replay commands, as in the counterexample table."""
    out: list[Table] = []
    if summ.get("estimates"):
        out.append(estimate_table(summ["estimates"]))
    ref = manifest["campaign"].get("reference") or {}
    if ref:
        paper = paper_tables.paper_table(summ, ref)
        if paper is not None:
            out.append(paper)
    out.append(outcome_table(summ))
    out += pivot_tables(summ)
    out += [distance_table(summ), time_table(summ), theorem_table(summ)]
    findings = findings_table(summ, run_dir)
    out += ([findings] if findings is not None else []) + [solver_table(summ)]
    out += [t for t in (end_state_table(summ), limits_table(summ)) if t is not None]
    return out


def estimate_table(est: Mapping[str, Any]) -> Table:
    """The estimate of the target's rate per cell (``mcverify estimate``): estimate, anytime-valid
    interval, episodes used and run, and the cost in control steps and solver time."""
    spec = est["spec"]
    level = float(spec["level"])
    columns = ["cell", "status", "k / n", "estimate", f"{level:.0%} interval", "half-width", "episodes run",
               "control steps run", "solver time (s)"]
    rows = []
    for c in est["cells"]:
        rows.append([c["cell"], c["status"], f"{c['k']} / {c['n']}",
                     DASH if c["n"] == 0 else f"{c['estimate']:.4g}", f"[{c['low']:.4g}, {c['high']:.4g}]",
                     f"{c['halfwidth']:.3g}", str(c["episodes_run"]), f"{c['steps_run']:.0f}",
                     f"{c['solver_time_s']:.1f}"])
    width = DASH if spec.get("halfwidth") is None else (
        f"{spec['halfwidth']:g}" + (" x estimate" if spec.get("relative") else ""))
    notes = [
        f"Target: {spec['target']}: {est['target_definition']}. Method: {est['method_description']}; "
        f"stop at half-width <= {width} or after {spec['budget']} episodes per cell.",
        "The interval is a confidence sequence (prior Beta"
        f"({spec['prior'][0]:g}, {spec['prior'][1]:g})): it keeps its coverage at the data-dependent stopping "
        "episode, which a fixed-count interval such as Clopper-Pearson would not; every rate of this report (tables, "
        "figures, summary.json, cells.parquet) carries the same kind of interval, over the same episodes. Episodes "
        "are taken in their pre-assigned order; episodes run after the stopping episode count as cost only (in "
        "episodes run, not in any statistic). Solver time: solves x mean solve time, machine-dependent.",
    ]
    return Table("estimates", f"Estimated {spec['target']} rate per cell", columns, rows, notes)


def outcome_table(summ: Mapping[str, Any]) -> Table:
    """Rates per cell: safe, collisions, ellipse violation, invariance breach, outcomes, errors."""
    cells = summ["cells"]
    has = {m: any(m in c["rates"] for c in cells) for m in RATE_NAMES}
    names = ["safe"]
    if has["collision_opp"]:
        names += ["collision_front", "collision_opp"]
    else:
        names += ["collision_front"]
    names += ["ellipse_violation", "invariance_breach", "opp_invariance_breach", "overtook", "went_back", "timeout"]
    names = [n for n in names if has.get(n)]
    errors = any(c["rates"]["error"]["k"] for c in cells)
    columns = ["cell", "episodes", *(METRICS[n].label for n in names)] + (["errors"] if errors else [])
    rows = []
    for c in cells:
        row = [c["cell"], str(c["valid"])] + [fmt_rate(c["rates"].get(n)) for n in names]
        if errors:
            row.append(fmt_rate(c["rates"]["error"]))
        rows.append(row)
    notes = [rate_note(summ), "Rates are over the episodes that ran; an episode that could not be simulated "
             "(outcome error) is counted apart, as a rate over all of the cell's episodes."]
    return Table("outcomes", "Safety and outcomes per cell", columns, rows, notes)


def pivot_tables(summ: Mapping[str, Any]) -> list[Table]:
    """For a grid over exactly two axes: safe, collision, ellipse-violation and overtaking rates
    with rows = the axis with more values and columns = the other."""
    axes = summ["axes"]
    if len(axes) != 2:
        return []
    a, b = list(axes)
    row_axis, col_axis = (a, b) if len(axes[a]) >= len(axes[b]) else (b, a)
    by_labels = {(c["labels"].get(row_axis), c["labels"].get(col_axis)): c for c in summ["cells"]}
    out = []
    for metric in ("safe", "collision", "ellipse_violation", "overtook"):
        if not any(metric in c["rates"] for c in summ["cells"]):
            continue
        rows = []
        for r in axes[row_axis]:
            row = [paper_tables.pretty_label(row_axis, r)]
            for col in axes[col_axis]:
                cell = by_labels.get((r, col))
                row.append(fmt_rate(cell["rates"].get(metric)) if cell else DASH)
            rows.append(row)
        label = METRICS[metric].label
        out.append(Table(f"pivot-{metric}", f"{label.capitalize()} rate per {row_axis} and {col_axis}",
                         [f"{row_axis} \\ {col_axis}", *(paper_tables.pretty_label(col_axis, x) for x in axes[col_axis])],
                         rows, [rate_note(summ)]))
    return out


def distance_table(summ: Mapping[str, Any]) -> Table:
    """Minimum distances per cell: to the front ellipse (min, 5 %, median, mean), the footprint gap,
    min h_ef, and to the opposing vehicle when the run has it."""
    cells = summ["cells"]
    opp = any(c["values"].get("min_gap_opp_m", {}).get("count") for c in cells)
    columns = ["cell", "min dist. veh_f: min (m)", "5 % quantile", "median", "mean [CI]", "min gap veh_f (m)",
               "min h_ef"]
    any_time = opp and any(c["values"].get("min_gap_opp_any_m", {}).get("count") for c in cells)
    if opp:
        columns += ["min dist. veh_o: min (m)", "median", "episodes in opp. lane"]
    if any_time:
        columns += ["min gap veh_o, any time (m)"]
    rows = []
    for c in cells:
        d = value_of(c, "min_dist_front_m")
        row = [c["cell"], stat_text(d, "min"), stat_text(d, "q5"), stat_text(d, "q50"), fmt_mean_ci(d),
               stat_text(value_of(c, "min_gap_front_m"), "min"), stat_text(value_of(c, "min_h_front"), "min", 3)]
        if opp:
            o = value_of(c, "min_gap_opp_m")
            row += [stat_text(o, "min"), stat_text(o, "q50"), str(o["count"]) if o else DASH]
        if any_time:
            row += [stat_text(value_of(c, "min_gap_opp_any_m"), "min")]
        rows.append(row)
    notes = ["min dist. veh_f is the paper's \"min dist. with veh_f\": signed distance from the ego c.g. to the safety "
             "ellipse, negative inside; the min column is the smallest over the cell's episodes, the others describe "
             "the per-episode minima (mean with its percentile-bootstrap interval)."]
    if opp:
        notes.append("min dist. veh_o is the paper's \"min dist. with veh_o\": bumper gap to the opposing vehicle while "
                     "the ego reaches into the opposing lane; episodes that never did have no value.")
    return Table("distances", "Minimum distances per cell", columns, rows, notes)


def time_table(summ: Mapping[str, Any]) -> Table:
    """Overtaking and lane-borrow times per cell (min / mean [CI] / max, as in the paper's Table II)."""
    columns = ["cell", "overtakes", "overtake time min (s)", "mean [CI] (s)", "max (s)", "lane borrows",
               "lane-borrow time min (s)", "mean [CI] (s)", "max (s)"]
    rows = []
    for c in summ["cells"]:
        ot, lb = value_of(c, "overtake_time_s"), value_of(c, "lane_borrow_time_s")
        rows.append([c["cell"], str(ot["count"]) if ot else DASH, stat_text(ot, "min"), fmt_mean_ci(ot), stat_text(ot, "max"),
                     str(lb["count"]) if lb else DASH, stat_text(lb, "min"), fmt_mean_ci(lb), stat_text(lb, "max")])
    notes = ["Overtake time: from the episode start to the paper's convergence test, over overtaking episodes only. "
             "Lane-borrow time: while the ego footprint reaches into the opposing lane, over every episode that did "
             "(\"lane borrows\": those that went back included, so in a cell with turn-backs it is not the overtakes' "
             "lane-borrow time that the paper's Table II reports). Means carry their percentile-bootstrap interval."]
    return Table("times", "Overtaking times per cell", columns, rows, notes)


# ------------------------------------------------------------------------------------- markdown


def _title(manifest: Mapping[str, Any]) -> str:
    return f"mcverify report: {manifest['campaign']['name']}"


def facts(manifest: Mapping[str, Any], summ: Mapping[str, Any]) -> list[tuple[str, str]]:
    """The run's identity as (label, text) pairs: no timestamp and no absolute path."""
    camp = manifest["campaign"]
    cells = summ["cells"]
    controllers = sorted({str(c.get("controller")) for c in cells})
    kernels = sorted({str(h)[:12] for h in (manifest.get("kernels") or {}).values()})
    axes = summ["axes"]
    source = Path(str(camp.get("source", ""))).name or DASH
    out = [
        ("campaign", f"{camp['name']} ({source})"),
        ("description", " ".join(str(camp.get("description") or DASH).split())),
        ("episodes", (f"{summ['episodes']} used by the estimate ({summ['episodes_run']} run)" if "episodes_run" in summ
                      else str(summ["episodes"])) + f" in {len(cells)} cell(s)"),
        ("grid", "; ".join(f"{a}: {', '.join(v)}" for a, v in axes.items()) or "one cell"),
        ("seed", f"{camp.get('seed')} (common random numbers: {'yes' if camp.get('common_random_numbers') else 'no'})"),
    ]
    if camp.get("settings"):  # what the command line changed from the file (--set)
        out.append(("settings", "--set " + ", --set ".join(f"`{s}`" for s in camp["settings"])))
    out += [
        ("controllers", ", ".join(controllers)),
        ("intervals", f"two-sided {summ['confidence_level']:.0%} {method_name(summ['interval_method'])} for rates; "
                      f"{bound_name(summ['interval_method'])} bound when no or every episode "
                      "counts; percentile bootstrap "
                      f"({summ['bootstrap']['resamples']} resamples, seed {summ['bootstrap']['seed']}) for means"),
        ("code", f"git {(manifest.get('environment') or {}).get('git_commit') or DASH}; kernels "
                 f"{', '.join(kernels) or DASH}"),
    ]
    return out


def definitions(summ: Mapping[str, Any]) -> list[tuple[str, str]]:
    """(term, definition) for every metric the report shows, and the theorem checks."""
    shown = {m for c in summ["cells"] for m in c["rates"]} | {m for c in summ["cells"] for m in c["values"]}
    out = [(m.label, m.definition) for m in RATE_METRICS + VALUE_METRICS if m.name in shown]
    out += [
        ("Thm 2 (invariance)", "an invariance breach contradicts Theorem 2 (h ≥ ε is forward invariant under the "
                               "VL-CBF); with perception noise and sampling it can happen, which is what is measured"),
        ("Thm 5 (one-in-two feasibility)", "steps where neither applicable problem (Q1 while overtaking, Q2) solved; "
                                           "the ego then holds its last plan or brakes towards its lane; only a step "
                                           "where IPOPT certified both infeasible contradicts the theorem (up to local "
                                           "infeasibility), the others are solver budgets or numerical failures"),
        ("error", "the episode could not be simulated; it is counted apart and not in any safety rate"),
    ]
    return out


def render_markdown(
    manifest: Mapping[str, Any], summ: Mapping[str, Any], tables: Sequence[Table], figs: Sequence[FigureResult]
) -> str:
    """report.md: the run's facts, every table, the figures (links into figures/) and definitions."""
    lines = [f"# {_title(manifest)}", ""]
    lines += [f"- **{k}**: {v}" for k, v in facts(manifest, summ)]
    lines += ["", "## Tables", "", f"Also in `{TABLES_DIR}/` as Markdown and LaTeX (booktabs); per-cell statistics in "
              f"`{SUMMARY}` and `{CELLS}`.", ""]
    for t in tables:
        lines += [to_markdown(t), ""]
    lines += ["## Figures", ""]
    for f in figs:
        if f.file:
            lines += [f"### {f.title}", "", f"![{f.title}]({f.file})", "", f.caption, ""]
    skipped = [f for f in figs if not f.file]
    if skipped:
        lines += ["Not drawn:", ""] + [f"- {f.title}: {f.skipped}" for f in skipped] + [""]
    lines += ["## Definitions", ""] + [f"- **{k}**: {v}." for k, v in definitions(summ)] + [""]
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------ files


def _write_text(path: Path, text: str) -> None:
    files.atomic_write(path, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))


def _write_parquet(path: Path, table: pa.Table) -> None:
    files.atomic_write(path, lambda tmp: pq.write_table(table, tmp))
