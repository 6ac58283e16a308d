"""report.md: the run's statistics in Markdown, with the paper's numbers side by side.

Everything here is computed from stored data (``episodes.parquet`` and ``manifest.json``), so
``mcverify report RUN_DIR`` regenerates the same bytes without re-simulating.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from mcverify import store, summary

REPORT = "report.md"
SUMMARY = "summary.json"


def build(run_dir: Path) -> tuple[dict[str, Any], str]:
    """Summary dict and report text of a finished run folder."""
    manifest = store.read_json(Path(run_dir) / store.MANIFEST)
    table = store.read_episodes(run_dir)
    summ = summary.summarise(table)
    summ["campaign"] = manifest["campaign"]["name"]
    summ["episodes"] = table.num_rows
    return summ, render(manifest, summ)


def write(run_dir: Path) -> Path:
    summ, text = build(run_dir)
    store.write_json_atomic(Path(run_dir) / SUMMARY, summ)
    path = Path(run_dir) / REPORT
    path.write_text(text)
    return path


def render(manifest: dict[str, Any], summ: dict[str, Any]) -> str:
    camp = manifest["campaign"]
    lines = [
        f"# {camp['name']}",
        "",
        camp.get("description", "") or "",
        "",
        f"- episodes: {summ['episodes']} ({len(summ['cells'])} cells), seed {camp['seed']}, controllers "
        + ", ".join(sorted({f"`{c['controller']}`" for c in manifest['cells']})),
        f"- intervals: {summ['interval_method']} at {summ['confidence_level']:.0%}; for a cell with no"
        " event the exact one-sided upper bound is given",
        f"- code: git `{manifest['environment'].get('git_commit')}`, kernels "
        + ", ".join(f"`{h}`" for h in manifest.get("kernels", {}).values()),
        "",
        "## Outcomes per cell",
        "",
        _outcome_table(summ),
        "",
        "## Distances and times per cell",
        "",
        _value_table(summ),
        "",
        "## Theorem checks and solver",
        "",
        _theorem_table(summ),
        "",
    ]
    ref = camp.get("reference") or {}
    if ref.get("cells"):
        lines += ["## Side by side with the paper", "", _reference_table(summ, ref), ""]
        if ref.get("note"):
            lines += [ref["note"].strip(), ""]
    lines += [_definitions(), ""]
    return "\n".join(lines)


def _rate(r: dict[str, Any]) -> str:
    k, n = r["k"], r["n"]
    if n == 0:
        return "–"
    if k == 0:
        return f"0/{n} (≤ {r['upper_one_sided']:.3f})"
    return f"{k}/{n} [{r['low']:.3f}, {r['high']:.3f}]"


def _num(x: float, digits: int = 2) -> str:
    return "–" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"


def _outcome_table(summ: dict[str, Any]) -> str:
    head = "| cell | ε | safe | collision (front) | ellipse violated | invariance breach | overtook | went back | timeout |"
    rows = [head, "|" + "---|" * 9]
    for c in summ["cells"]:
        r = c["rates"]
        rows.append(
            f"| {c['cell']} | {_num(c['epsilon'])} | {_rate(r['safe'])} | {_rate(r['collision_front'])} | "
            f"{_rate(r['ellipse_violation'])} | {_rate(r['invariance_breach'])} | {_rate(r['overtook'])} | "
            f"{_rate(r['went_back'])} | {_rate(r['timeout'])} |"
        )
    return "\n".join(rows)


def _value_table(summ: dict[str, Any]) -> str:
    head = (
        "| cell | min dist. to front ellipse (m) | min footprint gap (m) | min h_ef | "
        "overtake time min / mean [95% CI] / max (s) | lane-borrow time min / mean / max (s) |"
    )
    rows = [head, "|" + "---|" * 6]
    for c in summ["cells"]:
        v = c["values"]
        ot, lb = v["overtake_time_s"], v["lane_borrow_time_s"]
        rows.append(
            f"| {c['cell']} | {_num(v['min_dist_front_m']['min'])} | {_num(v['min_gap_front_m']['min'])} | "
            f"{_num(v['min_h_front']['min'], 3)} | {_num(ot['min'])} / {_num(ot['mean'])} "
            f"[{_num(ot['mean_low'])}, {_num(ot['mean_high'])}] / {_num(ot['max'])} | "
            f"{_num(lb['min'])} / {_num(lb['mean'])} / {_num(lb['max'])} |"
        )
    return "\n".join(rows)


def _theorem_table(summ: dict[str, Any]) -> str:
    head = (
        "| cell | episodes with Q1 and Q2 both unsolved (Thm 5) | such steps | fallback steps | "
        "Q1 failed steps | Q2 failed steps | solves | mean iters | mean / max solve time (ms) |"
    )
    rows = [head, "|" + "---|" * 9]
    for c in summ["cells"]:
        t, s = c["theorem_checks"], c["solver"]
        rows.append(
            f"| {c['cell']} | {t['episodes_with_both_infeasible']} | {t['both_infeasible_steps']} | "
            f"{t['fallback_steps']} | {t['q1_fail_steps']} | {t['q2_fail_steps']} | {s['solves']} | "
            f"{_num(s['iterations_mean'], 1)} | {_num(1e3 * s['solve_time_mean_s'], 1)} / "
            f"{_num(1e3 * s['solve_time_max_s'], 1)} |"
        )
    return "\n".join(rows)


def lookup(cell: dict[str, Any], quantity: str) -> float:
    """Our value of a reference quantity: ``<value column>.<stat>`` or ``<rate column>.<k|rate>``."""
    column, stat = quantity.rsplit(".", 1)
    if column in cell["values"]:
        return cell["values"][column][stat]
    if column in cell["rates"]:
        return cell["rates"][column][stat]
    raise KeyError(f"unknown reference quantity {quantity!r}")


def _reference_table(summ: dict[str, Any], ref: dict[str, Any]) -> str:
    rows = [
        f"Paper: {ref.get('source', 'Table ' + str(ref.get('table', '?')))}.",
        "",
        "| cell | quantity | ours | paper | ours − paper | relative |",
        "|---|---|---|---|---|---|",
    ]
    by_name = {c["cell"]: c for c in summ["cells"]}
    for cell_name, quantities in ref["cells"].items():
        cell = by_name.get(cell_name)
        for quantity, paper_value in quantities.items():
            ours = lookup(cell, quantity) if cell else math.nan
            diff = ours - paper_value
            rel = diff / paper_value if paper_value else math.nan
            rows.append(
                f"| {cell_name} | {quantity} | {_num(ours)} | {_num(paper_value)} | {_num(diff)} | "
                f"{'–' if math.isnan(rel) else f'{rel:+.0%}'} |"
            )
    return "\n".join(rows)


def _definitions() -> str:
    return """## Definitions

- **safe**: no footprint overlap with the front vehicle and h_ef ≥ 0 (outside the safety ellipse) at every integration sub-step.
- **min dist. to front ellipse**: signed Euclidean distance from the ego c.g. to the ellipse h_ef = 0 around the front vehicle, negative inside (the paper's "min dist. with veh_f").
- **invariance breach**: h_ef started at or above ε and fell below ε at some sub-step (Theorem 2); the margin min h_ef − ε is in `episodes.parquet`.
- **overtake time**: time from the episode start to the paper's convergence test (x_e ≥ x_f + φ v_f and |y_e| ≤ ε_y, on measured values).
- **lane-borrow time**: from the first to the last sub-step at which the ego footprint reaches into the opposing lane.
- **Thm 5** (one-in-two feasibility): steps where neither applicable problem (Q1 while overtaking, Q2) solved; the fallback brakes towards the ego lane.
"""
