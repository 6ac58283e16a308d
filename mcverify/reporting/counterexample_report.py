"""The counterexample section of every report: the table of unsafe episodes and the worst drawn.

:func:`section` turns :func:`mcverify.analysis.counterexamples.counterexamples` records into a
report :class:`Table` (worst first, at most :data:`MAX_ROWS` rows; the whole list is in
``counterexamples.parquet``) and draws road snapshots of the worst :data:`MAX_DRAWN` whose
trajectory is stored (``trajectories/`` or ``replay/``; ``mcverify replay`` stores one).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from mcverify.analysis import counterexamples as cx
from mcverify.analysis import failure_regions
from mcverify.reporting import episode_figures, figure_common
from mcverify.reporting.run_figures import FIGURES_DIR, TRAJECTORY_DIRS, FigureResult
from mcverify.reporting.tables import Table, fmt_num

FILE = "counterexamples.parquet"
#: Rows of the report's table (every counterexample is in counterexamples.parquet).
MAX_ROWS = 25
#: Worst counterexamples drawn (those with a stored trajectory).
MAX_DRAWN = 3
#: Failure regions listed in the counterexample table's notes (all in ``regions_table`` / the file).
MAX_REGIONS = 10


def _shown_parameters(records: Sequence[Mapping[str, Any]]) -> list[str]:
    """The ``param:`` columns, and the ``sample_`` columns that say something the table does not
    already say: not the same value in every row (of two or more), and not a copy of a ``param:``
    column (a searched or overridden field is also the episode's sampled value).
    ``counterexamples.parquet`` keeps them all."""
    keys = list(records[0]) if records else []
    params = [k for k in keys if k.startswith("param:")]

    def same(a: Any, b: Any) -> bool:
        if isinstance(a, int | float) and isinstance(b, int | float):
            return math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12) or (math.isnan(a) and math.isnan(b))
        return a == b

    def informative(k: str) -> bool:
        values = [r.get(k) for r in records]
        if len(values) > 1 and all(same(v, values[0]) for v in values):
            return False
        return not any(all(same(r.get(k), r.get(p)) for r in records) for p in params)

    return params + [k for k in keys if k.startswith("sample_") and informative(k)]


def table(records: Sequence[Mapping[str, Any]], requirement: str, total_episodes: int, *,
          audits: Mapping[str, Mapping[str, Any]] | None = None, run_dir: str = "RUN_DIR",
          audit_key: Callable[[Mapping[str, Any]], str] = lambda r: str(r["episode_id"])) -> Table:
    """The counterexample table: one row per violating episode, worst first. With ``audits`` (a run's
    ``audits.json``, or a search's gathered from its generation folders, keyed by ``audit_key`` of a
    record) a column says what the reference solver made of each episode."""
    params = _shown_parameters(records)
    columns = ["episode", "cell", *[p.removeprefix("param:") for p in params], "robustness", "first violation (s)",
               "cause", "min gap veh_f (m)", "min h_ef", "min gap veh_o, any time (m)", "min h_eo (m)", "replay"]
    if audits is not None:
        columns.insert(-1, "reference solver")
    rows = []
    for r in records[:MAX_ROWS]:
        row = [str(r["episode_id"]), str(r["cell"]), *[_value(r.get(p)) for p in params],
               fmt_num(r["robustness"], 3, signed=True), fmt_num(_first_violation(r), 2),
               r["failure_mode"], fmt_num(r.get("min_gap_front_m"), 2), fmt_num(r.get("min_h_front"), 3),
               fmt_num(r.get("min_gap_opp_any_m"), 2), fmt_num(r.get("min_h_opp"), 2), r["replay"]]
        if audits is not None:
            row.insert(-1, _audit_text(audits.get(audit_key(r))))
        rows.append(row)
    notes = [f"Episodes violating `{requirement}` (robustness < 0), worst first: {len(records)} of "
             f"{total_episodes}; all of them, with the robustness of every requirement, in `{FILE}`."]
    if audits is not None:
        notes.append("Reference solver: the same episode (same noise and draws) re-simulated with IPOPT solving "
                     "every problem at every step; \"confirmed\": it is unsafe there too, or for a search it "
                     "violates the search's requirement there too (the controller's counterexample), "
                     "\"solver-dependent\": not there (the fast solver's path decided it); "
                     f"\"not audited\": `mcverify report {run_dir} --audit` audits the rest.")
    if len(records) > MAX_ROWS:
        notes.append(f"Only the worst {MAX_ROWS} are listed here.")
    modes = cx.failure_modes(records)
    if modes:
        notes.append("Failure modes (violated requirement/what drove the ego at the first unsafe instant): "
                     + "; ".join(f"{m}: {n} (worst {fmt_num(w, 3, signed=True)})" for m, n, w in modes) + ".")
    regions = failure_regions.from_records(records)
    if regions:
        notes.append(f"Failure regions (counterexamples of one failure mode joined by steps of at most "
                     f"{failure_regions.LINK:g} of each parameter's range; column `region`): {len(regions)}. "
                     + "; ".join(_region_text(g) for g in regions[:MAX_REGIONS])
                     + (f"; ... {len(regions) - MAX_REGIONS} more." if len(regions) > MAX_REGIONS else "."))
    if not records:
        notes = [f"No episode violated `{requirement}` (robustness < 0): 0 of {total_episodes}."]
    return Table("counterexamples", f"Counterexamples ({requirement})", columns, rows, notes,
                 align="l" * 2 + "r" * (len(columns) - 3) + "l")


def regions_table(records: Sequence[Mapping[str, Any]]) -> Table:
    """One row per failure region: mode, size, worst robustness, the box per parameter, the worst's replay."""
    regions = failure_regions.from_records(records)
    shown = set(_shown_parameters(records))
    params = [p for p in regions[0].box if p in shown] if regions else []
    columns = ["region", "failure mode", "episodes", "worst robustness",
               *[p.removeprefix("param:") for p in params], "replay (worst)"]
    rows = [[str(g.region), g.failure_mode, str(g.count), fmt_num(g.worst_robustness, 3, signed=True),
             *[_box(g.box[p]) for p in params], g.worst_replay] for g in regions]
    notes = [f"Counterexamples grouped by failure mode and parameter region: within one mode, two are in the "
             f"same region when a chain of counterexamples joins them whose neighbours differ by at most "
             f"{failure_regions.LINK:g} of the searched range in every parameter (single linkage, "
             "mcverify.analysis.failure_regions); each parameter column is the box the region spans."]
    if len(regions) > 1 and all(g.count == 1 for g in regions):
        notes.insert(0, f"Every counterexample is a region of its own: no two of the {len(regions)} differ by at most "
                        f"{failure_regions.LINK:g} of the range in every parameter, so the "
                        "search found no cluster of failures at this resolution (the rows repeat the "
                        "counterexample table's).")
    return Table("failure_regions", "Failure regions", columns, rows, notes,
                 align="l" * 2 + "r" * (len(columns) - 3) + "l")


def _audit_text(entry: Mapping[str, Any] | None) -> str:
    if entry is None:
        return "not audited"
    if entry["verdict"] == "confirmed by the reference solver":
        return f"confirmed ({entry['reference_outcome']})"
    if "requirement" in entry:  # a search's audit, on its own requirement
        verdict = f"{entry['requirement']} {'violated' if entry['reference_violated'] else 'holds'}"
    else:
        verdict = "safe" if entry["reference_safe"] else "unsafe"
    return f"solver-dependent ({entry['backend']}: {entry['reference_outcome']}, {verdict})"


def _first_violation(record: Mapping[str, Any]) -> float:
    """When the record's requirement was first violated (older tables have only ``first_unsafe_s``)."""
    return record.get("first_violation_s", record.get("first_unsafe_s"))


def _region_text(g: failure_regions.Region) -> str:
    """One region for the notes; the box only for regions of two or more (a single counterexample's
    values are its row of the table)."""
    box = ", ".join(f"{p.removeprefix('param:')} {_box(b)}" for p, b in g.box.items()) if g.count > 1 else ""
    return f"region {g.region} {g.failure_mode}: {g.count} (worst {fmt_num(g.worst_robustness, 3, signed=True)}" + (
        f"; {box})" if box else ")")


def _box(b: tuple[float, float]) -> str:
    return fmt_num(b[0], 3) if b[0] == b[1] else f"{fmt_num(b[0], 3)} to {fmt_num(b[1], 3)}"


def figures(run_dir: Path, records: Sequence[Mapping[str, Any]], manifest: Mapping[str, Any]) -> list[FigureResult]:
    """Snapshots of the worst counterexamples with a stored trajectory."""
    if not records:
        return []
    params = {int(c["index"]): c.get("params") for c in manifest.get("cells", [])}
    out: list[FigureResult] = []
    for r in records:
        if len(out) >= MAX_DRAWN:
            break
        eid = int(r["episode_id"])
        stored = [Path(run_dir) / d / f"episode-{eid:06d}.parquet" for d in TRAJECTORY_DIRS]
        path = next((p for p in stored if p.is_file()), None)
        if path is None:
            continue
        traj = figure_common.load_table(path)
        plans_path = path.with_name(f"episode-{eid:06d}-plans.parquet")
        plans = figure_common.load_table(plans_path) if plans_path.is_file() else None
        key = f"counterexample-{eid:06d}"
        head = (f"counterexample · episode {eid} · {r['failure_mode']} at {fmt_num(_first_violation(r), 2)} s"
                f" · robustness {fmt_num(r['robustness'], 3, signed=True)}")
        (Path(run_dir) / FIGURES_DIR).mkdir(exist_ok=True)
        try:
            drawn = episode_figures.snapshots(traj, plans, figure_common.params_dict(params.get(int(r["cell_index"]))),
                                              Path(run_dir) / FIGURES_DIR / f"{key}.png", title=head,
                                              moment=_first_violation(r))
        except (KeyError, ValueError) as err:
            out.append(FigureResult(key, f"Counterexample {eid}", "", None, f"not drawn: {err}"))
            continue
        out.append(FigureResult(key, f"Counterexample {eid}", f"Road snapshots of counterexample {eid} "
                                f"({path.parent.name}/{path.name}); replay: `{r['replay']}`.",
                                f"{FIGURES_DIR}/{key}.png", "", drawn))
    if not out:
        out.append(FigureResult("counterexamples", "Worst counterexamples", "", None,
                                f"not drawn: no stored trajectory of a counterexample (`{records[0]['replay']}` "
                                "stores the worst one)"))
    return out


def _value(x: Any) -> str:
    if isinstance(x, float):
        return fmt_num(x, 3)
    return "–" if x is None else str(x)
