"""The per-cell summary as files: ``cells.parquet`` (one typed row per cell) and strict JSON.

The statistics themselves are computed by :mod:`mcverify.analysis.summary`; this module only lays
them out for ``cells.parquet`` and ``summary.json``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

import pyarrow as pa

from mcverify import schema
from mcverify.analysis import stats
from mcverify.analysis.metrics import RATE_NAMES, VALUE_NAMES
from mcverify.analysis.summary import (
    CATEGORY_COLUMNS,
    JSON_COUNT_COLUMNS,
    OUTCOMES,
    QUANTILES,
    THEOREM_CHECKS,
)


def cells_table(summ: Mapping[str, Any]) -> pa.Table:
    """``cells.parquet``: one row per cell, every statistic of :func:`summarise` as a flat column.

    Columns: ``cell_index``, ``cell``, ``label_<axis>`` for every axis, then every model field that
    differs between cells (the grid's and the axes' fields) under its campaign name, e.g.
    ``barrier.epsilon`` or ``scenario.front_speed_kmh``, typed (:func:`varied_fields`), ``controller``,
    ``opposing_kind``, ``epsilon``, ``lambda0``, ``episodes_planned``, ``episodes``, ``valid``,
    ``interval_method`` (the rates' interval: exact, Wilson or an estimate's confidence sequence),
    ``outcome_<o>``; per rate ``<rate>_{k,n,rate,low,high,lower_one_sided,upper_one_sided}``; per value
    ``<value>_{count,min,max,mean,mean_low,mean_high,std,q5,q25,q50,q75,q95}``; then
    ``thm_<check>``, ``count_<column>`` (JSON object strings) and ``solver_<field>``. Missing
    statistics are nulls; the column order is fixed.
    """
    cells = summ["cells"]
    axes = []
    for c in cells:
        for a in c["labels"]:
            if a not in axes:
                axes.append(a)
    rate_names = [r for r in (*RATE_NAMES, "error") if any(r in c["rates"] for c in cells)]
    value_names = [m for m in VALUE_NAMES if any(m in c["values"] for c in cells)]
    qkeys = [stats.quantile_key(q) for q in QUANTILES if 0.0 < q < 1.0]
    thm_keys = [k for k in THEOREM_CHECKS if any(k in c["theorem_checks"] for c in cells)]
    solver_keys = ["solves", "cold_retries", "iterations_mean", "iterations_max", "solve_time_mean_s",
                   "solve_time_max_s"]
    columns: dict[str, tuple[pa.DataType, list[Any]]] = {}
    varied = varied_fields(cells)

    def put(col: str, typ: pa.DataType, value: Any) -> None:
        columns.setdefault(col, (typ, []))[1].append(_null(value))

    for c in cells:
        put("cell_index", pa.int64(), c["cell_index"])
        put("cell", pa.string(), c["cell"])
        for a in axes:
            put(f"label_{a}", pa.string(), c["labels"].get(a))
        for key, typ in varied.items():
            put(key, typ, schema.grid_value(c.get("overrides", {}).get(key), typ))
        put("controller", pa.string(), c["controller"])
        put("opposing_kind", pa.string(), c["opposing_kind"])
        put("epsilon", pa.float64(), c["epsilon"])
        put("lambda0", pa.float64(), c["lambda0"])
        for key in ("episodes_planned", "episodes", "valid"):
            put(key, pa.int64(), c[key])
        put("interval_method", pa.string(), summ.get("interval_method"))  # which interval every rate carries
        for o in OUTCOMES:
            put(f"outcome_{o}", pa.int64(), c["outcomes"].get(o, 0))  # a summary from before "stopped" lacks it
        for r in rate_names:
            rs = c["rates"].get(r, {})
            for key, typ in (("k", pa.int64()), ("n", pa.int64())):
                put(f"{r}_{key}", typ, rs.get(key))
            for key in ("rate", "low", "high", "lower_one_sided", "upper_one_sided"):
                put(f"{r}_{key}", pa.float64(), rs.get(key))
        for m in value_names:
            vs = c["values"].get(m, {})
            put(f"{m}_count", pa.int64(), vs.get("count"))
            for key in ("min", "max", "mean", "mean_low", "mean_high", "std"):
                put(f"{m}_{key}", pa.float64(), vs.get(key))
            for q in qkeys:
                put(f"{m}_{q}", pa.float64(), vs.get("quantiles", {}).get(q))
        for key in thm_keys:
            put(f"thm_{key}", pa.int64(), c["theorem_checks"].get(key))
        for key in (*CATEGORY_COLUMNS, *JSON_COUNT_COLUMNS):
            if any(key in x.get("counts", {}) for x in cells):
                counts = c.get("counts", {}).get(key)
                put(f"count_{key}", pa.string(), None if counts is None else json.dumps(counts, sort_keys=True))
        for key in solver_keys:
            typ = pa.int64() if key in ("solves", "cold_retries", "iterations_max") else pa.float64()
            put(f"solver_{key}", typ, c["solver"].get(key))
    est = {e["cell_index"]: e for e in (summ.get("estimates") or {}).get("cells", [])}
    if est:  # a run of `mcverify estimate`: the estimate per cell as estimate_<field>
        for c in cells:
            e = est.get(c["cell_index"], {})
            for key in ("method", "target", "status", "interval_method"):
                put(f"estimate_{key}", pa.string(), e.get(key))
            for key in ("n", "k", "episodes_used", "episodes_run"):
                put(f"estimate_{key}", pa.int64(), e.get(key))
            for key in ("estimate", "low", "high", "halfwidth", "level", "steps_used", "steps_run", "solver_time_s"):
                put(f"estimate_{key}", pa.float64(), e.get(key))
    return pa.table({name: pa.array(vals, type=typ) for name, (typ, vals) in columns.items()})


def varied_fields(cells: list[Mapping[str, Any]]) -> dict[str, pa.DataType]:
    """The model fields whose value differs between cells, typed: the grid-value columns of
    :func:`mcverify.schema.grid_columns` (``episodes.parquet`` has the same ones)."""
    return schema.grid_columns([c.get("overrides", {}) for c in cells])


def json_ready(obj: Any) -> Any:
    """``obj`` with every non-finite float replaced by None (strict JSON has no NaN)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Mapping):
        return {k: json_ready(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [json_ready(v) for v in obj]
    return obj


def _null(x: Any) -> Any:
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x
