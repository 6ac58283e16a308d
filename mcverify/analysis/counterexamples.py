"""Counterexamples of a run: its episodes that violate a requirement, as one sorted table.

:func:`counterexamples` reads stored rows only (``episodes.parquet`` as a pyarrow table) and the
manifest's cells; every run report and every falsification search writes the same table
(``counterexamples.parquet``). One row per violating episode, worst first (ascending robustness of
the chosen requirement, then episode id):

- identity: ``episode_id``, ``cell``, ``cell_index``, ``cell_episode``;
- the episode's inputs: the cell's overrides (``param:<section.field>``; one column per field any
  violating cell overrides) and its sampled values (``sample_*``);
- ``robustness`` (the chosen requirement) and ``rob:<name>`` for every requirement;
- the minimum margins ``min_gap_front_m``, ``min_h_front``, ``min_gap_opp_any_m``, ``min_h_opp``;
- ``first_unsafe_s`` and ``first_unsafe_cause`` (what drove the ego then), ``outcome``;
- ``first_violation_s``: when the chosen requirement was first violated
  (:func:`mcverify.analysis.robustness.first_violation_s`, from the stored trajectory when the caller
  passes ``trajectory``; NaN where it cannot be located);
- ``failure_mode``: the most violated member requirement and the driver at the first unsafe
  instant (e.g. ``collision_opp/planned``), to group distinct failures;
- ``region``: the failure region, i.e. the group of counterexamples of the same failure mode that
  lie close together in parameter space (:mod:`mcverify.analysis.failure_regions`);
- ``replay``: the command that re-simulates the episode bit for bit.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import numpy as np
import pyarrow as pa

from mcverify.analysis import failure_regions
from mcverify.analysis import robustness as rb

#: The margins copied from the row (the smallest distances and barrier values of the episode).
MARGIN_COLUMNS: tuple[str, ...] = ("min_gap_front_m", "min_h_front", "min_gap_opp_any_m", "min_h_opp")
#: Row columns copied as they are.
ROW_COLUMNS: tuple[str, ...] = ("outcome", "first_unsafe_s", "first_unsafe_cause", "stopped_at_violation")
#: The requirements whose robustness every counterexample row carries.
REPORTED: tuple[str, ...] = tuple(rb.REQUIREMENTS)


def members(requirement: str) -> tuple[str, ...]:
    """The base requirements a requirement is the minimum of (itself if it is one)."""
    return rb.SAFE_SET if requirement == "safe" else (requirement,)


def failure_mode(row: Mapping[str, Any], requirement: str) -> str:
    """``<most violated member>/<what drove the ego at the first unsafe instant>`` (the driver is
    known for the safe set only; other requirements give just the member)."""
    if rb.needs_trajectory(requirement):
        return requirement
    worst = min(members(requirement), key=lambda n: (rb.robustness(row, n), n))
    cause = row.get("first_unsafe_cause") or ""
    return f"{worst}/{cause}" if cause and worst in rb.SAFE_SET else worst


def replay_command(run_dir: str, episode_id: int) -> str:
    return f"mcverify replay {run_dir} {episode_id}"


def counterexamples(
    table: pa.Table,
    manifest: Mapping[str, Any],
    run_dir: str,
    requirement: str = "safe",
    trajectory: Callable[[int], Mapping[str, np.ndarray] | None] | None = None,
) -> list[dict[str, Any]]:
    """The rows of ``table`` that violate ``requirement``, worst first, as counterexample records
    (see the module docstring); ``run_dir`` is written into the replay commands as given;
    ``trajectory(episode_id)`` gives an episode's stored trajectory (None if not stored), read only
    for the counterexamples, to locate their first violation."""
    rb.check_requirement(requirement)
    cells = {int(c["index"]): c for c in manifest.get("cells", [])}
    robs = {int(r["episode_id"]): _robustness(r, requirement, trajectory) for r in table.to_pylist()}
    rows = [r for r in table.to_pylist() if robs[int(r["episode_id"])] < 0.0]
    rows.sort(key=lambda r: (robs[int(r["episode_id"])], int(r["episode_id"])))
    fields = sorted({k for r in rows for k in cells.get(int(r["cell_index"]), {}).get("overrides", {})})
    samples = [n for n in table.column_names if n.startswith("sample_")]
    out = []
    for r in rows:
        overrides = cells.get(int(r["cell_index"]), {}).get("overrides", {})
        rec: dict[str, Any] = {k: r.get(k) for k in ("episode_id", "cell", "cell_index", "cell_episode")}
        rec.update({f"param:{f}": _param(overrides.get(f)) for f in fields})
        rec.update({s: r.get(s) for s in samples})
        rec["robustness"] = robs[int(r["episode_id"])]
        rec.update({f"rob:{n}": rb.robustness(r, n) for n in REPORTED})
        rec.update({m: r.get(m) for m in MARGIN_COLUMNS})
        rec.update({c: r.get(c) for c in ROW_COLUMNS})
        rec["first_violation_s"] = _first_violation_s(r, cells.get(int(r["cell_index"]), {}), requirement, trajectory)
        rec["failure_mode"] = failure_mode(r, requirement)
        rec["replay"] = replay_command(run_dir, int(r["episode_id"]))
        out.append(rec)
    failure_regions.assign(out, run_bounds(out, table, cells.values()))
    return out


def _robustness(row: Mapping[str, Any], requirement: str,
                trajectory: Callable[[int], Mapping[str, np.ndarray] | None] | None) -> float:
    """The chosen requirement's robustness (an STL one from the stored trajectory: NaN if not stored)."""
    if not rb.needs_trajectory(requirement) or rb.is_error_row(row):
        return rb.robustness(row, requirement)
    traj = trajectory(int(row["episode_id"])) if trajectory is not None else None
    return rb.robustness(row, requirement, traj)


def _first_violation_s(row: Mapping[str, Any], cell: Mapping[str, Any], requirement: str,
                       trajectory: Callable[[int], Mapping[str, np.ndarray] | None] | None) -> float:
    sim = (cell.get("params") or {}).get("sim", {})
    traj = trajectory(int(row["episode_id"])) if trajectory is not None else None
    return rb.first_violation_s(row, traj, requirement, control_period_s=float(sim.get("control_period_s", math.nan)),
                                stopped_at=str(sim.get("stop_at") or ""))


def run_bounds(records: Sequence[Mapping[str, Any]], table: pa.Table,
               cells: Iterable[Mapping[str, Any]]) -> dict[str, tuple[float, float]]:
    """The scale of each numeric coordinate of a run's counterexamples (:mod:`failure_regions`): a
    ``param:`` column by the range of that override over all the run's cells, a ``sample_`` column
    by its range over all the run's episodes."""
    cells = list(cells)
    bounds = {}
    for name in failure_regions.numeric_columns(records):
        if name.startswith("param:"):
            rng = failure_regions.span([c.get("overrides", {}).get(name.removeprefix("param:")) for c in cells])
        else:
            rng = failure_regions.span(table.column(name).to_pylist())
        if rng is not None:
            bounds[name] = rng
    return bounds


def to_arrow(records: Sequence[Mapping[str, Any]]) -> pa.Table:
    """Counterexample records as an Arrow table (parameters as float where numeric, else text)."""
    if not records:
        return pa.table({"episode_id": pa.array([], pa.int64()), "robustness": pa.array([], pa.float64()),
                         "replay": pa.array([], pa.string())})
    names = list(records[0])
    return pa.table({n: pa.array([r.get(n) for r in records]) for n in names})


def failure_modes(records: Sequence[Mapping[str, Any]]) -> list[tuple[str, int, float]]:
    """Distinct failure modes: (mode, count, worst robustness), most frequent first."""
    counts = Counter(r["failure_mode"] for r in records)
    worst = {m: min(r["robustness"] for r in records if r["failure_mode"] == m) for m in counts}
    return sorted(((m, n, worst[m]) for m, n in counts.items()), key=lambda x: (-x[1], x[0]))


def _param(value: Any) -> Any:
    """A cell override as a table value: numbers as float, the rest (strings, lists) as text."""
    if value is None:
        return None
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, int | float):
        return float(value) if math.isfinite(float(value)) else float(value)
    return value if isinstance(value, str) else json.dumps(value)
