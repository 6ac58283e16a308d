"""Run a campaign's chunks: in this process, on local worker processes, or as tasks on a Ray cluster.

Three executors share one scheduler (:func:`execute`):

* :class:`SerialExecutor`: in this process (debugging, tests; a crash of the process ends the run);
* :class:`LocalExecutor` (the default): ``workers`` spawned processes, one chunk at a time each;
  a worker that dies (segfault, out-of-memory kill) is replaced and only its own chunk is charged;
* :class:`RayExecutor`: chunks as Ray tasks (``max_retries`` for dead workers), on a local Ray
  instance or an existing cluster (``address``).

Workers receive plain data (a :class:`Work`: the Cell, episode ids, seed, the episode function),
never CasADi objects (they do not pickle, casadi issue 1942); each worker process builds or loads
the cached solver once (:func:`solver_for`). IPOPT runs in processes, not threads (casadi issue
3456). Results do not depend on the executor, the worker count or the chunk size: every episode's
randomness comes from (seed, cell, episode id) alone, and the rollout is batch-invariant.

Failures never stop a campaign. An exception escaping a chunk, or a worker that dies, is retried
(``max_attempts`` runs in all); if the chunk still fails its episodes are run one by one (with the
same retries), so a failing episode cannot take its chunk-mates with it and the result does not
depend on the chunk size; an episode that still fails becomes a row with ``outcome = "error"`` and
its ``error_message``. A row whose safety metrics are not finite (the plant state became NaN) is
also turned into an error row: a NaN must never read as "safe" or "unsafe".
"""

from __future__ import annotations

import contextlib
import ctypes
import math
import multiprocessing as mp
import multiprocessing.connection as mpc
import os
import signal
import socket
import sys
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

from mcverify import store
from mcverify.model import ModelParams
from mcverify.run.campaign import Campaign, Cell
from mcverify.store import Chunk

#: Runs of one task (a chunk, or one episode of a split chunk) before it counts as failed.
MAX_ATTEMPTS = 2
#: Row columns that are finite for every simulated episode; NaN or inf there means the plant blew up.
FINITE_METRICS = ("min_h_front", "min_dist_front_m", "min_gap_front_m", "h0_front")
ERROR_OUTCOME = "error"
#: Longest error message kept in a row (characters).
MAX_MESSAGE = 300


class ExecutorError(store.RunError):
    """The executor cannot run (Ray missing or unreachable, a worker with other code); one line."""


class ChunkResultLike(Protocol):
    """What an episode function returns (:class:`mcverify.episode.rollout.ChunkResult`): one row per
    episode, and trajectories (and optionally ``plans``) of the recorded ones, by cell-local id."""

    rows: list[dict]
    trajectories: Mapping[int, Any]


#: ``fn(cell, episode_ids, seed, common_random_numbers, record) -> ChunkResult``: simulate the
#: cell-local ``episode_ids`` of ``cell`` and also return the trajectories of the ids in ``record``
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


def simulate(
    cell: Cell, episode_ids: tuple[int, ...], seed: int, common_random_numbers: bool, record: tuple[int, ...]
) -> ChunkResultLike:
    """The real episode function: the closed loop of :func:`mcverify.episode.rollout.run_episodes`
    (``record``: the ids whose trajectories are kept; an empty tuple records nothing)."""
    from mcverify.episode.rollout import run_episodes

    return run_episodes(
        cell, list(episode_ids), seed, solver_for(cell.params),
        common_random_numbers=common_random_numbers, record=record,
    )


def default_workers() -> int:
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)


# ------------------------------------------------------------------------------ work units


@dataclass(frozen=True)
class Work:
    """What a worker runs: cell-local ``episode_ids`` of ``cell``; trajectories of ``record``."""

    cell: Cell
    episode_ids: tuple[int, ...]
    seed: int
    common_random_numbers: bool
    record: tuple[int, ...]
    episode_fn: EpisodeFn


@dataclass
class Outcome:
    """What a worker sends back: rows (None on failure) or a one-line error, and who ran it."""

    rows: list[dict] | None
    trajectories: dict[int, Any] = field(default_factory=dict)
    error: str | None = None
    code: dict[str, Any] | None = None  # the worker's store.code_version()
    worker: str = ""  # host:pid


def run_work(work: Work) -> Outcome:
    """Run one work unit and never raise: an exception becomes ``Outcome(error=...)``."""
    where = f"{socket.gethostname()}:{os.getpid()}"
    try:
        result = work.episode_fn(work.cell, work.episode_ids, work.seed, work.common_random_numbers, work.record)
        rows = [dict(r) for r in result.rows]
        got = sorted(int(r["cell_episode"]) for r in rows)
        if got != sorted(work.episode_ids):
            raise RuntimeError(f"episode function returned episodes {got}, expected {sorted(work.episode_ids)}")
        rows = [_finite_or_error(r, work.cell, work.seed) for r in rows]
        trajectories = _recorded(result, work.record)
    except Exception as exc:  # noqa: BLE001 - any failure of a chunk becomes a recorded status
        return Outcome(None, error=one_line(exc), code=store.code_version(), worker=where)
    return Outcome(rows, trajectories, code=store.code_version(), worker=where)


def _recorded(result: ChunkResultLike, record: Sequence[int]) -> dict[int, Any]:
    """Per recorded episode: its trajectory columns, or ``{"trajectory": ..., "plans": ...}`` when
    the rollout also returns plan snapshots (``ChunkResult.plans``)."""
    trajectories = result.trajectories or {}
    plans = getattr(result, "plans", None) or {}
    out: dict[int, Any] = {}
    for e in record:
        if e in trajectories and e in plans:
            out[e] = {"trajectory": trajectories[e], "plans": plans[e]}
        elif e in trajectories:
            out[e] = trajectories[e]
    return out


def one_line(exc: BaseException) -> str:
    text = f"{type(exc).__name__}: {exc}".strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return text if len(text) <= MAX_MESSAGE else text[: MAX_MESSAGE - 3] + "..."


def error_row(cell: Cell, seed: int, cell_episode: int, message: str) -> dict:
    """The row of an episode that could not be simulated: identification, the cell's level, the
    message; outcome flags False, metrics null (unknown, never counted as safe or unsafe)."""
    return {
        "episode_id": cell.episode_offset + cell_episode,
        "cell_episode": cell_episode,
        "cell": cell.name,
        "cell_index": cell.index,
        "seed": seed,
        "outcome": ERROR_OUTCOME,
        "overtook": False,
        "went_back": False,
        "timeout": False,
        "epsilon": cell.epsilon,
        "lambda0": cell.lambda0,
        store.ERROR_COLUMN: message,
    }


def _finite_or_error(row: dict, cell: Cell, seed: int) -> dict:
    if row.get("outcome") == ERROR_OUTCOME:
        return row
    for name in FINITE_METRICS:
        if name in row:
            value = row[name]
            if value is None or not math.isfinite(float(value)):
                return error_row(
                    cell, seed, int(row["cell_episode"]),
                    f"non-finite result: {name} = {value} (the plant state became NaN or inf)",
                )
    return row


# ---------------------------------------------------------------------------------- scheduler


@dataclass(frozen=True)
class ChunkOutput:
    """A finished chunk: its rows sorted by cell-local episode id, recorded trajectories (by
    cell-local id), and how many runs (chunk or single-episode) it took."""

    rows: list[dict]
    trajectories: dict[int, Any]
    attempts: int

    @property
    def errors(self) -> int:
        return sum(r.get("outcome") == ERROR_OUTCOME for r in self.rows)


@dataclass
class _Task:
    chunk: Chunk
    episode_ids: tuple[int, ...]
    attempt: int = 1


class _Scheduler:
    """Which task runs next, retries, splitting of failed chunks, and assembly of chunk results."""

    def __init__(self, campaign: Campaign, chunks: Sequence[Chunk], max_attempts: int) -> None:
        self.campaign = campaign
        self.max_attempts = max_attempts
        self.queue: deque[_Task] = deque(_Task(c, c.episode_ids) for c in chunks)
        self.runs: dict[str, int] = {}
        self.partial: dict[str, dict[int, dict]] = {}  # split chunks: cell-local id -> row
        self.partial_traj: dict[str, dict[int, Any]] = {}

    def next(self) -> _Task | None:
        return self.queue.popleft() if self.queue else None

    def finish(self, task: _Task, outcome: Outcome) -> list[tuple[Chunk, ChunkOutput]]:
        chunk = task.chunk
        self.runs[chunk.name] = self.runs.get(chunk.name, 0) + 1
        whole = task.episode_ids == chunk.episode_ids
        if outcome.error is None:
            rows = outcome.rows or []
            if whole:
                return [self._output(chunk, rows, outcome.trajectories)]
            return self._collect(chunk, rows, outcome.trajectories)
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

    def _collect(self, chunk: Chunk, rows: list[dict], trajectories: dict[int, Any]):
        got = self.partial.setdefault(chunk.name, {})
        for r in rows:
            got[int(r["cell_episode"])] = r
        self.partial_traj.setdefault(chunk.name, {}).update(trajectories)
        if len(got) < len(chunk.episode_ids):
            return []
        rows = [got[e] for e in chunk.episode_ids]
        del self.partial[chunk.name]
        return [self._output(chunk, rows, self.partial_traj.pop(chunk.name, {}))]

    def _output(self, chunk: Chunk, rows: list[dict], trajectories: dict[int, Any]):
        rows = sorted(rows, key=lambda r: int(r["cell_episode"]))
        return chunk, ChunkOutput(rows, dict(trajectories), self.runs.pop(chunk.name, 1))


def execute(
    campaign: Campaign,
    chunks: Sequence[Chunk],
    on_done: Callable[[Chunk, ChunkOutput], None],
    *,
    executor: Executor | None = None,
    episode_fn: EpisodeFn = simulate,
    record: Iterable[tuple[int, int]] = (),
    max_attempts: int = MAX_ATTEMPTS,
) -> None:
    """Run ``chunks`` on ``executor`` (default: in this process) and hand each finished one to
    ``on_done`` in this process, as soon as it is complete (results are streamed, never gathered).

    The caller enters and leaves ``executor`` (``with executor: execute(...)``), so that a Ray
    cluster is reached before anything is written. record: (cell_index, cell-local episode id)
    pairs whose trajectories are returned.
    """
    if max_attempts < 1:
        raise ValueError(f"max_attempts must be >= 1, got {max_attempts}")
    executor = executor or SerialExecutor()
    wanted: dict[int, set[int]] = {}
    for cell_index, episode in record:
        wanted.setdefault(cell_index, set()).add(episode)
    scheduler = _Scheduler(campaign, chunks, max_attempts)
    driver_code = store.code_version()
    inflight: dict[Any, _Task] = {}
    while True:
        while len(inflight) < executor.capacity:
            task = scheduler.next()
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
            diff = "; ".join(store.code_differences(outcome.code, driver_code))
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
        return handle, run_work(work)


@dataclass
class _Worker:
    proc: Any  # multiprocessing.Process (spawn context)
    conn: mpc.Connection
    handle: int | None = None
    work: Work | None = None
    ready: bool = False  # sent its start-up message: it imported everything and can run work


#: Start-up failures in a row (workers that die before they are ready) that stop the run.
MAX_STARTUP_FAILURES = 3


class LocalExecutor(Executor):
    """``workers`` spawned processes on this machine, each running one unit at a time.

    Each worker is fed through its own pipe, so the parent always knows which unit a worker holds:
    if the worker dies, exactly that unit fails ("worker process died ...") and is retried by the
    scheduler in a fresh worker. A worker that dies before it is ready (an import error, a script
    without ``if __name__ == "__main__":``) charges nothing: its unit goes to a fresh worker, and
    :data:`MAX_STARTUP_FAILURES` such deaths in a row stop the run with one line. Workers ignore
    SIGINT (the parent decides) and, on Linux, die with the parent (``PR_SET_PDEATHSIG``), so a
    killed run leaves no orphans behind.
    """

    kind = "local"

    def __init__(self, workers: int | None = None) -> None:
        workers = default_workers() if workers is None else workers
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        self.capacity = workers
        # spawn, not fork: JAX and CasADi hold threads and state that do not survive a fork.
        self._ctx = mp.get_context("spawn")
        self._workers: list[_Worker] = []
        self._next = 0
        self._startup_failures = 0

    def submit(self, work: Work) -> int:
        self._next += 1
        self._dispatch(self._next, work)
        return self._next

    def _dispatch(self, handle: int, work: Work) -> None:
        while True:
            worker = next((w for w in self._workers if w.handle is None), None) or self._start()
            try:
                worker.conn.send(work)
            except (BrokenPipeError, EOFError, OSError):  # died while idle: replace it
                self._worker_died(worker)
                continue
            worker.handle, worker.work = handle, work
            return

    def wait(self) -> tuple[int, Outcome]:
        while True:
            busy = [w for w in self._workers if w.handle is not None]
            if not busy:
                raise RuntimeError("wait() with nothing submitted")
            ready = set(mpc.wait([w.conn for w in busy] + [w.proc.sentinel for w in busy]))
            for w in busy:
                if w.conn not in ready and w.proc.sentinel not in ready:
                    continue
                message = None
                if w.conn.poll():
                    try:
                        message = w.conn.recv()
                    except Exception:  # noqa: BLE001 - EOF or a torn message: the worker died mid-send
                        message = None
                if message == _READY:
                    w.ready = True
                    self._startup_failures = 0
                    continue
                handle, work = w.handle, w.work
                if isinstance(message, Outcome):
                    w.handle = w.work = None
                    return handle, message
                was_ready = w.ready
                exitcode = self._worker_died(w)
                if not was_ready:  # not the work's fault: give it to a fresh worker
                    self._dispatch(handle, work)
                    continue
                where = f"{socket.gethostname()}:{w.proc.pid}"
                return handle, Outcome(None, error=_death_message(exitcode), worker=where)

    def close(self, failed: bool = False) -> None:
        for w in self._workers:
            if failed:
                w.proc.kill()
                continue
            with contextlib.suppress(OSError, EOFError):
                w.conn.send(None)
        for w in self._workers:
            w.proc.join(timeout=0 if failed else 30)
            if w.proc.is_alive():
                w.proc.kill()
                w.proc.join(timeout=5)
            w.conn.close()
        self._workers = []

    def describe(self) -> dict[str, Any]:
        return {"executor": self.kind, "workers": self.capacity}

    def _start(self) -> _Worker:
        parent, child = self._ctx.Pipe(duplex=True)
        proc = self._ctx.Process(target=_worker_main, args=(child,), daemon=True, name="mcverify-worker")
        proc.start()
        child.close()
        worker = _Worker(proc, parent)
        self._workers.append(worker)
        return worker

    def _worker_died(self, worker: _Worker) -> int | None:
        """Remove a dead (or broken) worker; returns its exit code. Counts start-up failures."""
        with contextlib.suppress(Exception):
            worker.conn.close()
        if worker.proc.is_alive():
            worker.proc.kill()
        worker.proc.join(timeout=5)
        self._workers.remove(worker)
        if not worker.ready:
            self._startup_failures += 1
            if self._startup_failures >= MAX_STARTUP_FAILURES:
                raise ExecutorError(
                    f"worker processes die at start-up ({_exit_reason(worker.proc.exitcode)}, "
                    f"{self._startup_failures} times in a row); see the messages above (a script that "
                    'starts a run needs `if __name__ == "__main__":`)'
                )
        return worker.proc.exitcode


_READY = "mcverify-worker-ready"


def _worker_main(conn: mpc.Connection) -> None:
    """A local worker: run units from the pipe until told to stop (None) or the parent is gone."""
    _die_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    conn.send(_READY)
    while True:
        try:
            work = conn.recv()
        except (EOFError, OSError):
            return
        if work is None:
            return
        conn.send(run_work(work))


def _die_with_parent() -> None:
    """Ask Linux to SIGKILL this process when its parent dies (no orphaned workers after kill -9)."""
    if not sys.platform.startswith("linux"):
        return
    with contextlib.suppress(OSError, AttributeError):
        PR_SET_PDEATHSIG = 1
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() == 1:  # the parent died before prctl took effect
        os._exit(1)


def _death_message(exitcode: int | None) -> str:
    if exitcode is None:
        return "worker process stopped responding"
    return f"worker process died ({_exit_reason(exitcode)})"


def _exit_reason(exitcode: int | None) -> str:
    if exitcode is None:
        return "no exit status"
    if exitcode < 0:
        try:
            return signal.Signals(-exitcode).name
        except ValueError:
            return f"signal {-exitcode}"
    return f"exit status {exitcode}"


class RayExecutor(Executor):
    """Chunks as Ray tasks, on an existing cluster (``address``, e.g. ``"auto"`` or ``"10.0.0.5:6379"``,
    or ``$RAY_ADDRESS``) or on a local Ray instance with ``workers`` CPUs.

    Tasks are retried ``max_retries`` times by Ray when their worker process or node dies; each Ray
    worker process loads the solver once (:func:`solver_for`'s module-level cache) and keeps it for
    the following tasks. At most ``capacity`` tasks (default: the cluster's CPUs) are in flight, and
    each result is fetched and written as soon as it is ready, so the driver's memory stays flat. If
    Ray was already initialised (e.g. by a test), that connection is used and left open.
    """

    kind = "ray"

    def __init__(self, address: str | None = None, workers: int | None = None, max_retries: int = 2) -> None:
        if workers is not None and workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        self.address = address or os.environ.get("RAY_ADDRESS") or None
        self.workers = workers
        self.max_retries = max_retries
        self.capacity = workers or 1
        self._ray: Any = None
        self._remote: Any = None
        self._owns = False
        self._inflight: set[Any] = set()

    def __enter__(self) -> RayExecutor:
        try:
            import ray
        except ImportError:
            raise ExecutorError(
                "the Ray executor needs Ray: pip install 'mcverify[ray]' (or use --executor local)"
            ) from None
        self._ray = ray
        if not ray.is_initialized():
            if self.address and self.address != "auto":
                probe_address(self.address)
            import logging

            kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                                      "logging_level": logging.WARNING}
            if self.address:
                kwargs["address"] = self.address
            elif self.workers:
                kwargs["num_cpus"] = self.workers
            try:
                ray.init(**kwargs)
            except Exception as exc:  # noqa: BLE001 - any start-up failure is one line for the user
                where = f" at {self.address}" if self.address else ""
                raise ExecutorError(f"cannot start or reach Ray{where}: {one_line(exc)}") from None
            self._owns = True
        self._remote = ray.remote(num_cpus=1, max_retries=self.max_retries)(run_work)
        cpus = int(ray.cluster_resources().get("CPU", 1))
        self.capacity = self.workers or max(1, cpus)
        return self

    def submit(self, work: Work) -> Any:
        ref = self._remote.remote(work)
        self._inflight.add(ref)
        return ref

    def wait(self) -> tuple[Any, Outcome]:
        ray = self._ray
        ready, _ = ray.wait(list(self._inflight), num_returns=1)
        ref = ready[0]
        self._inflight.discard(ref)
        try:
            outcome = ray.get(ref)
        except Exception as exc:  # noqa: BLE001 - a task that Ray gave up on (worker or node lost)
            outcome = Outcome(None, error=f"Ray task failed: {one_line(exc)}")
        return ref, outcome

    def close(self, failed: bool = False) -> None:
        ray = self._ray
        if ray is None:
            return
        for ref in list(self._inflight):
            with contextlib.suppress(Exception):
                ray.cancel(ref, force=True)
        self._inflight.clear()
        if self._owns and ray.is_initialized():
            ray.shutdown()
        self._owns = False

    def describe(self) -> dict[str, Any]:
        return {"executor": self.kind, "address": self.address, "capacity": self.capacity}


def probe_address(address: str, timeout_s: float = 5.0) -> None:
    """Fail fast with one line if nothing listens at a Ray ``host:port`` (``ray.init`` would wait minutes)."""
    target = address.split("://", 1)[-1]
    host, sep, port = target.rpartition(":")
    if not sep or not host or not port.isdigit():
        raise ExecutorError(f"Ray address must be HOST:PORT, ray://HOST:PORT or auto, got {address!r}")
    try:
        with socket.create_connection((host, int(port)), timeout=timeout_s):
            pass
    except OSError as err:
        raise ExecutorError(f"cannot reach the Ray cluster at {address}: {err.strerror or err}") from None


def make_executor(kind: str = "local", *, workers: int | None = None, address: str | None = None) -> Executor:
    """The executor named on the command line: ``local`` (default), ``ray`` or ``serial``."""
    if address is not None and kind != "ray":
        raise ExecutorError("--address is for the Ray executor: add --executor ray")
    if kind == "local":
        return LocalExecutor(workers)
    if kind == "ray":
        return RayExecutor(address=address, workers=workers)
    if kind == "serial":
        return SerialExecutor()
    raise ExecutorError(f"unknown executor {kind!r}; valid: local, ray, serial")
