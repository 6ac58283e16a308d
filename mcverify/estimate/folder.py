"""The folder of an estimate that does not run through the campaign runner (splitting, importance):
``manifest.json`` (the campaign record, the estimator's specification, the code version),
``estimate.json`` (the specification and one result per finished cell, rewritten after every cell),
``cells.parquet`` (the same results, one row per finished cell, for tables and pandas),
``summary.json`` (the results as a run folder's ``summary.json`` gives an estimate: ``estimates``),
``report.md`` and ``report.html`` (a table of the results, the estimator's figures and, where the
campaign has a numeric sweep axis such as ε, the estimates against it). ``--resume`` keeps the
finished cells: each cell's result is deterministic, so running it again would give the same
numbers. Once every cell is estimated the manifest gets ``finished_utc`` (:func:`finish`), as a run
folder's does, so that ``mcverify.open_run(DIR).finished`` says the estimate is complete.
"""

from __future__ import annotations

import json
import math
import shlex
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from mcverify import files, provenance, store
from mcverify.analysis import summary
from mcverify.analysis.cells import json_ready
from mcverify.campaign import runner
from mcverify.campaign.spec import Campaign
from mcverify.errors import RunError
from mcverify.reporting import estimate_report
from mcverify.reporting.run_figures import FigureResult
from mcverify.reporting.tables import Table

ESTIMATE = "estimate.json"
CELLS = "cells.parquet"
SUMMARY = "summary.json"
REPORT = "report.md"
HTML = "report.html"

#: A report column: (header, cell result -> text).
Column = tuple[str, Callable[[dict[str, Any]], str]]


def check_noise_is_drawn(campaign: Campaign) -> None:
    """Refuse a campaign whose cells fix the per-step noise (``noise.key_seed`` or noise branches, as
    a falsification search's counterexample does): its episodes would ignore the campaign seed and
    the cell, so estimates with distinct ``--seed`` would not be independent repetitions."""
    for cell in campaign.cells:
        n = cell.params.noise
        if n.key_seed >= 0 or n.branch_after_steps:
            field = "noise.key_seed" if n.key_seed >= 0 else "noise.branch_after_steps"
            raise RunError(f"cell {cell.name} fixes the per-step noise ({field}): an estimate's episodes must draw "
                           "their noise from the campaign seed; remove it to estimate this cell")


def check_cells(campaign: Campaign, cells: Sequence[str] | None) -> None:
    """Refuse a ``--cell`` name that is not one of the campaign's cells."""
    if cells:
        known = [c.name for c in campaign.cells]
        missing = [c for c in cells if c not in known]
        if missing:
            raise RunError(f"no cell {missing[0]!r} in {campaign.name}; cells: {', '.join(known)}")


def create(out: Path, campaign: Campaign, spec: dict[str, Any], cells: Sequence[str] | None) -> None:
    """A new estimate folder ``out`` (refused if it holds anything); ``cells``: only these cells."""
    out = Path(out)
    check_cells(campaign, cells)
    if out.exists() and any(out.iterdir()):
        raise RunError(f"{out} exists and is not empty; choose another folder or use --resume {out}")
    out.mkdir(parents=True, exist_ok=True)
    record = runner.campaign_record(campaign)
    manifest = {"format": store.FORMAT,
                "campaign": {**{k: v for k, v in record.items() if k != "cells"}, "raw": campaign.raw,
                             "source": str(campaign.source)},
                "cells": record["cells"], "estimate": spec, "only_cells": list(cells) if cells else None,
                "code": provenance.code_version(), "environment": provenance.environment_info()}
    files.write_json_atomic(out / store.MANIFEST, manifest)


def load(out: Path, method: str) -> tuple[dict[str, Any], dict[int, dict[str, Any]]]:
    """(manifest, finished cells by index) of an estimate folder made by ``method``."""
    out = Path(out)
    manifest = store.read_manifest(out)
    if (manifest.get("estimate") or {}).get("method") != method:
        raise RunError(f"{out} is not a {method} estimate")
    diffs = provenance.code_differences(manifest.get("code", {}), provenance.code_version())
    if diffs:
        raise RunError(f"cannot resume {out}: it was started with other code ({'; '.join(diffs)})")
    done = store.read_json(out / ESTIMATE)["cells"] if (out / ESTIMATE).exists() else []
    return manifest, {c["cell_index"]: c for c in done}


def finish(out: Path) -> None:
    """Mark the estimate in ``out`` complete: ``finished_utc`` in its manifest, as the campaign runner
    marks a run folder (kept as it is when a finished estimate is resumed again)."""
    out = Path(out)
    manifest = store.read_json(out / store.MANIFEST)
    if not manifest.get("finished_utc"):
        manifest["finished_utc"] = provenance.now_utc()
        files.write_json_atomic(out / store.MANIFEST, manifest)


def write(out: Path, title: str, intro: str, spec: dict[str, Any], results: dict[int, dict[str, Any]],
          columns: Sequence[Column], figures: Sequence[FigureResult] = ()) -> Path:
    """Rewrite ``estimate.json``, ``cells.parquet``, ``summary.json``, ``report.md`` and ``report.html``
    with the results so far (``figures``: the estimator's own figures, drawn already; the estimates
    against the campaign's sweep axis are drawn here); returns the ``report.md`` path."""
    out = Path(out)
    cells = [json_ready(results[i]) for i in sorted(results)]
    files.write_json_atomic(out / ESTIMATE, {"spec": json_ready(spec), "cells": cells})
    write_cells_table(out / CELLS, spec, cells)
    manifest = store.read_json(out / store.MANIFEST)
    files.write_json_atomic(out / SUMMARY, summary_record(manifest, spec, intro, cells))
    sweep = estimate_report.estimate_figure(out, manifest["cells"], cells, method=str(spec["method"]),
                                            target=str(spec["target"]), level=float(spec["level"]))
    shown = [*figures, *([sweep] if sweep else [])]
    table = Table("estimates", f"Estimated {spec['target']} probability per cell", [h for h, _ in columns],
                  [[fn(c) for _, fn in columns] for c in cells],
                  [f"Interval: {kind}." for kind in dict.fromkeys(str(c["interval"]) for c in cells
                                                                  if c.get("interval"))],
                  align="l" * len(columns))
    files.atomic_write(out / REPORT, lambda tmp: Path(tmp).write_text(
        estimate_report.markdown(title, intro, table, shown), encoding="utf-8"))
    facts = [("campaign", f"{manifest['campaign']['name']} ({manifest['campaign'].get('source', '')})"),
             ("estimator", intro), ("cells estimated", f"{len(cells)} of {len(expected_cells(manifest))}"),
             ("code", f"mcverify source {str(manifest.get('code', {}).get('source_sha256', ''))[:12]}"),
             ("finished", manifest.get("finished_utc") or "not yet: `mcverify estimate --resume " + str(out) + "`")]
    files.atomic_write(out / HTML, lambda tmp: Path(tmp).write_text(
        estimate_report.html_page(out, title, facts, table, shown), encoding="utf-8"))
    return out / REPORT


def expected_cells(manifest: dict[str, Any]) -> list[dict[str, Any]]:
    """The manifest's cells the estimate covers (all, or those named with ``--cell``)."""
    only = manifest.get("only_cells")
    return [c for c in manifest["cells"] if not only or c["name"] in only]


def summary_record(manifest: dict[str, Any], spec: dict[str, Any], intro: str,
                   cells: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """``summary.json`` of an estimate folder: what a run folder's ``summary.json`` says of an estimate
    (``estimates``: the specification, the method's description and one result per finished cell),
    with the campaign's varying axes and each estimated cell's labels, so that a script reads a
    splitting, importance or crude estimate the same way."""
    labels = {int(c["index"]): c.get("labels", {}) for c in manifest["cells"]}
    return json_ready({
        "format": store.FORMAT, "kind": "estimate", "campaign": manifest["campaign"]["name"],
        "axes": summary.varying_axes(manifest["cells"]),
        "cells_expected": len(expected_cells(manifest)), "finished": bool(manifest.get("finished_utc")),
        "estimates": {"spec": spec, "method_description": intro,
                      "cells": [{**c, "labels": labels.get(int(c["cell_index"]), {})} for c in cells]},
    })


def write_cells_table(path: Path, spec: dict[str, Any], cells: Sequence[dict[str, Any]]) -> None:
    """One row per cell result: its scalar fields as they are, a list of scalars joined with "; " (the
    warnings, the parameters), anything else (nested records) as JSON text; the estimator's method
    and target in every row."""
    import pyarrow as pa  # noqa: PLC0415 - only when writing
    import pyarrow.parquet as pq  # noqa: PLC0415

    def flat(value: Any) -> Any:
        if value is None or isinstance(value, (bool, int, float, str)):
            return value
        if isinstance(value, list) and all(isinstance(v, (bool, int, float, str)) for v in value):
            return "; ".join(str(v) for v in value)
        return json.dumps(value, sort_keys=True)

    rows = [{"method": spec.get("method"), "target": spec.get("target"), **{k: flat(v) for k, v in c.items()}}
            for c in cells]
    keys = list(dict.fromkeys(k for r in rows for k in r))
    table = pa.table({k: [r.get(k) for r in rows] for k in keys}) if rows else pa.table({})
    files.atomic_write(path, lambda tmp: pq.write_table(table, tmp))


def replay_text(out: Path, result: dict[str, Any], failing: Sequence[Any] | None, first: int, cells: int) -> str:
    """The replay command of a cell's first failing draw or particle (id ``first``), with how many
    failed, or "-" when none did (or the folder predates the list)."""
    if not failing:
        return "-"
    cell = f" --cell {shlex.quote(result['cell'])}" if cells > 1 else ""
    return f"`mcverify replay {shlex.quote(str(out))} {first}{cell}` ({len(failing)} failing)"


def estimate_text(x: float | None) -> str:
    """An estimate for the report: "not estimated" where there is none (None in JSON or NaN; the
    warnings say why)."""
    return "not estimated" if x is None or math.isnan(float(x)) else num(x)


def interval_text(low: float | None, high: float | None) -> str:
    """An interval for the report, "-" where there is none."""
    return "-" if low is None or high is None or math.isnan(float(low)) else f"[{num(low)}, {num(high)}]"


def num(x: float | None, fmt: str = ".3g") -> str:
    """A number for the report; "-" where it does not exist (None in JSON, NaN or inf)."""
    return "-" if x is None or not math.isfinite(float(x)) else format(float(x), fmt)
