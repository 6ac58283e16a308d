"""The paper's Tables II, III and IV, filled with a run's numbers beside the paper's.

A campaign says which table it reproduces in its ``[reference]`` table::

    [reference]
    table = "IV"                       # "II" | "III" | "IV": the layout
    source = "Yuan et al., Table IV"   # optional, printed under the table
    runs = 30                          # optional: the paper's episodes per cell (default 30)
    block_axis = "scenario"            # optional (IV): the axis whose labels start row blocks
    note = "..."                       # optional, printed under the table
    [reference.cells."scenario=A,method=MPC-DC"]
    "min_dist_front_m.min" = -0.15     # <episode metric>.<statistic> = the paper's value
    "min_gap_opp_m.min" = 0.31
    "safe.k" = 0

Quantities are ``<metric>.<stat>``: for a value metric (``overtake_time_s``, ``min_dist_front_m``,
``min_gap_opp_m``, ...) the stat is ``min``, ``max``, ``mean`` or a quantile key (``q50``); for a rate
metric (``safe``, ``overtook``, ...) it is ``k`` (a count out of ``runs``) or ``rate``.

Each layout has the paper's rows (Table II: overtaking time min / max / mean; Table III:
successful overtakes, min dist. with veh_f and veh_o, safe episodes; Table IV: per scenario, min
dist. with veh_f and veh_o and safe cases) and one column per reference cell. Every row is given
three times: ours, the paper's, and the gap. Counts carry their exact interval and the gap of a
count is the difference of the two rates with the Miettinen-Nurminen score interval (the paper's 30
runs are a sample too); minima and maxima are minima and maxima; our means carry their bootstrap interval and the gap
of a value is ours − paper with the relative gap.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from mcverify.analysis import stats
from mcverify.analysis.metrics import METRICS
from mcverify.reporting.tables import (
    DASH,
    Section,
    Table,
    bound_name,
    fmt_mean_ci,
    fmt_num,
    fmt_p,
    fmt_rate,
    fmt_rel,
    is_missing,
    method_name,
)

#: The paper's episodes per cell ("30 runs per group" in every table).
PAPER_RUNS = 30


@dataclass(frozen=True)
class Layout:
    title: str
    rows: tuple[tuple[str, str], ...]  # (quantity, row label)
    #: rows computed from the cell's parameters, not measured: (key of the cell summary's
    #: ``goal_time_bound_s``, row label); shown once per block, ours only
    bound_rows: tuple[tuple[str, str], ...] = ()


LAYOUTS: dict[str, Layout] = {
    "II": Layout(
        "Table II: time taken when no opposing traffic",
        (("overtake_time_s.min", "min (s)"), ("overtake_time_s.max", "max (s)"), ("overtake_time_s.mean", "mean (s)")),
        (("speed_limit", "start-to-goal lower bound, at the speed limit from t = 0 (s)"),
         ("accel_limit", "start-to-goal lower bound, with the acceleration limit (s)")),
    ),
    "III": Layout(
        "Table III: overtaking with different accelerating rates of veh_f",
        (
            ("overtook.k", "successful overtaking"),
            ("min_dist_front_m.min", "min dist. with veh_f (m)"),
            ("min_gap_opp_m.min", "min dist. with veh_o (m)"),
            ("safe.k", "safe episodes"),
        ),
    ),
    "IV": Layout(
        "Table IV: minimum distance with surrounding vehicles",
        (
            ("min_dist_front_m.min", "min dist. with veh_f (m)"),
            ("min_gap_opp_m.min", "min dist. with veh_o (m)"),
            ("safe.k", "safe cases (h_ef ≥ 0)"),
            ("outside_margin.k", "outside the ε margin (h_ef ≥ ε)"),
        ),
    ),
}

#: Where a cell's method label is one of these, its ε-margin variant (the label plus " eps=...")
#: gets the column right after it (Table IV: "MPC-DC", "MPC-DC eps=0.3").
_VARIANT_SEPARATOR = " eps="

_STAT_WORDS = {"min": "min", "max": "max", "mean": "mean", "k": "count", "rate": "rate"}


def lookup(cell: Mapping[str, Any], quantity: str) -> Any:
    """Our value of ``<metric>.<stat>`` in a cell summary: a value statistic (float, NaN when the
    metric never had a value), a rate field, or None when the run does not have the metric."""
    column, stat = quantity.rsplit(".", 1)
    if column in cell["values"]:
        v = cell["values"][column]
        return v["quantiles"].get(stat, math.nan) if stat.startswith("q") else v.get(stat, math.nan)
    if column in cell["rates"]:
        return cell["rates"][column].get(stat)
    if column in METRICS:
        return None
    raise KeyError(f"unknown reference quantity {quantity!r}")


def parse_cell_name(name: str) -> dict[str, str]:
    """Labels from a cell name ``axis=label,axis=label`` (labels may hold commas, e.g. ``[1,3]``)."""
    labels = {}
    for part in re.split(r",(?=[A-Za-z_][\w.]*=)", name):
        if "=" in part:
            axis, label = part.split("=", 1)
            labels[axis] = label
    return labels


def pretty_label(axis: str, label: str) -> str:
    """A column header for an axis label, in the paper's notation where the axis is a known one."""
    if axis == "front_speed_kmh":
        return f"v_f = {label} km/h"
    if axis == "alpha_f" and label[:1] in "([":
        return f"α_f ∈ {label}"
    if axis == "front_accel_range_mps2":
        m = re.fullmatch(r"\[([^,\]]+),([^\]]+)\]", label)
        return f"α_f ∈ ({m.group(1)},{m.group(2)}]" if m else f"α_f ∈ {label}"
    if axis == "epsilon":
        return f"ε = {label}"
    if axis == "lambda0":
        return f"λ₀ = {label}"
    if axis in ("method", "controller", "scenario"):
        return label
    if axis == "noise":
        return f"noise {label}"
    return f"{axis} = {label}"


def paper_table(summ: Mapping[str, Any], reference: Mapping[str, Any]) -> Table | None:
    """The layout ``reference["table"]`` filled from ``summ`` (see the module docstring), or None
    when the reference names no known layout."""
    key = str(reference.get("table", "")).strip().upper()
    layout = LAYOUTS.get(key)
    if layout is None:
        return None
    runs = int(reference.get("runs", PAPER_RUNS))
    ref_cells: Mapping[str, Mapping[str, Any]] = reference.get("cells") or {}
    by_name = {c["cell"]: c for c in summ["cells"]}
    names = list(ref_cells) or [c["cell"] for c in summ["cells"]]
    labels = {n: (by_name[n]["labels"] if n in by_name and by_name[n]["labels"] else parse_cell_name(n)) for n in names}

    varying = [a for a in _axes_in_order(labels.values()) if len({lab.get(a) for lab in labels.values()}) > 1]
    block_axis = reference.get("block_axis")
    if block_axis is None and len(varying) > 1:
        block_axis = "scenario" if "scenario" in varying else varying[0]
    col_axes = [a for a in varying if a != block_axis]

    def col_key(name: str) -> tuple[str, ...]:
        return tuple(labels[name].get(a, "") for a in col_axes) if col_axes else (name,)

    col_keys: list[tuple[str, ...]] = []
    blocks: list[str | None] = []
    for n in names:
        if col_key(n) not in col_keys:
            col_keys.append(col_key(n))
        b = labels[n].get(block_axis) if block_axis else None
        if b not in blocks:
            blocks.append(b)
    col_keys = _variants_beside_their_base(col_keys, col_axes)
    headers = [
        ", ".join(pretty_label(a, lab) for a, lab in zip(col_axes, ck, strict=True)) if col_axes else ck[0]
        for ck in col_keys
    ]

    quantities = list(layout.rows)
    known = {q for q, _ in quantities}
    for qs in ref_cells.values():  # reference quantities beyond the layout's rows, in file order
        for q in qs:
            if q not in known:
                known.add(q)
                quantities.append((q, _auto_label(q)))

    rows: list[list[str] | Section] = []
    missing_metrics: set[str] = set()
    bounds_shown = False
    for block in blocks:
        if block_axis:
            rows.append(Section(f"Scenario {block}" if block_axis == "scenario" else pretty_label(block_axis, block)))
        cells_here = {}
        for n in names:
            if not block_axis or labels[n].get(block_axis) == block:
                cells_here[col_key(n)] = n
        for quantity, label in quantities:
            ours, paper, gaps = [], [], []
            any_paper = False
            for ck in col_keys:
                name = cells_here.get(ck)
                cell = by_name.get(name) if name else None
                ref_value = ref_cells.get(name, {}).get(quantity) if name else None
                any_paper |= ref_value is not None
                mine = lookup(cell, quantity) if cell else None
                if cell and mine is None:
                    missing_metrics.add(quantity.rsplit(".", 1)[0])
                ours.append(_ours(cell, quantity) if cell else DASH)
                paper.append(_paper(quantity, ref_value, runs))
                gaps.append(_gap(cell, quantity, ref_value, runs, summ["confidence_level"]))
            rows.append([f"{label}: ours", *ours])
            if any_paper:
                rows.append([f"{label}: paper", *paper])
                rows.append([f"{label}: ours − paper", *gaps])
        for bound_key, label in layout.bound_rows:
            values = [_bound(by_name.get(cells_here.get(ck) or ""), bound_key) for ck in col_keys]
            if any(v != DASH for v in values):
                rows.append([label, *values])
                bounds_shown = True

    notes = _notes(summ, reference, runs, bounds_shown=bounds_shown,
                   margin_rows=any(_is_margin_row(q) for q, _ in quantities),
                   absent=[n for n in names if n not in by_name], missing_metrics=missing_metrics)
    return Table(f"paper-table-{key}", layout.title, ["", *headers], rows, notes)


def _notes(summ: Mapping[str, Any], reference: Mapping[str, Any], runs: int, *, bounds_shown: bool,
           margin_rows: bool, absent: list[str], missing_metrics: set[str]) -> list[str]:
    """The notes under a paper table: how ours and the gaps are given, and what the run lacks."""
    level = summ["confidence_level"]
    notes = [
        f"ours: counts as k/n [{method_name(summ['interval_method'])} {level:.0%} interval], with "
        f"{bound_name(summ['interval_method'])} bound (≤ u or ≥ l) when k is 0 or n; means with their "
        "percentile-bootstrap interval; minima and maxima over all episodes of the cell.",
        f"ours − paper: for counts, the difference of rates (ours − paper/{runs}) with the {level:.0%} "
        "Miettinen-Nurminen score interval, the paper's runs being a sample too; for values, the difference and "
        "the relative gap.",
    ]
    if bounds_shown:
        notes.append("Start-to-goal lower bound: the earliest time at which any controller can meet x_e ≥ x_f(t) + "
                     "φ v_f from the cell's start with veh_f at its constant speed (true values), the ego at its "
                     "speed limit from t = 0, or accelerating at its limit up to it (mcverify.analysis.bounds). "
                     "Our overtake time is taken on measured values, so noise can put it slightly below the bound.")
    if margin_rows:
        notes.append("Two meanings of safe: \"safe\" is no collision and h_ef ≥ 0 (outside the ellipse) at every "
                     "sub-step; \"outside the ε margin\" also needs h_ef ≥ ε, the cell's level (min h_ef − ε ≥ 0).")
    if reference.get("source"):
        notes.append(f"Paper: {reference['source']}.")
    if absent:
        notes.append("Not in this run: " + "; ".join(absent) + ".")
    if missing_metrics:
        notes.append("Not measured in this run: " + ", ".join(sorted(missing_metrics)) + f" ({DASH}).")
    if reference.get("note"):
        notes.append(" ".join(str(reference["note"]).split()))
    return notes


def _bound(cell: Mapping[str, Any] | None, key: str) -> str:
    """A cell's start-to-goal lower bound ``key`` (s), from its summary, or a dash."""
    b = (cell or {}).get("goal_time_bound_s") or {}
    return fmt_num(b[key]) if key in b and not is_missing(b[key]) else DASH


def _is_margin_row(quantity: str) -> bool:
    return quantity.rsplit(".", 1)[0] == "outside_margin"


def _variants_beside_their_base(col_keys: list[tuple[str, ...]], col_axes: list[str]) -> list[tuple[str, ...]]:
    """``col_keys`` with each ε-margin variant column (method label ``<base> eps=<x>``, the other
    column labels equal) moved right after the column of its base ``<base>``, the rest in order."""
    if "method" not in col_axes:
        return col_keys
    i = col_axes.index("method")

    def base_of(ck: tuple[str, ...]) -> tuple[str, ...] | None:
        base = ck[i].split(_VARIANT_SEPARATOR, 1)[0]
        key = (*ck[:i], base, *ck[i + 1:])
        return key if base != ck[i] and key in col_keys else None

    out: list[tuple[str, ...]] = []
    for ck in col_keys:
        if base_of(ck) is None:
            out.append(ck)
            out += [v for v in col_keys if base_of(v) == ck]
    return out


def _axes_in_order(label_dicts: Sequence[Mapping[str, str]] | Any) -> list[str]:
    axes: list[str] = []
    for lab in label_dicts:
        for a in lab:
            if a not in axes:
                axes.append(a)
    return axes


def _auto_label(quantity: str) -> str:
    column, stat = quantity.rsplit(".", 1)
    metric = METRICS.get(column)
    name = metric.label if metric else column
    unit = f" ({metric.unit})" if metric and metric.unit and stat not in ("k", "rate") else ""
    return f"{name} {_STAT_WORDS.get(stat, stat)}{unit}"


def _is_count(quantity: str) -> bool:
    return quantity.rsplit(".", 1)[1] in ("k", "rate")


def _ours(cell: Mapping[str, Any], quantity: str) -> str:
    column, stat = quantity.rsplit(".", 1)
    if _is_count(quantity):
        return fmt_rate(cell["rates"].get(column))
    if stat == "mean":
        return fmt_mean_ci(cell["values"].get(column))
    value = lookup(cell, quantity)
    return fmt_num(value)


def _paper(quantity: str, value: Any, runs: int) -> str:
    if value is None:
        return DASH
    stat = quantity.rsplit(".", 1)[1]
    if stat == "k":
        return f"{int(value)}/{runs}"
    if stat == "rate":
        return fmt_p(value)
    return fmt_num(value)


def _gap(cell: Mapping[str, Any] | None, quantity: str, ref_value: Any, runs: int, level: float) -> str:
    if cell is None or ref_value is None:
        return DASH
    column, stat = quantity.rsplit(".", 1)
    if _is_count(quantity):
        r = cell["rates"].get(column)
        if not r or not r["n"]:
            return DASH
        k_paper = int(ref_value) if stat == "k" else int(round(float(ref_value) * runs))
        if not 0 <= k_paper <= runs:
            return DASH
        d = stats.compare_unpaired(r["k"], r["n"], k_paper, runs, level=level)
        return f"{fmt_num(d['diff'], 3, signed=True)} [{fmt_num(d['low'], 3, signed=True)}, " \
               f"{fmt_num(d['high'], 3, signed=True)}]"
    ours = lookup(cell, quantity)
    if is_missing(ours):
        return DASH
    return f"{fmt_num(float(ours) - float(ref_value), signed=True)} ({fmt_rel(ours, ref_value)})"
