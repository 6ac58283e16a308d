"""Which work runs next, retries, splitting of failed chunks, and the executor interface.

:func:`execute` runs a campaign's chunks on an :class:`Executor` and hands each finished chunk to
the caller as soon as it is complete. Failures never stop a campaign. An exception escaping a
chunk, or a worker that dies, is retried (``max_attempts`` runs in all); if the chunk still fails
its episodes are run one by one (with the same retries), so a failing episode cannot take its
chunk-mates with it and the result does not depend on the chunk size; an episode that still fails
becomes a row with ``outcome = "error"`` and its ``error_message``.

Order: cells differ up to about 8x in cost per episode, so on many workers the last few dear chunks
decide the wall time. The scheduler therefore starts the dearest work first (by
:func:`mcverify.campaign.episode_cost.typical_seconds`) and, with more than one worker, runs a chunk
dearer than a share of the run as several tasks (:func:`plan_tasks`). Neither changes a result:
every episode is a function of (campaign, seed, episode id) alone, and a chunk's rows are handed on
whole, in episode order, once all its tasks are in.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from mcverify import provenance
from mcverify.campaign.episode_cost import typical_seconds
from mcverify.campaign.spec import Campaign
from mcverify.campaign.work import EpisodeDone, EpisodeFn, ExecutorError, Outcome, Work, run_work, simulate
from mcverify.episode.recording import EpisodeRecording
from mcverify.episode.row import Row, error_row
from mcverify.schema import ERROR_OUTCOME
from mcverify.store import Chunk

#: Runs of one task (a chunk, or one episode of a split chunk) before it counts as failed.
MAX_ATTEMPTS = 2
#: With more than one worker, no task is planned dearer than the run's estimated cost over
#: (workers x TASKS_PER_WORKER): a few tasks per worker, so the dearest ones cannot make a long tail.
TASKS_PER_WORKER = 3


@dataclass(frozen=True)
class ChunkOutput:
    """A finished chunk: its rows sorted by cell-local episode id, the recordings of its recorded
    episodes (by cell-local id), and how many runs (chunk or single-episode) it took."""

    rows: list[Row]
    recordings: dict[int, EpisodeRecording]
    attempts: int

    @property
    def errors(self) -> int:
        return sum(r.get("outcome") == ERROR_OUTCOME for r in self.rows)


@dataclass
class _Task:
    chunk: Chunk
    episode_ids: tuple[int, ...]
    attempt: int = 1


def plan_tasks(
    chunks: Sequence[Chunk], seconds_per_episode: Sequence[float], workers: int
) -> list[tuple[Chunk, tuple[int, ...]]]:
    """The tasks that run ``chunks`` on ``workers``: (chunk, its episode ids). One worker runs the
    chunks whole in the plan's order (its wall time is the sum whatever the order); more start the
    dearest tasks first.

    seconds_per_episode: an estimate per cell index. With more than one worker, a chunk estimated
    dearer than a share of the run (its total over ``workers`` x :data:`TASKS_PER_WORKER`) is split
    into near-equal runs of consecutive episodes, each within the share (or of one episode). Tasks
    of equal cost keep the plan's order, so a cell's episodes still start in order (sequential
    stopping reads them so)."""
    if workers <= 1:
        return [(c, c.episode_ids) for c in chunks]
    share = sum(seconds_per_episode[c.cell_index] * len(c.episode_ids) for c in chunks) / (workers * TASKS_PER_WORKER)
    tasks: list[tuple[float, Chunk, tuple[int, ...]]] = []
    for chunk in chunks:
        ids, each = chunk.episode_ids, seconds_per_episode[chunk.cell_index]
        size = len(ids) if each * len(ids) <= share else max(1, math.floor(share / each))
        parts = math.ceil(len(ids) / size)
        bounds = [round(i * len(ids) / parts) for i in range(parts + 1)]
        for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
            tasks.append((each * (hi - lo), chunk, ids[lo:hi]))
    tasks.sort(key=lambda t: -t[0])  # stable: equal costs keep the plan's order
    return [(chunk, ids) for _, chunk, ids in tasks]


class _Scheduler:
    """Which task runs next, retries, splitting of failed chunks, and assembly of chunk results."""

    def __init__(self, campaign: Campaign, chunks: Sequence[Chunk], max_attempts: int, workers: int = 1) -> None:
        self.campaign = campaign
        self.max_attempts = max_attempts
        costs = [typical_seconds(cell) for cell in campaign.cells]
        planned = plan_tasks(chunks, costs, workers)
        self.queue: deque[_Task] = deque(_Task(c, ids) for c, ids in planned)
        self.pieces: dict[str, int] = {}  # tasks a chunk was planned as (absent: one)
        for c, _ in planned:
            self.pieces[c.name] = self.pieces.get(c.name, 0) + 1
        self.started: set[str] = set()  # chunks with a task submitted
        self.runs: dict[str, int] = {}
        self.partial: dict[str, dict[int, Row]] = {}  # split chunks: cell-local id -> row
        self.partial_recordings: dict[str, dict[int, EpisodeRecording]] = {}

    def next(self, skip: Callable[[Chunk], bool] | None = None) -> _Task | None:
        """The next task to submit; ``skip`` is asked once per chunk, before its first task, and a
        chunk it accepts is dropped with all its tasks."""
        while self.queue:
            task = self.queue.popleft()
            name = task.chunk.name
            if name not in self.started:
                if skip is not None and skip(task.chunk):
                    self.queue = deque(t for t in self.queue if t.chunk.name != name)
                    continue
                self.started.add(name)
            return task
        return None

    def finish(self, task: _Task, outcome: Outcome) -> list[tuple[Chunk, ChunkOutput]]:
        chunk = task.chunk
        self.runs[chunk.name] = self.runs.get(chunk.name, 0) + 1
        whole = task.episode_ids == chunk.episode_ids
        if outcome.error is None:
            rows = outcome.rows or []
            if whole:
                return [self._output(chunk, rows, outcome.recordings)]
            return self._collect(chunk, rows, outcome.recordings)
        if task.attempt < self.max_attempts:
            self.queue.appendleft(_Task(chunk, task.episode_ids, task.attempt + 1))
            return []
        if len(task.episode_ids) > 1:
            # Run the episodes one by one: a deterministic failure then costs only its own episode,
            # so the rows do not depend on which episodes happened to share its chunk.
            self.partial.setdefault(chunk.name, {})
            self.queue.extendleft(_Task(chunk, (e,)) for e in reversed(task.episode_ids))
            return []
        cell = self.campaign.cells[chunk.cell_index]
        row = error_row(cell, self.campaign.seed, task.episode_ids[0], outcome.error or "unknown failure")
        if whole:
            return [self._output(chunk, [row], {})]
        return self._collect(chunk, [row], {})

    def _collect(self, chunk: Chunk, rows: list[Row], recordings: dict[int, EpisodeRecording]):
        got = self.partial.setdefault(chunk.name, {})
        for r in rows:
            got[int(r["cell_episode"])] = r
        self.partial_recordings.setdefault(chunk.name, {}).update(recordings)
        if len(got) < len(chunk.episode_ids):
            return []
        rows = [got[e] for e in chunk.episode_ids]
        del self.partial[chunk.name]
        return [self._output(chunk, rows, self.partial_recordings.pop(chunk.name, {}))]

    def _output(self, chunk: Chunk, rows: list[Row], recordings: dict[int, EpisodeRecording]):
        rows = sorted(rows, key=lambda r: int(r["cell_episode"]))
        # a chunk planned as several tasks that each ran once took one attempt
        attempts = self.runs.pop(chunk.name, 1) - self.pieces.pop(chunk.name, 1) + 1
        self.started.discard(chunk.name)  # no task of it is left: memory stays flat over long runs
        return chunk, ChunkOutput(rows, dict(recordings), attempts)


def execute(
    campaign: Campaign,
    chunks: Sequence[Chunk],
    on_done: Callable[[Chunk, ChunkOutput], None],
    *,
    executor: Executor | None = None,
    episode_fn: EpisodeFn = simulate,
    record: Iterable[tuple[int, int]] = (),
    max_attempts: int = MAX_ATTEMPTS,
    skip: Callable[[Chunk], bool] | None = None,
    on_episode: Callable[[Chunk, EpisodeDone], None] | None = None,
) -> None:
    """Run ``chunks`` on ``executor`` (default: in this process) and hand each finished one to
    ``on_done`` in this process, as soon as it is complete (results are streamed, never gathered).

    The caller enters and leaves ``executor`` (``with executor: execute(...)``), so that a Ray
    cluster is reached before anything is written. record: (cell_index, cell-local episode id)
    pairs whose recordings are returned. skip: asked for each chunk just before it is first
    submitted; a chunk it accepts is dropped (sequential stopping: its cell is already decided).
    on_episode: told of each episode that stops inside a running chunk, where the executor reports
    them (serial and local do; Ray reports whole chunks only). A retried chunk may report an episode
    again; its rows still come once, through ``on_done``.
    """
    if max_attempts < 1:
        raise ValueError(f"max_attempts must be >= 1, got {max_attempts}")
    executor = executor or SerialExecutor()
    wanted: dict[int, set[int]] = {}
    for cell_index, episode in record:
        wanted.setdefault(cell_index, set()).add(episode)
    scheduler = _Scheduler(campaign, chunks, max_attempts, executor.capacity)
    driver_code = provenance.code_version()
    inflight: dict[Any, _Task] = {}
    if on_episode is not None:
        executor.progress = lambda handle, msg: on_episode(inflight[handle].chunk, msg) if handle in inflight else None
    try:
        _loop(campaign, scheduler, executor, inflight, wanted, episode_fn, driver_code, on_done, skip)
    finally:
        executor.progress = None


def _loop(
    campaign: Campaign,
    scheduler: _Scheduler,
    executor: Executor,
    inflight: dict[Any, _Task],
    wanted: dict[int, set[int]],
    episode_fn: EpisodeFn,
    driver_code: dict[str, Any],
    on_done: Callable[[Chunk, ChunkOutput], None],
    skip: Callable[[Chunk], bool] | None,
) -> None:
    """The body of :func:`execute`: keep the executor full, hand finished chunks on."""
    while True:
        while len(inflight) < executor.capacity:
            task = scheduler.next(skip)
            if task is None:
                break
            rec = tuple(sorted(wanted.get(task.chunk.cell_index, set()) & set(task.episode_ids)))
            work = Work(
                campaign.cells[task.chunk.cell_index], task.episode_ids, campaign.seed,
                campaign.common_random_numbers, rec, episode_fn,
            )
            inflight[executor.submit(work)] = task
        if not inflight:
            break
        handle, outcome = executor.wait()
        task = inflight.pop(handle)
        if outcome.code is not None and outcome.code != driver_code:
            diff = "; ".join(provenance.code_differences(outcome.code, driver_code))
            raise ExecutorError(
                f"worker {outcome.worker} runs other code than this process ({diff}); "
                "install the same mcverify and packages on every node"
            )
        for chunk, output in scheduler.finish(task, outcome):
            on_done(chunk, output)


# ---------------------------------------------------------------------------------- executors


class Executor(ABC):
    """Runs :class:`Work` units; ``capacity`` of them at a time. Use as a context manager."""

    kind: str = "?"
    capacity: int = 1
    #: Workers already started by an earlier run (:class:`KeptAlive`): no start-up to announce.
    warm: bool = False
    #: Set by :func:`execute` while it runs: ``progress(handle, EpisodeDone)`` for an executor that
    #: reports episodes inside a unit (None: nobody listens).
    progress: Callable[[Any, EpisodeDone], None] | None = None

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc) -> None:
        self.close(failed=exc[0] is not None)

    def close(self, failed: bool = False) -> None:  # noqa: B027 - optional hook
        """Release workers (``failed``: the run is aborting; do not wait for them)."""

    @abstractmethod
    def submit(self, work: Work) -> Any:
        """Start ``work``; returns a handle that :meth:`wait` will return with its outcome."""

    @abstractmethod
    def wait(self) -> tuple[Any, Outcome]:
        """Block until one submitted unit is finished; its handle and outcome."""

    def describe(self) -> dict[str, Any]:
        return {"executor": self.kind, "capacity": self.capacity}


class SerialExecutor(Executor):
    """In this process, one unit at a time (no crash isolation: for tests and debugging)."""

    kind = "serial"
    capacity = 1

    def __init__(self) -> None:
        self._pending: deque[tuple[int, Work]] = deque()
        self._next = 0

    def submit(self, work: Work) -> int:
        self._next += 1
        self._pending.append((self._next, work))
        return self._next

    def wait(self) -> tuple[int, Outcome]:
        handle, work = self._pending.popleft()
        report = self.progress
        return handle, run_work(work, None if report is None else lambda msg: report(handle, msg))


class KeptAlive(Executor):
    """One executor lent to several runs in turn (the generations of a falsification search).

    Leaving a run (``with``) keeps the inner executor and its workers, so they start (JAX imported,
    solver loaded, plant compiled) once for all the runs rather than once per run; :meth:`release`
    ends them, and so does a run that fails. The inner one is made by ``make`` on first entry."""

    def __init__(self, make: Callable[[], Executor]) -> None:
        self._make = make
        self._inner: Executor | None = None

    @property
    def inner(self) -> Executor:
        if self._inner is None:
            self._inner = self._make().__enter__()
        return self._inner

    def __enter__(self) -> Executor:
        inner = self.inner
        self.kind, self.capacity = inner.kind, inner.capacity
        return self

    def close(self, failed: bool = False) -> None:
        if failed:
            self.release(failed=True)

    def release(self, failed: bool = False) -> None:
        """End the inner executor's workers (``failed``: without waiting for them)."""
        if self._inner is not None:
            self._inner.close(failed=failed)
            self._inner = None
        self.warm = False

    def submit(self, work: Work) -> Any:
        self.inner.progress = self.progress
        handle = self.inner.submit(work)
        self.warm = True
        return handle

    def wait(self) -> tuple[Any, Outcome]:
        return self.inner.wait()

    def describe(self) -> dict[str, Any]:
        return self.inner.describe()
