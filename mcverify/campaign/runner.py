"""Run a campaign into a run folder, or finish an interrupted one: plan chunks, execute them,
merge, summarise, run_report.

Finished chunks are written (atomically) and recorded in the ledger as they complete, so a killed
run loses at most the chunks in flight. ``resume`` re-plans the chunks from the manifest, runs only
those that are not done (see :func:`mcverify.store.verify_chunk`), and refuses a folder whose
campaign or simulation code differs from what the manifest recorded, since the finished chunks
would then not be the episodes this code would produce.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import logging
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Protocol

from tqdm.auto import tqdm

from mcverify import files, provenance, store
from mcverify.campaign import executors, lint
from mcverify.campaign.executors import ChunkOutput, EpisodeFn, Executor
from mcverify.campaign.progress import ProgressTally
from mcverify.campaign.spec import Campaign, CampaignError, campaign_from_dict
from mcverify.episode import schedule_file
from mcverify.episode.recording import EpisodeRecording
from mcverify.errors import RunError
from mcverify.levels import Level
from mcverify.model_validation import params_from_record
from mcverify.reporting import run_report
from mcverify.sim.schedule import ErrorInput

log = logging.getLogger(__name__)

#: Episodes per chunk when the command line does not say.
DEFAULT_CHUNK_SIZE = 8


# ---------------------------------------------------------------------------------- manifest


def campaign_record(campaign: Campaign) -> dict[str, Any]:
    """What defines a campaign's episodes, as JSON data: name, seed, counts, paired draws, and every
    cell's name, labels, episode range, level and parameters. Two campaigns with the same record
    produce the same episodes (with the same code)."""
    record = {
        "name": campaign.name,
        "seed": campaign.seed,
        "episodes_per_cell": campaign.episodes_per_cell,
        "common_random_numbers": campaign.common_random_numbers,
        "cells": [
            {
                "index": c.index,
                "name": c.name,
                "labels": c.labels,
                "controller": c.controller,
                "overrides": c.overrides,
                "episodes": c.episodes,
                "episode_offset": c.episode_offset,
                "epsilon": c.epsilon,
                "lambda0": c.lambda0,
                "params": dataclasses.asdict(c.params),
            }
            for c in campaign.cells
        ],
    }
    return json.loads(json.dumps(record, default=files.json_default))


def manifest_for(campaign: Campaign, chunk_size: int, kernels: dict[str, str]) -> dict[str, Any]:
    record = campaign_record(campaign)
    chunks = store.plan_chunks([c.episodes for c in campaign.cells], chunk_size)
    return {
        "format": store.FORMAT,
        "campaign": {
            "name": campaign.name,
            "description": campaign.description,
            "source": campaign.source,
            "seed": campaign.seed,
            "episodes_per_cell": campaign.episodes_per_cell,
            "common_random_numbers": campaign.common_random_numbers,
            "grid": campaign.grid,
            "axes": campaign.axes,
            "reference": campaign.reference,
            "raw": campaign.raw,
            "settings": list(campaign.settings),
        },
        "cells": record["cells"],
        "chunk_size": chunk_size,
        "chunks": {"dir": store.CHUNK_DIR, "ledger": store.LEDGER, "planned": len(chunks), "size": chunk_size},
        "kernels": kernels,
        "code": provenance.code_version(),
        "environment": provenance.environment_info(),
        "sessions": [],
    }


def campaign_from_manifest(manifest: dict[str, Any]) -> Campaign:
    """Rebuild the exact campaign a run used: its structure (cells, labels, episode counts) from the file's
    content and the command line's overrides, and every cell's parameters from what the manifest recorded
    (:func:`with_recorded_params`), never from today's defaults.

    The manifest keeps the file's content and the resolved seed and per-cell episode counts; a
    ``--episodes`` override (which replaces every bundle's own count) is recognised by the counts:
    the campaign is rebuilt without it first and with it if the counts then differ.
    """
    return with_recorded_params(expand_recorded_campaign(manifest), manifest.get("cells", []),
                                manifest["campaign"]["source"])


def expand_recorded_campaign(manifest: dict[str, Any]) -> Campaign:
    """The campaign of a run's recorded file content and overrides, expanded by this code (its cells' parameters
    are this code's, not the recorded ones: :func:`campaign_from_manifest` replaces them)."""
    camp = manifest["campaign"]
    recorded = [c.get("episodes") for c in manifest.get("cells", [])]
    last_error: CampaignError | None = None
    for episodes in (None, camp["episodes_per_cell"]):
        try:
            campaign = campaign_from_dict(camp["raw"], source=camp["source"], episodes=episodes, seed=camp["seed"])
        except CampaignError as err:
            last_error = err
            continue
        if [c.episodes for c in campaign.cells] == recorded or episodes is not None:
            return campaign
    assert last_error is not None
    raise last_error


def with_recorded_params(campaign: Campaign, cells: list[dict[str, Any]], where: str) -> Campaign:
    """``campaign`` with every cell's parameters (and so its level) replaced by those its run recorded
    (:func:`mcverify.model_validation.params_from_record`); a CampaignError naming the field when a record
    lacks one this code needs or holds an option since deleted."""
    if [c.get("name") for c in cells] != [c.name for c in campaign.cells]:
        raise CampaignError(f"{where}: the run's recorded cells are not the cells its campaign expands to")
    rebuilt = []
    for cell, record in zip(campaign.cells, cells, strict=True):
        params = params_from_record(record.get("params"), f"{where} cell {cell.name!r}")
        rebuilt.append(dataclasses.replace(cell, params=params, level=Level.of_barrier(params.barrier)))
    return dataclasses.replace(campaign, cells=tuple(rebuilt))


def first_difference(a: Any, b: Any, path: str = "") -> str | None:
    """The first place where two JSON values differ, as ``path: a -> b``; None if equal."""
    if isinstance(a, dict) and isinstance(b, dict):
        for key in list(a) + [k for k in b if k not in a]:
            diff = first_difference(a.get(key), b.get(key), f"{path}.{key}" if path else str(key))
            if diff:
                return diff
        return None
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            diff = first_difference(x, y, f"{path}[{i}]")
            if diff:
                return diff
        return None
    if a != b:
        show = lambda v: json.dumps(v)[:60]  # noqa: E731
        return f"{path or 'campaign'}: {show(a)} -> {show(b)}"
    return None


# ---------------------------------------------------------------------------------- run/resume


class Stopper(Protocol):
    """Sequential stopping of a run (``mcverify estimate``): told every finished chunk's rows (those
    already on disk first, when resuming), asked before a chunk starts whether it is still needed."""

    def observe(self, chunk: store.Chunk, rows: list[dict[str, Any]]) -> None: ...

    def skip(self, chunk: store.Chunk) -> bool: ...


@dataclasses.dataclass(frozen=True)
class _Execution:
    """How a run's chunks are executed and reported, the same for a new run and a resumed one: the
    executor (already entered), the episode function (reading the folder's error schedules, if any), and
    the settings and hooks of :func:`run` (see there)."""

    executor: Executor
    episode_fn: EpisodeFn
    progress: bool
    record_first: bool
    on_chunk: Callable[[store.ChunkRecord], None] | None
    on_start: Callable[[int, int], None] | None
    stopper: Stopper | None


def run(
    campaign: Campaign,
    run_dir: Path,
    *,
    executor: Executor | None = None,
    chunk_size: int = DEFAULT_CHUNK_SIZE,
    progress: bool = True,
    episode_fn: EpisodeFn = executors.simulate,
    record_first: bool = True,
    on_chunk: Callable[[store.ChunkRecord], None] | None = None,
    on_start: Callable[[int, int], None] | None = None,
    stopper: Stopper | None = None,
    manifest_extra: dict[str, Any] | None = None,
    schedules: Mapping[int, ErrorInput] | None = None,
) -> Path:
    """Run ``campaign`` into a new folder ``run_dir``; returns the report path.

    executor: default a :class:`~mcverify.campaign.executors.LocalExecutor` on all cores; episode_fn: the
    episode simulation (tests inject cheap ones); record_first: write the trajectory of every
    cell's first episode to ``trajectories/``; on_chunk: called with each ledger record, after the
    chunk is safely on disk; on_start: called with (chunks planned, chunks already done) once every
    check has passed and the executor is up, just before the first chunk runs; stopper: skips the
    chunks of cells already decided (only the chunks that ran are merged); manifest_extra: entries
    added to the manifest (the estimate's specification); schedules: global episode id -> its error
    schedule (:mod:`mcverify.sim.schedule`), one for every episode of the campaign: they are kept in the
    folder (:mod:`mcverify.episode.schedule_file`, named in the manifest) before any episode runs, and the
    real episode function reads them from there (so do ``resume`` and ``mcverify replay``).
    """
    run_dir = Path(run_dir)
    if chunk_size < 1:
        raise RunError(f"chunk size must be >= 1, got {chunk_size}")
    if (run_dir / store.MANIFEST).exists():
        raise RunError(f"{run_dir} already holds a run; choose another folder or use --resume {run_dir}")
    if run_dir.exists() and (not run_dir.is_dir() or any(p.name != store.LOCK for p in run_dir.iterdir())):
        raise RunError(f"{run_dir} exists and is not an empty folder; choose another folder")
    executor = executor or executors.LocalExecutor()
    with executor:  # a Ray cluster is reached before anything is written
        kernels = _prepare_kernels(campaign, episode_fn)
        run_dir.mkdir(parents=True, exist_ok=True)
        with store.run_lock(run_dir):
            if schedules is not None:
                episode_fn = _keep_schedules(campaign, run_dir, schedules, episode_fn)
                manifest_extra = {**(manifest_extra or {}), schedule_file.MANIFEST_KEY: schedule_file.SCHEDULES}
            manifest = {**manifest_for(campaign, chunk_size, kernels), **(manifest_extra or {})}
            manifest["sessions"].append(_session(executor, resumed=False))
            files.write_json_atomic(run_dir / store.MANIFEST, manifest)
            return _execute(campaign, run_dir, chunk_size, _Execution(
                executor=executor, episode_fn=episode_fn, progress=progress, record_first=record_first,
                on_chunk=on_chunk, on_start=on_start, stopper=stopper))


def resume(
    run_dir: Path,
    *,
    executor: Executor | None = None,
    progress: bool = True,
    campaign: Campaign | None = None,
    chunk_size: int | None = None,
    episode_fn: EpisodeFn = executors.simulate,
    record_first: bool = True,
    on_chunk: Callable[[store.ChunkRecord], None] | None = None,
    on_start: Callable[[int, int], None] | None = None,
    stopper: Stopper | None = None,
) -> Path:
    """Finish an interrupted run in ``run_dir``: only chunks that are not done are run.

    campaign / chunk_size: if given, they must match the run's (a check, not a change).
    Refuses (:class:`~mcverify.RunError`, one line) a folder that is not a run, a finished
    run, another manifest format, other simulation code or package versions, and a campaign that
    no longer expands to the recorded cells.
    """
    run_dir = Path(run_dir)
    manifest = store.read_manifest(run_dir)
    if manifest.get("format") != store.FORMAT:
        raise RunError(
            f"cannot resume {run_dir}: its manifest has format {manifest.get('format')!r}, this mcverify "
            f"writes format {store.FORMAT}; start a new run"
        )
    if manifest.get("finished_utc"):
        total = sum(c["episodes"] for c in manifest["cells"])
        raise RunError(
            f"{run_dir} is already finished ({total} episodes); nothing to resume "
            f"(`mcverify report {run_dir}` rebuilds its report)"
        )
    diffs = provenance.code_differences(manifest.get("code", {}), provenance.code_version())
    if diffs:
        commit = manifest.get("environment", {}).get("git_commit") or "unknown"
        raise RunError(
            f"cannot resume {run_dir}: it was started with other code ({'; '.join(diffs)}); "
            f"finish it with the code it started with (git {commit}) or start a new run"
        )
    try:
        rebuilt = campaign_from_manifest(manifest)
        expanded = expand_recorded_campaign(manifest)
    except CampaignError as err:
        raise RunError(f"cannot resume {run_dir}: its campaign no longer loads: {err}") from None
    recorded = {k: manifest["campaign"][k] for k in ("name", "seed", "episodes_per_cell", "common_random_numbers")}
    recorded["cells"] = manifest["cells"]
    # with the run's own code (checked above) its file expands to the parameters it recorded, unless the manifest
    # was edited: then the finished chunks and the recorded parameters need not agree
    diff = first_difference(recorded, campaign_record(rebuilt)) or first_difference(recorded,
                                                                                     campaign_record(expanded))
    if diff:
        raise RunError(f"cannot resume {run_dir}: its campaign expands differently with this code ({diff})")
    if campaign is not None:
        diff = first_difference(recorded, campaign_record(campaign))
        if diff:
            raise RunError(
                f"cannot resume {run_dir} with {campaign.source}: the campaign differs from the run's ({diff})"
            )
    planned = int(manifest["chunk_size"])
    if chunk_size is not None and chunk_size != planned:
        raise RunError(
            f"cannot resume {run_dir} with chunk size {chunk_size}: it was planned with {planned} "
            "(leave --chunk-size out)"
        )
    if manifest.get(schedule_file.MANIFEST_KEY):
        episode_fn = _reading_schedules(episode_fn, run_dir / manifest[schedule_file.MANIFEST_KEY])
    executor = executor or executors.LocalExecutor()
    with executor:
        kernels = _prepare_kernels(rebuilt, episode_fn)
        if executors.simulates(episode_fn) and kernels != manifest.get("kernels"):
            raise RunError(f"cannot resume {run_dir}: the solver kernels differ from the run's (compiler or CasADi)")
        with store.run_lock(run_dir):
            manifest["sessions"] = [*manifest.get("sessions", []), _session(executor, resumed=True)]
            files.write_json_atomic(run_dir / store.MANIFEST, manifest)
            return _execute(rebuilt, run_dir, planned, _Execution(
                executor=executor, episode_fn=episode_fn, progress=progress, record_first=record_first,
                on_chunk=on_chunk, on_start=on_start, stopper=stopper))


def _execute(campaign: Campaign, run_dir: Path, chunk_size: int, how: _Execution) -> Path:
    stopper = how.stopper
    chunks = store.plan_chunks([c.episodes for c in campaign.cells], chunk_size)
    done = store.done_chunks(run_dir, chunks)
    if stopper is not None:  # resume from the stored rows, in plan order
        for c in chunks:
            if c.name in done:
                table = store.read_chunk(run_dir, c)
                stopper.observe(c, table.to_pylist() if table is not None else [])
    todo = [c for c in chunks if c.name not in done]
    if how.on_start is not None:
        how.on_start(len(chunks), len(done))
    if todo:  # after every check: an error stays one line
        for warning in lint.warnings(campaign):
            log.warning("warning: %s", warning)
    done_episodes = sum(len(c.episode_ids) for c in chunks if c.name in done)
    record = [(c.index, 0) for c in campaign.cells if c.episodes > 0] if how.record_first else []
    if todo and executors.simulates(how.episode_fn) and not how.executor.warm:
        bar_note = (f"; then the bar moves as episodes finish (chunks of up to {chunk_size} run together; with Ray, "
                    "as whole chunks finish)" if how.progress else "")
        log.info("starting %s: each worker imports JAX and CasADi, loads the solver and compiles the plant once "
                 "(tens of seconds) before its first chunk%s",
                 ", ".join(f"{k} {v}" for k, v in how.executor.describe().items() if v is not None), bar_note)
    bar = tqdm(
        total=campaign.total_episodes,
        initial=done_episodes,
        unit="ep",
        desc=campaign.name,
        disable=not how.progress,
        dynamic_ncols=True,
    )
    tally = ProgressTally(bar, _unsafe_in(run_dir, [c for c in chunks if c.name in done]))

    def on_done(chunk: store.Chunk, output: ChunkOutput) -> None:
        cell = campaign.cells[chunk.cell_index]
        # Recordings first: a chunk in the ledger implies its trajectories are on disk.
        for episode, recording in output.recordings.items():
            _write_recording(run_dir, cell.episode_offset + int(episode), recording)
        rec = store.write_chunk(run_dir, chunk, output.rows, attempts=output.attempts)
        store.append_record(run_dir, rec)
        tally.chunk(chunk, output.rows, rec.errors)
        if how.on_chunk is not None:
            how.on_chunk(rec)
        if stopper is not None:
            stopper.observe(chunk, output.rows)

    with bar:
        executors.execute(campaign, todo, on_done, executor=how.executor, episode_fn=how.episode_fn, record=record,
                          skip=stopper.skip if stopper is not None else None, on_episode=tally.episode)
    if stopper is not None:  # the chunks of decided cells never ran: merge those that did
        ran = store.done_chunks(run_dir, chunks)
        chunks = [c for c in chunks if c.name in ran]
    log.info("merging %d chunks into %s and writing the report", len(chunks), store.EPISODES)
    cells = store.read_json(run_dir / store.MANIFEST)["cells"]
    store.merge_chunks(run_dir, chunks, {int(c["index"]): c.get("overrides", {}) for c in cells})
    path = run_report.write(run_dir)
    manifest = store.read_json(run_dir / store.MANIFEST)
    manifest["finished_utc"] = provenance.now_utc()
    files.write_json_atomic(run_dir / store.MANIFEST, manifest)
    return path


def _keep_schedules(campaign: Campaign, run_dir: Path, schedules: Mapping[int, ErrorInput],
                    episode_fn: EpisodeFn) -> EpisodeFn:
    """Write every episode's error schedule into the run folder; the episode function that reads them
    (a test's stand-in is kept as it is)."""
    wanted = {c.episode_offset + e for c in campaign.cells for e in range(c.episodes)}
    if set(schedules) != wanted:
        missing, extra = sorted(wanted - set(schedules)), sorted(set(schedules) - wanted)
        raise RunError(f"error schedules must be given for exactly the campaign's episodes 0 to {len(wanted) - 1}"
                       f" (missing: {missing[:5]}, not in the campaign: {extra[:5]})")
    folder = run_dir / schedule_file.SCHEDULES
    for episode_id, schedule in sorted(schedules.items()):
        schedule_file.write_schedule(schedule_file.schedule_path(folder, episode_id), schedule)
    return _reading_schedules(episode_fn, folder)


def _reading_schedules(episode_fn: EpisodeFn, folder: Path) -> EpisodeFn:
    """The episode function of a run with stored error schedules: the real one reads them from ``folder``; a
    test's stand-in marked ``reads_schedules = True`` gets the folder as its first argument; others are kept."""
    if episode_fn is executors.simulate:
        return functools.partial(executors.simulate_scheduled, str(folder))
    if getattr(episode_fn, "reads_schedules", False):
        return functools.partial(episode_fn, str(folder))
    return episode_fn


def _unsafe_in(run_dir: Path, chunks: list[store.Chunk]) -> int:
    """Unsafe episodes in chunks already on disk (a resumed run's count starts from them)."""
    count = 0
    for chunk in chunks:
        table = store.read_chunk(run_dir, chunk, columns=["cell_episode", "cell_index", "safe"])
        if table is not None:
            count += sum(v is False for v in table.column("safe").to_pylist())
    return count


def _write_recording(run_dir: Path, episode_id: int, recording: EpisodeRecording) -> None:
    """One episode's recording: ``trajectories/episode-NNNNNN.parquet`` and, when plans were
    recorded, ``episode-NNNNNN-plans.parquet``."""
    for suffix, columns in recording.to_columns().items():
        store.write_trajectory(run_dir, episode_id, columns, suffix=suffix)


def _prepare_kernels(campaign: Campaign, episode_fn: EpisodeFn) -> dict[str, str]:
    """Build (or load) every cell's kernel here, once, before any worker starts: workers then only
    load the cached shared object and never race to compile it. Cell name -> kernel hash."""
    if not executors.simulates(episode_fn):
        return {}
    return {c.name: executors.solver_for(c.params).kernel_hash for c in campaign.cells}


def _session(executor: Executor, *, resumed: bool) -> dict[str, Any]:
    return {"started_utc": provenance.now_utc(), "resumed": resumed, **executor.describe()}


def describe(campaign: Campaign, *, episodes: bool = True) -> str:
    """The campaign and its cells in a few lines; ``episodes=False`` leaves out the episode counts (an
    estimator that chooses its own episodes)."""
    count = f", {campaign.total_episodes} episodes" if episodes else ""
    lines = [f"{campaign.name}: {len(campaign.cells)} cells{count}"]
    for c in campaign.cells:
        each = f"  episodes={c.episodes}" if episodes else ""
        lines.append(f"  [{c.index}] {c.name}{each} eps={c.epsilon:.3g} lambda0={c.lambda0:.4g}")
    return "\n".join(lines)

