"""The unit of work every executor runs, and what comes back from it.

Workers receive plain data (a :class:`Work`: the Cell, episode ids, seed, the episode function),
never CasADi objects (they do not pickle, casadi issue 1942); each worker process builds or loads
the cached solver once (:func:`solver_for`). What comes back (an :class:`Outcome`) is plain data as
well: episode rows (:mod:`mcverify.episode.row`) and recordings
(:class:`~mcverify.episode.recording.EpisodeRecording`), so it pickles through a pipe or Ray.

A unit never raises: an exception becomes ``Outcome(error=...)``, and a row whose safety metrics
are not finite (the plant state became NaN) becomes an error row, since a NaN must never read as
"safe" or "unsafe".

Progress inside a unit: an episode function calls :func:`episode_done` as each of its episodes
stops (the real one through the rollout's ``on_episode`` hook); :func:`run_work` hands these to the
executor's ``progress`` callback as :class:`EpisodeDone` messages (a local worker sends them up its
pipe before the outcome). They only move the progress bar: the rows come with the outcome.
"""

from __future__ import annotations

import functools
import math
import os
import socket
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from mcverify import provenance
from mcverify.cell import Cell
from mcverify.episode.recording import EpisodeRecording
from mcverify.episode.row import Row, error_row
from mcverify.errors import RunError
from mcverify.model import ModelParams
from mcverify.schema import ERROR_OUTCOME, FINITE_COLUMNS

#: Longest error message kept in a row (characters).
MAX_MESSAGE = 300


class ExecutorError(RunError):
    """The executor cannot run (Ray missing or unreachable, a worker with other code); one line."""


class ChunkResultLike(Protocol):
    """What an episode function returns (:class:`mcverify.episode.rollout.ChunkResult`): one row per
    episode, and the recordings of the recorded ones, by cell-local id."""

    rows: list[Row]
    recordings: Mapping[int, EpisodeRecording]


#: ``fn(cell, episode_ids, seed, common_random_numbers, record) -> ChunkResult``: simulate the
#: cell-local ``episode_ids`` of ``cell`` and also return the recordings of the ids in ``record``
#: (a tuple, empty for none). Must be a module-level function (or a ``functools.partial`` of one):
#: it is pickled by reference to reach worker processes.
EpisodeFn = Callable[[Cell, tuple[int, ...], int, bool, tuple[int, ...]], ChunkResultLike]

_SOLVERS: dict[ModelParams, object] = {}


def solver_for(params: ModelParams):
    """This process's planner for ``params`` (its solvers built or loaded from the kernel cache once)."""
    from mcverify.control.planner import Planner

    if params not in _SOLVERS:
        _SOLVERS[params] = Planner(params)
    return _SOLVERS[params]


@dataclass(frozen=True)
class EpisodeDone:
    """A progress message: cell-local episode ``episode`` of the running unit has stopped, and was
    ``unsafe`` (not its row: the row comes with the unit's :class:`Outcome`)."""

    episode: int
    unsafe: bool


#: Where :func:`episode_done` reports while :func:`run_work` runs a unit with a progress callback.
_PROGRESS: Callable[[EpisodeDone], None] | None = None


def episode_done(episode: int, unsafe: bool) -> None:
    """Called by an episode function when one of its episodes has stopped (cell-local id); passed on
    to the running unit's progress callback, a no-op when there is none."""
    if _PROGRESS is not None:
        _PROGRESS(EpisodeDone(int(episode), bool(unsafe)))


def simulate(
    cell: Cell, episode_ids: tuple[int, ...], seed: int, common_random_numbers: bool, record: tuple[int, ...]
) -> ChunkResultLike:
    """The real episode function: the closed loop of :func:`mcverify.episode.rollout.run_episodes`
    (``record``: the ids whose recordings are kept; an empty tuple records nothing); every episode
    that stops is reported to :func:`episode_done`."""
    from mcverify.episode.rollout import run_episodes

    return run_episodes(
        cell, list(episode_ids), seed, solver_for(cell.params),
        common_random_numbers=common_random_numbers, record=record, on_episode=episode_done,
    )


def simulate_scheduled(
    schedules_dir: str, cell: Cell, episode_ids: tuple[int, ...], seed: int, common_random_numbers: bool,
    record: tuple[int, ...],
) -> ChunkResultLike:
    """:func:`simulate` with each episode's measurement error from its stored error schedule
    (:mod:`mcverify.episode.schedule_file`: ``schedules_dir``, by global episode id); bind the folder
    with ``functools.partial``."""
    from mcverify.episode.rollout import run_episodes
    from mcverify.episode.schedule_file import read_schedule, schedule_path

    schedules = [read_schedule(schedule_path(Path(schedules_dir), cell.episode_offset + e)) for e in episode_ids]
    return run_episodes(
        cell, list(episode_ids), seed, solver_for(cell.params),
        common_random_numbers=common_random_numbers, record=record, on_episode=episode_done, schedules=schedules,
    )


def simulates(episode_fn: EpisodeFn) -> bool:
    """Whether ``episode_fn`` is a real closed loop (:func:`simulate`, or :func:`simulate_scheduled` bound
    to a folder), which needs the solver kernels, rather than a test's stand-in."""
    bound = isinstance(episode_fn, functools.partial) and episode_fn.func is simulate_scheduled
    return episode_fn is simulate or bound


def default_workers() -> int:
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)


@dataclass(frozen=True)
class Work:
    """What a worker runs: cell-local ``episode_ids`` of ``cell``; recordings of ``record``."""

    cell: Cell
    episode_ids: tuple[int, ...]
    seed: int
    common_random_numbers: bool
    record: tuple[int, ...]
    episode_fn: EpisodeFn


@dataclass
class Outcome:
    """What a worker sends back: rows (None on failure) or a one-line error, and who ran it."""

    rows: list[Row] | None
    recordings: dict[int, EpisodeRecording] = field(default_factory=dict)
    error: str | None = None
    code: dict[str, Any] | None = None  # the worker's provenance.code_version()
    worker: str = ""  # host:pid


def run_work(work: Work, progress: Callable[[EpisodeDone], None] | None = None) -> Outcome:
    """Run one work unit and never raise: an exception becomes ``Outcome(error=...)``. ``progress``
    receives an :class:`EpisodeDone` for each episode the episode function reports as stopped."""
    global _PROGRESS
    _PROGRESS = progress
    try:
        return _run(work)
    finally:
        _PROGRESS = None


def _run(work: Work) -> Outcome:
    where = f"{socket.gethostname()}:{os.getpid()}"
    try:
        result = work.episode_fn(work.cell, work.episode_ids, work.seed, work.common_random_numbers, work.record)
        rows = [dict(r) for r in result.rows]
        got = sorted(int(r["cell_episode"]) for r in rows)
        if got != sorted(work.episode_ids):
            raise RuntimeError(f"episode function returned episodes {got}, expected {sorted(work.episode_ids)}")
        rows = [_finite_or_error(r, work.cell, work.seed) for r in rows]
        recordings = _recorded(result, work.record)
    except Exception as exc:  # noqa: BLE001 - any failure of a chunk becomes a recorded status
        return Outcome(None, error=one_line(exc), code=provenance.code_version(), worker=where)
    return Outcome(rows, recordings, code=provenance.code_version(), worker=where)


def _recorded(result: ChunkResultLike, record: Sequence[int]) -> dict[int, EpisodeRecording]:
    """The recordings of the episodes in ``record`` (the episode function may return more)."""
    recordings = result.recordings or {}
    return {e: recordings[e] for e in record if e in recordings}


def one_line(exc: BaseException) -> str:
    text = f"{type(exc).__name__}: {exc}".strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return text if len(text) <= MAX_MESSAGE else text[: MAX_MESSAGE - 3] + "..."


def _finite_or_error(row: Row, cell: Cell, seed: int) -> Row:
    if row.get("outcome") == ERROR_OUTCOME:
        return row
    for name in FINITE_COLUMNS:
        if name in row:
            value = row[name]
            if value is None or not math.isfinite(float(value)):
                return error_row(
                    cell, seed, int(row["cell_episode"]),
                    f"non-finite result: {name} = {value} (the plant state became NaN or inf)",
                )
    return row
