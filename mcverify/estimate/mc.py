"""Crude Monte Carlo with sequential stopping: ``mcverify estimate CAMPAIGN --method mc``.

Each cell is planned with ``budget`` episodes, in chunks, through :func:`mcverify.campaign.runner.run`.
After every finished chunk the cell's stored rows are read in the pre-assigned episode order (never
in completion order, which would favour episodes that end early) and the stopping rule of
:mod:`mcverify.analysis.estimates` is applied to the gap-free prefix; once a cell is decided its
chunks that have not started are skipped. The decision is a pure function of the stored rows, so
``--resume`` (re-reading the chunk files) and the report compute the same n, k and interval.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pyarrow as pa

from mcverify import store
from mcverify.analysis.columns import Columns
from mcverify.analysis.estimates import EstimateSpec, cell_estimate
from mcverify.campaign import executors, runner
from mcverify.campaign.executors import EpisodeFn, Executor
from mcverify.campaign.spec import Campaign
from mcverify.errors import RunError

#: Manifest key of the estimate's specification.
MANIFEST_KEY = "estimate"


class SequentialStopper:
    """The runner's :class:`~mcverify.campaign.runner.Stopper` for crude Monte Carlo: keeps each
    cell's rows and marks the cell decided once its ordered prefix meets the rule."""

    def __init__(self, cells: int, spec: EstimateSpec) -> None:
        self.spec = spec
        self.rows: dict[int, list[dict[str, Any]]] = {i: [] for i in range(cells)}
        self.decided: dict[int, dict[str, Any]] = {}

    def observe(self, chunk: store.Chunk, rows: list[dict[str, Any]]) -> None:
        if chunk.cell_index in self.decided:
            return  # a chunk in flight when the cell was decided: cost, not data
        self.rows[chunk.cell_index].extend(rows)
        result = cell_estimate(Columns.from_table(pa.Table.from_pylist(self.rows[chunk.cell_index])), self.spec)
        if result["status"] != "running":
            self.decided[chunk.cell_index] = result

    def skip(self, chunk: store.Chunk) -> bool:
        return chunk.cell_index in self.decided


def run(
    campaign: Campaign,
    spec: EstimateSpec,
    run_dir: Path,
    *,
    executor: Executor | None = None,
    chunk_size: int = runner.DEFAULT_CHUNK_SIZE,
    progress: bool = True,
    episode_fn: EpisodeFn = executors.simulate,
    on_start: Callable[[int, int], None] | None = None,
) -> Path:
    """Estimate ``spec.target``'s rate in every cell of ``campaign`` (whose per-cell episode count
    must be ``spec.budget``) into the new folder ``run_dir``; returns the report path."""
    if spec.method != "mc":
        raise RunError(f"method {spec.method!r} does not run through the campaign runner")
    if any(c.episodes != spec.budget for c in campaign.cells):
        raise RunError("every cell must be planned with the budget's episode count (load it with episodes=budget)")
    stopper = SequentialStopper(len(campaign.cells), spec)
    return runner.run(
        campaign, run_dir, executor=executor, chunk_size=chunk_size, progress=progress, episode_fn=episode_fn,
        on_start=on_start, stopper=stopper, manifest_extra={MANIFEST_KEY: spec.as_dict()},
    )


def resume(
    run_dir: Path,
    *,
    executor: Executor | None = None,
    progress: bool = True,
    episode_fn: EpisodeFn = executors.simulate,
    on_start: Callable[[int, int], None] | None = None,
) -> Path:
    """Finish an interrupted estimate: the stored chunks are re-read (in plan order) first, so the
    cells already decided are not run again."""
    manifest = store.read_manifest(Path(run_dir))
    raw = manifest.get(MANIFEST_KEY)
    if not raw:
        raise RunError(f"{run_dir} is not an estimate run (no '{MANIFEST_KEY}' in its manifest); use mcverify run "
                       "--resume")
    spec = EstimateSpec.from_dict(raw)
    stopper = SequentialStopper(len(manifest["cells"]), spec)
    return runner.resume(run_dir, executor=executor, progress=progress, episode_fn=episode_fn, on_start=on_start,
                         stopper=stopper)
