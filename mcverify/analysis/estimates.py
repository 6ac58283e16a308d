"""Rate estimates of a target event per cell, from stored episode rows: what ``mcverify estimate``
reports (``summary.json`` ``estimates``, the ``estimate_*`` columns of ``cells.parquet``).

Crude Monte Carlo with sequential stopping (method ``"mc"``): each cell's episodes are read in
their pre-assigned order (cell-local episode id 0, 1, 2, ...), up to the first id that is not
stored, and :func:`mcverify.analysis.sequential.sequential_estimate` stops at the first episode
where the anytime-valid interval is narrow enough. The result is therefore a pure function of the
stored rows: re-computing it, resuming the run, or having finished some later chunks first gives
the same n, k and interval. Episodes stored after the stopping index (chunks in flight when the
rule was met) are cost, not data.

Episodes whose outcome is ``error`` are left out of the sequence (counted in ``errors``); this
assumes a failure to simulate is unrelated to the target event, and the count is reported so that a
reader can judge.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import pyarrow as pa

from mcverify.analysis.columns import Columns, bools, floats, strings
from mcverify.analysis.sequential import DEFAULT_PRIOR, StopRule, sequential_estimate
from mcverify.requirements import TARGETS as REGISTERED_TARGETS
from mcverify.schema import ERROR_OUTCOME

#: Target events an estimate can be asked for: name -> one-line definition (the registry's
#: :data:`mcverify.requirements.TARGETS`).
TARGETS: dict[str, str] = {name: t.definition for name, t in REGISTERED_TARGETS.items()}

#: Estimation methods and how their interval is to be read.
METHODS: dict[str, str] = {
    "mc": "crude Monte Carlo, stopped on the half-width of an anytime-valid beta-binomial confidence sequence",
}


@dataclass(frozen=True)
class EstimateSpec:
    """What ``mcverify estimate`` was asked (stored in the manifest's ``estimate``): method, target
    event, half-width (absolute, or relative to the estimate), episode budget per cell, level and the
    mixture prior of the confidence sequence."""

    method: str = "mc"
    target: str = "collision"
    halfwidth: float | None = None
    relative: bool = False
    budget: int = 1000
    level: float = 0.95
    prior: tuple[float, float] = DEFAULT_PRIOR

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"unknown estimation method {self.method!r}; valid: {', '.join(METHODS)}")
        if self.target not in TARGETS:
            raise ValueError(f"unknown target {self.target!r}; valid: {', '.join(TARGETS)}")
        self.rule()  # checks half-width and budget

    def rule(self) -> StopRule:
        return StopRule(self.halfwidth, self.relative, self.budget)

    def as_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["prior"] = list(self.prior)
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> EstimateSpec:
        data = dict(data)
        data["prior"] = tuple(data.get("prior", DEFAULT_PRIOR))
        return cls(**data)


def target_events(cols: Columns, target: str) -> tuple[np.ndarray, np.ndarray]:
    """(event, valid) boolean arrays per row: whether the row shows ``target``, and whether it is
    an episode that ran (not an ``error`` row)."""
    if target not in TARGETS:
        raise ValueError(f"unknown target {target!r}; valid: {', '.join(TARGETS)}")
    valid = strings(cols, "outcome") != ERROR_OUTCOME

    def flag(name: str) -> np.ndarray:
        return bools(cols, name) if name in cols.column_names else np.zeros(cols.num_rows, dtype=bool)

    spec = REGISTERED_TARGETS[target]
    if spec.negated:  # a row without the flag shows no event
        (name,) = spec.flags
        event = ~flag(name) if name in cols.column_names else np.zeros(cols.num_rows, dtype=bool)
    else:
        event = np.zeros(cols.num_rows, dtype=bool)
        for name in spec.flags:
            event = event | flag(name)
    return event & valid, valid


def ordered_prefix(cell_episodes: Sequence[int]) -> int:
    """How many rows, sorted by cell-local episode id, form the gap-free prefix 0, 1, ..., m-1."""
    ids = np.sort(np.asarray(cell_episodes, dtype=np.int64))
    hits = np.flatnonzero(ids != np.arange(ids.size))
    return int(hits[0]) if hits.size else int(ids.size)


def cell_estimate(cols: Columns, spec: EstimateSpec) -> dict[str, Any]:
    """The estimate of one cell's rows (any order): the sequential result over the gap-free prefix in
    episode order, with its cost (episodes, control steps and solver time of every stored row)."""
    order = np.argsort(floats(cols, "cell_episode"), kind="stable") if cols.num_rows else np.zeros(0, np.int64)
    cols = cols.take(order)
    ids = floats(cols, "cell_episode").astype(np.int64) if cols.num_rows else np.zeros(0, np.int64)
    rule = spec.rule()
    # the budget counts episodes, error rows included: the prefix ends there, and a cell whose budget
    # is spent is finished even when error rows left fewer outcomes in the sequence
    m = ordered_prefix(ids) if rule.budget is None else min(ordered_prefix(ids), rule.budget)
    event, valid = target_events(cols, spec.target)
    seq_valid = valid[:m]
    res = sequential_estimate(event[:m][seq_valid], rule, spec.level, spec.prior)
    if res.status == "running" and rule.budget is not None and m >= rule.budget:
        res = dataclasses.replace(res, status="budget")
    # The episode index (cell-local) at which the sequence stopped: the res.n-th valid row.
    used_rows = int(np.flatnonzero(seq_valid)[res.n - 1]) + 1 if res.n else 0
    if res.status == "budget":
        used_rows = m  # the whole budget, error rows after the last outcome included
    steps = floats(cols, "steps") if "steps" in cols.column_names else np.full(cols.num_rows, math.nan)
    solver_s = _solver_seconds(cols)
    result = res.as_dict()
    result["interval_method"] = result.pop("method")
    return {
        **result,
        "target": spec.target,
        "episodes_used": used_rows,
        "errors_used": int(used_rows - int(np.sum(seq_valid[:used_rows]))),
        "episodes_run": int(cols.num_rows),
        "steps_used": float(np.nansum(steps[:used_rows])),
        "steps_run": float(np.nansum(steps)),
        "solver_time_s": float(np.nansum(solver_s)),
    }


def estimates(table: pa.Table, spec: EstimateSpec, cells: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """One estimate per cell of the manifest's ``cells`` (index, name), in that order."""
    cols = Columns.from_table(table)
    idx = floats(cols, "cell_index").astype(np.int64) if cols.num_rows else np.zeros(0, np.int64)
    out = []
    for cell in cells:
        rows = cols.take(np.flatnonzero(idx == int(cell["index"])))
        out.append({"cell_index": int(cell["index"]), "cell": cell["name"], "method": spec.method,
                    **cell_estimate(rows, spec)})
    return out


def estimate_summary(table: pa.Table, manifest: Mapping[str, Any]) -> dict[str, Any] | None:
    """``summary.json``'s ``estimates`` for a run started by ``mcverify estimate`` (None otherwise):
    the spec, what the method's interval means, and one estimate per cell."""
    raw = manifest.get("estimate")
    if not raw:
        return None
    spec = EstimateSpec.from_dict(raw)
    return {"spec": spec.as_dict(), "method_description": METHODS[spec.method],
            "target_definition": TARGETS[spec.target],
            "cells": estimates(table, spec, manifest.get("cells", []))}


def _solver_seconds(cols: Columns) -> np.ndarray:
    """Per row: solves x mean solve time, the solver wall time of the episode (machine-dependent)."""
    if "solves" not in cols.column_names or "solve_time_mean_s" not in cols.column_names:
        return np.full(cols.num_rows, math.nan)
    return floats(cols, "solves") * floats(cols, "solve_time_mean_s")
