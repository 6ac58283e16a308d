"""Run a campaign's chunks: in this process, on local worker processes, or as tasks on a Ray cluster.

The entry point for callers; the parts live in :mod:`mcverify.campaign.work` (the work unit and its
outcome), :mod:`mcverify.campaign.scheduler` (scheduling, retries, the executor interface),
:mod:`mcverify.campaign.local` and :mod:`mcverify.campaign.ray_executor`. Three executors share one scheduler
(:func:`execute`):

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

from mcverify.campaign.local import MAX_STARTUP_FAILURES, LocalExecutor
from mcverify.campaign.ray_executor import RayExecutor, probe_address
from mcverify.campaign.scheduler import MAX_ATTEMPTS, ChunkOutput, Executor, KeptAlive, SerialExecutor, execute
from mcverify.campaign.work import (
    MAX_MESSAGE,
    ChunkResultLike,
    EpisodeFn,
    ExecutorError,
    Outcome,
    Work,
    default_workers,
    one_line,
    run_work,
    simulate,
    simulate_scheduled,
    simulates,
    solver_for,
)
from mcverify.episode.row import error_row
from mcverify.schema import ERROR_OUTCOME

__all__ = [
    "ERROR_OUTCOME", "MAX_ATTEMPTS", "MAX_MESSAGE", "MAX_STARTUP_FAILURES", "ChunkOutput", "ChunkResultLike",
    "EpisodeFn", "Executor", "ExecutorError", "KeptAlive", "LocalExecutor", "Outcome", "RayExecutor",
    "SerialExecutor", "Work",
    "default_workers", "error_row", "execute", "make_executor", "one_line", "probe_address", "run_work",
    "simulate", "simulate_scheduled", "simulates", "solver_for",
]


def make_executor(kind: str = "local", *, workers: int | None = None, address: str | None = None) -> Executor:
    """The executor named on the command line: ``local`` (default), ``ray`` or ``serial``."""
    if address is not None and kind != "ray":
        raise ExecutorError("--address is for the Ray executor: add --executor ray")
    if kind == "local":
        return LocalExecutor(workers)
    if kind == "ray":
        return RayExecutor(address=address, workers=workers)
    if kind == "serial":
        if workers is not None and workers != 1:
            raise ExecutorError(f"--workers {workers} is for the local and Ray executors; --executor serial runs "
                                "one episode at a time in this process")
        return SerialExecutor()
    raise ExecutorError(f"unknown executor {kind!r}; valid: local, ray, serial")
