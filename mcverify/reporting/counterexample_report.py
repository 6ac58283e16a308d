"""The counterexample section of every report: the table of unsafe episodes and the worst drawn.

:func:`section` turns :func:`mcverify.analysis.counterexamples.counterexamples` records into a
report :class:`Table` (worst first, at most :data:`MAX_ROWS` rows; the whole list is in
``counterexamples.parquet``) and draws road snapshots of the worst :data:`MAX_DRAWN` whose
trajectory is stored (``trajectories/`` or ``replay/``; ``mcverify replay`` stores one).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from mcverify.analysis import counterexamples as cx
from mcverify.reporting import episode_figures, figure_common
from mcverify.reporting.run_figures import FIGURES_DIR, TRAJECTORY_DIRS, FigureResult
from mcverify.reporting.tables import Table, fmt_num

FILE = "counterexamples.parquet"
#: Rows of the report's table (every counterexample is in counterexamples.parquet).
MAX_ROWS = 25
#: Worst counterexamples drawn (those with a stored trajectory).
MAX_DRAWN = 3


def table(records: Sequence[Mapping[str, Any]], requirement: str, total_episodes: int) -> Table:
    """The counterexample table: one row per violating episode, worst first."""
    params = [k for k in (records[0] if records else {}) if k.startswith("param:") or k.startswith("sample_")]
    columns = ["episode", "cell", *[p.removeprefix("param:") for p in params], "robustness", "first unsafe (s)",
               "cause", "min gap veh_f (m)", "min h_ef", "min gap veh_o, any time (m)", "min h_eo (m)", "replay"]
    rows = []
    for r in records[:MAX_ROWS]:
        rows.append([str(r["episode_id"]), str(r["cell"]), *[_value(r.get(p)) for p in params],
                     fmt_num(r["robustness"], 3, signed=True), fmt_num(r.get("first_unsafe_s"), 2),
                     r["failure_mode"], fmt_num(r.get("min_gap_front_m"), 2), fmt_num(r.get("min_h_front"), 3),
                     fmt_num(r.get("min_gap_opp_any_m"), 2), fmt_num(r.get("min_h_opp"), 2), r["replay"]])
    notes = [f"Episodes violating `{requirement}` (robustness < 0), worst first: {len(records)} of "
             f"{total_episodes}; all of them, with the robustness of every requirement, in `{FILE}`."]
    if len(records) > MAX_ROWS:
        notes.append(f"Only the worst {MAX_ROWS} are listed here.")
    modes = cx.failure_modes(records)
    if modes:
        notes.append("Failure modes (violated requirement/what drove the ego at the first unsafe instant): "
                     + "; ".join(f"{m}: {n} (worst {fmt_num(w, 3, signed=True)})" for m, n, w in modes) + ".")
    if not records:
        notes.append("No episode violated the requirement.")
    return Table("counterexamples", f"Counterexamples ({requirement})", columns, rows, notes,
                 align="l" * 2 + "r" * (len(columns) - 3) + "l")


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
        head = (f"counterexample · episode {eid} · {r['failure_mode']} at {fmt_num(r.get('first_unsafe_s'), 2)} s"
                f" · robustness {fmt_num(r['robustness'], 3, signed=True)}")
        (Path(run_dir) / FIGURES_DIR).mkdir(exist_ok=True)
        try:
            drawn = episode_figures.snapshots(traj, plans, figure_common.params_dict(params.get(int(r["cell_index"]))),
                                              Path(run_dir) / FIGURES_DIR / f"{key}.png", title=head)
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
