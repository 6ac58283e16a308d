"""Independent replicate runs of an estimator, per cell, through an executor: the loop that subset
simulation and splitting share.

Each replicate (a subset simulation run, an AMS run) is one executor work unit whose single row is
kept in ``runs/cellNNN_runNNN.json`` as soon as it is back, before the cell is reported, so that
``--resume`` after a kill runs only the replicates that were not kept. A cell is reported once all
its replicates are in; the folder is finished once every cell is.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcverify import files, store
from mcverify.analysis.cells import json_ready
from mcverify.campaign import executors
from mcverify.campaign.executors import EpisodeFn, Executor
from mcverify.campaign.spec import Campaign
from mcverify.cell import Cell
from mcverify.errors import RunError
from mcverify.estimate import folder
from mcverify.schema import ERROR_COLUMN, ERROR_OUTCOME

RUNS = "runs"


def run_path(out: Path, cell_index: int, replicate: int) -> Path:
    """Where a finished replicate of a cell is kept (``runs/cellNNN_runNNN.json``)."""
    return Path(out) / RUNS / f"cell{cell_index:03d}_run{replicate:03d}.json"


@dataclass(frozen=True)
class Replicated:
    """What the shared loop needs from an estimator."""

    label: str
    """What one replicate is called in messages ("subset run", "AMS run")."""
    count: int
    """Replicates per cell."""
    unit: EpisodeFn
    """The executor work unit of one replicate (its episode id is the replicate number)."""
    announce: Callable[[Cell], str]
    """The line that starts a cell."""
    done_text: Callable[[dict[str, Any]], str]
    """What a finished replicate's line says about its row."""
    cell_result: Callable[[Cell, list[dict[str, Any]]], dict[str, Any]]
    """A cell's result from its replicates' rows, in replicate order."""
    write: Callable[[dict[int, dict]], Path]
    """Writes the folder's estimate and report from the results so far; returns the report path."""


def columns(out: Path, cells: int, failing_key: str, failing_name: str,
            extra: Sequence[folder.Column] = ()) -> list[folder.Column]:
    """The report's table of a replicated estimator: one row per cell (``cells``: how many the campaign has,
    for --cell); ``extra`` after the half-width; the last column replays the first of ``failing_key``."""
    return [
        ("cell", lambda c: c["cell"]), ("estimate", lambda c: folder.estimate_text(c["estimate"])),
        ("interval", lambda c: folder.interval_text(c["low"], c["high"])),
        ("rel. half-width", lambda c: folder.num(c["relative_halfwidth"], ".2f")), *extra,
        ("control steps", lambda c: str(c["steps"])), ("CPU (s)", lambda c: folder.num(c["cpu_s"], ".0f")),
        ("crude MC steps, same width", lambda c: folder.num(c["crude_steps_same_width"])),
        ("ratio", lambda c: folder.num(c["steps_ratio_vs_crude"], ".2f")),
        ("warnings", lambda c: "; ".join(c["warnings"]) or "-"),
        (f"replay a {failing_name}", lambda c: folder.replay_text(out, c, c.get(failing_key), 0, cells)),
    ]


def load(out: Path, cell: Cell, method: Replicated) -> dict[int, dict[str, Any]]:
    """The replicates of ``cell`` kept in ``out`` (replicate -> row)."""
    got = {}
    for r in range(method.count):
        path = run_path(out, cell.index, r)
        if not path.is_file():
            continue
        row = store.read_json(path)
        if row.get("cell_index") != cell.index or row.get("cell") != cell.name or row.get("cell_episode") != r:
            raise RunError(f"{path} is not {method.label} {r} of cell {cell.name}; move it away to run it again")
        got[r] = {k: v for k, v in row.items() if k not in ("cell_index", "cell")}
    return got


def run_cells(campaign: Campaign, method: Replicated, out: Path, done: dict[int, dict], progress,
              only: list[str] | None = None, executor: Executor | None = None) -> Path:
    """Run every cell not in ``done`` (nor left out by ``only``), then finish the folder."""
    results = dict(done)
    with executor or executors.SerialExecutor() as ex:
        for cell in campaign.cells:
            if cell.index in results or (only and cell.name not in only):
                continue
            results[cell.index] = _cell(campaign, method, out, cell, progress, ex)
            method.write(results)
    folder.finish(out)
    return method.write(results)  # after finish, so that the report says the estimate is complete


def _cell(campaign: Campaign, method: Replicated, out: Path, cell: Cell, progress, ex: Executor) -> dict[str, Any]:
    got = load(out, cell, method)
    kept = f" ({len(got)} finished before, kept)" if got else ""
    progress(f"{method.announce(cell)}{kept}")

    def on_done(chunk: store.Chunk, output) -> None:
        (replicate,) = chunk.episode_ids
        row = output.rows[0]
        if row.get("outcome") == ERROR_OUTCOME:
            raise RunError(f"{method.label} {replicate} of {cell.name} failed: {row.get(ERROR_COLUMN)}")
        files.write_json_atomic(run_path(out, cell.index, replicate),
                                json_ready({"cell_index": cell.index, "cell": cell.name, **row}))
        got[replicate] = row
        progress(f"  {method.label} {replicate} done ({len(got)} of {method.count}): {method.done_text(row)}")

    chunks = [store.Chunk(cell.index, (r,)) for r in range(method.count) if r not in got]
    if chunks:
        executors.execute(campaign, chunks, on_done, executor=ex, episode_fn=method.unit)
    return method.cell_result(cell, [got[r] for r in range(method.count)])
