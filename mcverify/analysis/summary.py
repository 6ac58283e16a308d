"""Per-cell statistics of a run: rates with exact intervals, distances, times, theorem checks.

:func:`summarise` turns ``episodes.parquet`` (one row per episode) and the run's manifest into one
dict per cell; :func:`cells_table` flattens those dicts into ``cells.parquet`` (one row per cell).
Everything is a pure function of the stored data and the options (confidence level, interval
method, bootstrap resamples and seed), so regenerating gives identical numbers.

Episodes whose ``outcome`` is ``"error"`` (the episode could not be simulated) are counted apart:
every safety and outcome rate is over the ``valid`` episodes, and ``error`` is a rate over all
episodes of the cell. Columns that a run does not have (``collision_opp``, ``min_gap_opp_m`` on
runs without opposing traffic, ...) are left out of the summary rather than invented.
"""

from __future__ import annotations

import json
import math
import zlib
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pyarrow as pa

from mcverify import schema
from mcverify.analysis import bounds, stats
from mcverify.analysis.columns import Columns, bools, floats, strings
from mcverify.analysis.metrics import RATE_METRICS, VALUE_METRICS
from mcverify.analysis.sequential import CONFIDENCE_SEQUENCE, DEFAULT_PRIOR, sequence_rate_summary
from mcverify.schema import ERROR_OUTCOME, OUTCOME_FLAGS, STOPPED_OUTCOME

#: Version of the summary.json / cells.parquet layout.
FORMAT = 2


#: Quantiles stored for every continuous metric.
QUANTILES = (0.0, 0.05, 0.25, 0.5, 0.75, 0.95, 1.0)

#: Outcomes in report order; "error" episodes are kept apart from the safety statistics. "stopped"
#: occurs only in falsification searches (an episode ended at its first violation).
OUTCOMES = (*OUTCOME_FLAGS, STOPPED_OUTCOME, ERROR_OUTCOME)

#: Categorical episode columns counted per cell (empty strings are not counted): what drove the ego
#: when it first left the safe set ("planned", "held", "fallback") and why it went back.
CATEGORY_COLUMNS = ("first_unsafe_cause", "went_back_reason", "went_back_q1_failure")
#: JSON-count episode columns summed per cell: Table I rows met, IPOPT return statuses.
JSON_COUNT_COLUMNS = ("table_one_rows",)

#: ``theorem_checks`` of a cell: key -> (episode column, "sum" over episodes, "episodes" with a
#: positive value or "max" over episodes). Theorem 2: invariance breaches; Theorem 5: steps with Q1
#: and Q2 both unsolved, split by evidence (both certified infeasible, or a budget / numerical failure).
THEOREM_CHECKS: dict[str, tuple[str, str]] = {
    "invariance_breaches": ("invariance_breach", "sum"),
    "opp_invariance_breaches": ("opp_invariance_breach", "sum"),
    "episodes_with_both_infeasible": ("both_infeasible_steps", "episodes"),
    "both_infeasible_steps": ("both_infeasible_steps", "sum"),
    "episodes_with_both_certified": ("both_certified_infeasible_steps", "episodes"),
    "both_certified_infeasible_steps": ("both_certified_infeasible_steps", "sum"),
    "both_unsolved_uncertified_steps": ("both_unsolved_uncertified_steps", "sum"),
    "both_infeasible_longest_run": ("both_infeasible_longest_run", "max"),
    "episodes_with_fallback": ("fallback_steps", "episodes"),
    "fallback_steps": ("fallback_steps", "sum"),
    "episodes_with_held": ("held_steps", "episodes"),
    "held_steps": ("held_steps", "sum"),
    "q1_fail_steps": ("q1_fail_steps", "sum"),
    "q1_fail_certified_steps": ("q1_fail_certified_steps", "sum"),
    "q1_fail_presumed_steps": ("q1_fail_presumed_steps", "sum"),
    "q1_fail_iteration_limit_steps": ("q1_fail_iteration_limit_steps", "sum"),
    "q1_fail_other_steps": ("q1_fail_other_steps", "sum"),
    "q1_held_steps": ("q1_held_steps", "sum"),
    "q2_fail_steps": ("q2_fail_steps", "sum"),
    "q2_driven_steps": ("q2_driven_steps", "sum"),
    "q1_rescue_steps": ("q1_rescue_steps", "sum"),
}

#: The columns of one Theorem 5 finding (:func:`theorem_findings`), episode columns all.
FINDING_COLUMNS = ("episode_id", "cell_episode", "both_infeasible_steps", "both_certified_infeasible_steps",
                   "both_unsolved_uncertified_steps", "both_infeasible_longest_run")


_COLLISION_COLUMNS = ("collision_front", "collision_opp")

#: Metrics about the opposing vehicle: left out of a cell that has none (the rollout writes them
#: as False / NaN there), so runs without opposing traffic show no empty veh_o columns.
OPPOSING_METRICS = ("collision_opp", "opp_invariance_breach", "min_gap_opp_m", "min_gap_opp_any_m", "min_h_opp")
#: Per-episode solver columns aggregated in a cell's ``solver`` statistics.
SOLVER_COLUMNS = ("solves", "iterations_mean", "iterations_max", "cold_retries", "solve_time_mean_s",
                  "solve_time_max_s", "solver_statuses")
#: Summary metrics that are not episode columns (derived here from several).
DERIVED_METRICS = ("collision", "outside_margin", "speed_limit_exceeded", "input_limit_exceeded")


def summarised_columns() -> frozenset[str]:
    """Every episode column this module reads by name (each one declared in :mod:`mcverify.schema`)."""
    metrics = {m.name for m in RATE_METRICS + VALUE_METRICS} - set(DERIVED_METRICS)
    theorem = {col for col, _ in THEOREM_CHECKS.values()} | set(FINDING_COLUMNS)
    return frozenset(metrics | theorem | set(CATEGORY_COLUMNS) | set(JSON_COUNT_COLUMNS) | set(OPPOSING_METRICS)
                     | set(_COLLISION_COLUMNS) | set(SOLVER_COLUMNS) | set(OUTCOME_FLAGS)
                     | {"outcome", "cell", "cell_index", "controller", "opposing_kind", "epsilon", "lambda0"})


# A renamed or dropped episode column must fail here, at import, not as a silently missing statistic.
for _name in summarised_columns():
    schema.column(_name)


def summarise(
    table: pa.Table,
    manifest: Mapping[str, Any] | None = None,
    *,
    level: float = 0.95,
    method: str = "clopper-pearson",
    bootstrap_resamples: int = 2000,
    bootstrap_seed: int = 0,
    prior: tuple[float, float] = DEFAULT_PRIOR,
) -> dict[str, Any]:
    """Statistics per cell, in the order of the cells' indices.

    ``table``: the run's episodes (``episodes.parquet``). ``manifest``: the run's manifest; it
    supplies each cell's labels, controller, overrides and planned episode count, and lists cells
    that have no episode row yet. ``level`` / ``method``: the two-sided interval for every rate
    (``stats.PROPORTION_METHODS``, or :data:`CONFIDENCE_SEQUENCE` for the episodes an estimate used:
    the anytime-valid interval of each rate over its cell's episodes in episode order, with the mixture
    ``prior``, :func:`rate_of`). The bootstrap interval of each mean uses
    ``bootstrap_resamples`` resamples seeded from (``bootstrap_seed``, cell name, metric), so
    regenerating the summary gives the same numbers.

    Returns ``{"format", "confidence_level", "interval_method", "bootstrap", "episodes", "axes",
    "cells"}``; ``axes`` maps every axis whose label differs between cells to its labels in cell
    order, and each cell is the dict of :func:`cell_summary`.
    """
    level = float(level)
    rate_of(np.zeros(1, dtype=bool), level, method, prior)  # validate level and method once, with their messages
    info = _manifest_cells(manifest)
    cols = Columns.from_table(table)
    idx = cols["cell_index"].astype(np.int64) if cols.num_rows else np.zeros(0, dtype=np.int64)
    order = np.argsort(idx, kind="stable")  # rows grouped by cell, episode order kept within a cell
    grouped = idx[order]
    cells = []
    for cell_index in sorted(set(idx.tolist()) | set(info)):
        start, stop = np.searchsorted(grouped, cell_index, "left"), np.searchsorted(grouped, cell_index, "right")
        sub = cols.take(order[start:stop])
        cells.append(
            cell_summary(
                sub,
                info.get(cell_index, {}),
                cell_index=int(cell_index),
                level=level,
                method=method,
                bootstrap_resamples=bootstrap_resamples,
                bootstrap_seed=bootstrap_seed,
                prior=prior,
            )
        )
    return {
        "format": FORMAT,
        "confidence_level": level,
        "interval_method": method,
        "bootstrap": {"method": "percentile", "resamples": bootstrap_resamples, "seed": bootstrap_seed},
        "episodes": int(table.num_rows),
        "axes": varying_axes(cells),
        "cells": cells,
    }


def cell_summary(
    t: pa.Table | Columns,
    info: Mapping[str, Any],
    *,
    cell_index: int,
    level: float = 0.95,
    method: str = "clopper-pearson",
    bootstrap_resamples: int = 2000,
    bootstrap_seed: int = 0,
    prior: tuple[float, float] = DEFAULT_PRIOR,
) -> dict[str, Any]:
    """One cell's statistics from its episode rows ``t`` and its manifest entry ``info``.

    Keys: ``cell``, ``cell_index``, ``labels`` (axis -> label), ``controller``, ``opposing_kind``,
    ``noise`` (kind and scale), ``epsilon``, ``lambda0``, ``overrides``, ``episodes_planned``,
    ``episodes`` (rows), ``valid`` (rows without error), ``outcomes`` (counts of
    :data:`OUTCOMES`), ``rates`` (name -> :func:`stats.rate_summary`, over valid episodes;
    ``error`` over all), ``values`` (name -> :func:`value_summary`), ``counts`` (per
    :data:`CATEGORY_COLUMNS` and :data:`JSON_COUNT_COLUMNS` the run has: value -> episodes, or
    summed counts), ``theorem_checks``, ``theorem_findings`` (every episode with a step where
    neither Q1 nor Q2 solved: :func:`theorem_findings`), ``solver`` (iterations, solve times, cold retries, IPOPT
    return statuses summed over episodes).
    """
    t = t if isinstance(t, Columns) else Columns.from_table(t)
    if method == CONFIDENCE_SEQUENCE and t.num_rows and "cell_episode" in t.column_names:
        t = t.take(np.argsort(floats(t, "cell_episode"), kind="stable"))  # the sequence is in episode order
    params = info.get("params") or {}
    opposing_kind = params.get("opposing", {}).get("kind") or _first(t, "opposing_kind")  # None: not recorded
    if opposing_kind == "none":
        t = t.drop(OPPOSING_METRICS)
    n_all = t.num_rows
    outcome = strings(t, "outcome")
    error = outcome == ERROR_OUTCOME
    v = t.take(np.flatnonzero(~error)) if error.any() else t
    n = v.num_rows

    rates: dict[str, Any] = {}
    for m in RATE_METRICS:
        flags = _flags(v, m.name)
        if flags is not None:
            rates[m.name] = rate_of(flags, level, method, prior)
    rates["error"] = rate_of(error, level, method, prior)

    name = info.get("name") or (str(t["cell"][0]) if n_all and "cell" in t.column_names else f"cell {cell_index}")
    values = {}
    for m in VALUE_METRICS:
        if m.name in v.column_names:
            seed = zlib.crc32(f"{bootstrap_seed}/{name}/{m.name}".encode())
            values[m.name] = value_summary(
                floats(v, m.name), level=level, n_resamples=bootstrap_resamples, seed=seed
            )

    return {
        "cell": name,
        "cell_index": cell_index,
        "labels": dict(info.get("labels") or {}),
        "controller": info.get("controller") or _first(t, "controller") or params.get("mpc", {}).get("controller"),
        "opposing_kind": opposing_kind,
        "noise": {"kind": params.get("noise", {}).get("kind"), "scale": params.get("noise", {}).get("scale")},
        "epsilon": _num(info.get("epsilon", _first(t, "epsilon"))),
        "lambda0": _num(info.get("lambda0", _first(t, "lambda0"))),
        "goal_time_bound_s": bounds.goal_time_bounds(params),
        "overrides": dict(info.get("overrides") or {}),
        "episodes_planned": int(info["episodes"]) if "episodes" in info else n_all,
        "episodes": n_all,
        "valid": n,
        "outcomes": {o: int((outcome == o).sum()) for o in OUTCOMES},
        "rates": rates,
        "values": values,
        "counts": _counts(v),
        "theorem_checks": _theorem_checks(v),
        "theorem_findings": theorem_findings(v),
        "solver": _solver(v),
    }


def rate_of(flags: np.ndarray, level: float, method: str, prior: tuple[float, float] = DEFAULT_PRIOR
            ) -> dict[str, Any]:
    """The rate of ``flags`` (one per episode, in episode order) with its interval: the fixed-count
    :func:`stats.rate_summary` by ``method``, or the anytime-valid :func:`sequence_rate_summary` for
    :data:`CONFIDENCE_SEQUENCE` (an estimate's episode count was chosen by looking at its outcomes, so
    a fixed-count interval would not keep its coverage there)."""
    if method == CONFIDENCE_SEQUENCE:
        return sequence_rate_summary(flags, level, prior)
    return stats.rate_summary(int(np.sum(flags)), int(np.size(flags)), level=level, method=method)


def value_summary(
    values: np.ndarray, *, level: float = 0.95, n_resamples: int = 2000, seed: int = 0
) -> dict[str, Any]:
    """Count, min, max, mean with a percentile-bootstrap interval, std and :data:`QUANTILES` of the
    finite entries of ``values`` (NaN marks "no value", e.g. no overtake time when the ego went
    back). Everything but ``count`` is NaN when no entry is finite."""
    x = np.asarray(values, dtype=np.float64)
    finite = x[np.isfinite(x)]
    ci = stats.bootstrap_mean_interval(finite, level=level, n_resamples=n_resamples, seed=seed)
    has = finite.size > 0
    return {
        "count": int(finite.size),
        "min": float(finite.min()) if has else math.nan,
        "max": float(finite.max()) if has else math.nan,
        "mean": float(finite.mean()) if has else math.nan,
        "mean_low": ci.low,
        "mean_high": ci.high,
        "std": float(finite.std(ddof=1)) if finite.size > 1 else math.nan,
        "quantiles": stats.quantiles(finite, QUANTILES),
    }


def varying_axes(cells: Sequence[Mapping[str, Any]]) -> dict[str, list[str]]:
    """Axes whose label differs between cells: axis -> its distinct labels in cell order."""
    axes: dict[str, list[str]] = {}
    for c in cells:
        for axis, label in c.get("labels", {}).items():
            seen = axes.setdefault(axis, [])
            if label not in seen:
                seen.append(label)
    return {a: labels for a, labels in axes.items() if len(labels) > 1}


def axis_value(cell: Mapping[str, Any], axis: str) -> float | None:
    """The numeric value behind a grid axis label (e.g. 0.3 for ``epsilon``), or None when the
    axis is a bundle axis or its value is not a number (e.g. an acceleration range)."""
    for key, value in cell.get("overrides", {}).items():
        if key.split(".", 1)[-1] == axis and isinstance(value, int | float) and not isinstance(value, bool):
            return float(value)
    if axis in ("epsilon", "lambda0") and cell.get(axis) is not None:
        return float(cell[axis])
    return None


# ---------------------------------------------------------------------------------------- helpers


def _manifest_cells(manifest: Mapping[str, Any] | None) -> dict[int, dict[str, Any]]:
    if not manifest:
        return {}
    return {int(c["index"]): dict(c) for c in manifest.get("cells", []) if "index" in c}


def _theorem_checks(v: Columns) -> dict[str, int]:
    out = {}
    for key, (col, how) in THEOREM_CHECKS.items():
        if col in v.column_names:
            x = floats(v, col)
            if how == "episodes":
                out[key] = int((x > 0).sum())
            elif how == "max":
                out[key] = int(np.nanmax(x)) if np.isfinite(x).any() else 0
            else:
                out[key] = int(np.nansum(x))
    return out


def theorem_findings(v: Columns) -> list[dict[str, int]]:
    """Every episode with a step where neither Q1 nor Q2 solved (Theorem 5 says there is none), in
    episode order: :data:`FINDING_COLUMNS` (a column the run lacks is left out)."""
    if "both_infeasible_steps" not in v.column_names or v.num_rows == 0:
        return []
    cols = [c for c in FINDING_COLUMNS if c in v.column_names]
    values = {c: floats(v, c) for c in cols}
    out = []
    for i in np.flatnonzero(values["both_infeasible_steps"] > 0):
        out.append({c: int(values[c][i]) for c in cols if np.isfinite(values[c][i])})
    return sorted(out, key=lambda f: f.get("episode_id", 0))


def _solver(v: Columns) -> dict[str, Any]:
    if v.num_rows == 0 or "solves" not in v.column_names:
        return {}
    solves = floats(v, "solves")
    weights = np.maximum(solves, 1.0)
    out: dict[str, Any] = {"solves": int(solves.sum())}
    if "iterations_mean" in v.column_names:
        out["iterations_mean"] = float(np.average(floats(v, "iterations_mean"), weights=weights))
        out["iterations_max"] = int(np.nanmax(floats(v, "iterations_max")))
    if "cold_retries" in v.column_names:
        out["cold_retries"] = int(np.nansum(floats(v, "cold_retries")))
    if "solve_time_mean_s" in v.column_names:
        out["solve_time_mean_s"] = float(np.average(floats(v, "solve_time_mean_s"), weights=weights))
        out["solve_time_max_s"] = float(np.nanmax(floats(v, "solve_time_max_s")))
    if "solver_statuses" in v.column_names:
        out["statuses"] = _json_counts(v["solver_statuses"])
    return out


def _json_counts(texts: np.ndarray) -> dict[str, int]:
    totals: dict[str, int] = {}
    for text in texts:
        for key, count in (json.loads(text) if text else {}).items():
            totals[key] = totals.get(key, 0) + int(count)
    return dict(sorted(totals.items()))


def _counts(v: Columns) -> dict[str, dict[str, int]]:
    out: dict[str, dict[str, int]] = {}
    for name in CATEGORY_COLUMNS:
        if name in v.column_names:
            values = [str(x) for x in v[name] if x is not None and str(x) != ""]
            out[name] = {k: values.count(k) for k in sorted(set(values))}
    for name in JSON_COUNT_COLUMNS:
        if name in v.column_names:
            out[name] = _json_counts(v[name])
    return out


def _flags(t: Columns, name: str) -> np.ndarray | None:
    if name == "collision":
        present = [c for c in _COLLISION_COLUMNS if c in t.column_names]
        if not present:
            return None
        return np.logical_or.reduce([bools(t, c) for c in present])
    if name == "outside_margin":
        if "invariance_margin" not in t.column_names:
            return None
        collision = _flags(t, "collision")
        outside = floats(t, "invariance_margin") >= 0.0  # NaN (no level): not outside
        return outside if collision is None else outside & ~collision
    if name == "speed_limit_exceeded":
        return floats(t, "speed_excess_mps") > 0.0 if "speed_excess_mps" in t.column_names else None
    if name == "input_limit_exceeded":
        if "accel_excess_mps2" not in t.column_names:
            return None
        return (floats(t, "accel_excess_mps2") > 0.0) | (floats(t, "slip_excess_rad") > 0.0)
    if name in t.column_names:
        return bools(t, name)
    if name in OUTCOMES and "outcome" in t.column_names:  # the flag columns are derived from outcome
        return strings(t, "outcome") == name
    return None


def _first(t: Columns, name: str) -> Any:
    if name not in t.column_names or not t.num_rows:
        return None
    x = t[name][0]
    return x.item() if hasattr(x, "item") else x


def _num(x: Any) -> float:
    return math.nan if x is None else float(x)

