"""Per-cell statistics of a run: rates with exact intervals, distances, times, theorem checks."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pyarrow as pa

from mcverify import stats

#: Boolean episode columns summarised as rates with confidence intervals.
RATE_COLUMNS = (
    "safe",
    "collision_front",
    "collision_opp",
    "ellipse_violation",
    "invariance_breach",
    "overtook",
    "went_back",
    "timeout",
)

#: Continuous episode columns summarised by min / quantiles / mean with a bootstrap interval.
VALUE_COLUMNS = (
    "overtake_time_s",
    "lane_borrow_time_s",
    "min_dist_front_m",
    "min_gap_front_m",
    "min_h_front",
    "invariance_margin",
    "min_gap_opp_m",
    "min_gap_opp_any_m",
    "min_h_opp",
)


def summarise(table: pa.Table, *, level: float = 0.95, method: str = "clopper-pearson") -> dict[str, Any]:
    """Statistics per cell, in the order of the cells' indices."""
    cells = []
    idx = np.asarray(table.column("cell_index").to_numpy())
    for cell_index in sorted(set(idx.tolist())):
        sub = table.filter(pa.compute.equal(table.column("cell_index"), cell_index))
        cells.append(_cell_summary(sub, level, method))
    return {"confidence_level": level, "interval_method": method, "cells": cells}


def _cell_summary(t: pa.Table, level: float, method: str) -> dict[str, Any]:
    n = t.num_rows
    col = lambda name: np.asarray(t.column(name).to_numpy(zero_copy_only=False))  # noqa: E731
    present = set(t.column_names)
    rates = {
        name: stats.rate_summary(int(col(name).sum()), n, level=level, method=method)
        for name in RATE_COLUMNS if name in present
    }
    values = {}
    for name in (c for c in VALUE_COLUMNS if c in present):
        v = col(name).astype(float)
        finite = v[np.isfinite(v)]
        ci = stats.bootstrap_mean_interval(finite, level=level, seed=0)
        values[name] = {
            "count": int(finite.size),
            "min": _f(finite.min()) if finite.size else math.nan,
            "max": _f(finite.max()) if finite.size else math.nan,
            "mean": _f(finite.mean()) if finite.size else math.nan,
            "mean_low": _f(ci.low),
            "mean_high": _f(ci.high),
            "quantiles": stats.quantiles(finite),
        }
    both = col("both_infeasible_steps")
    return {
        "cell": t.column("cell")[0].as_py(),
        "cell_index": int(t.column("cell_index")[0].as_py()),
        "episodes": n,
        "epsilon": _f(col("epsilon")[0]),
        "lambda0": _f(col("lambda0")[0]),
        "rates": rates,
        "values": values,
        "theorem_checks": {
            "episodes_with_both_infeasible": int((both > 0).sum()),
            "both_infeasible_steps": int(both.sum()),
            "fallback_steps": int(col("fallback_steps").sum()),
            "q1_fail_steps": int(col("q1_fail_steps").sum()),
            "q2_fail_steps": int(col("q2_fail_steps").sum()),
            "invariance_breaches": int(col("invariance_breach").sum()),
        },
        "solver": {
            "solves": int(col("solves").sum()),
            "iterations_mean": _f(np.average(col("iterations_mean"), weights=np.maximum(col("solves"), 1))),
            "iterations_max": int(col("iterations_max").max()),
            "solve_time_mean_s": _f(np.average(col("solve_time_mean_s"), weights=np.maximum(col("solves"), 1))),
            "solve_time_max_s": _f(col("solve_time_max_s").max()),
        },
    }


def _f(x: Any) -> float:
    return float(x)
