"""The local executor: spawned worker processes on this machine, one work unit at a time each.

IPOPT runs in processes, not threads (casadi issue 3456); processes are spawned, not forked, since
JAX and CasADi hold threads and state that do not survive a fork.
"""

from __future__ import annotations

import contextlib
import ctypes
import multiprocessing as mp
import multiprocessing.connection as mpc
import os
import signal
import socket
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

from mcverify.campaign.scheduler import Executor
from mcverify.campaign.work import EpisodeDone, ExecutorError, Outcome, Work, default_workers, run_work


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
                if isinstance(message, EpisodeDone):  # progress inside the unit; its outcome follows
                    if self.progress is not None:
                        self.progress(w.handle, message)
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
        with _callers_script_hidden():
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
        conn.send(run_work(work, conn.send))  # EpisodeDone messages first, then the Outcome


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


@contextlib.contextmanager
def _callers_script_hidden() -> Iterator[None]:
    """Start a spawned worker without making it re-import the caller's ``__main__``.

    A spawned child re-runs the parent's main script (or ``-m`` module) unless it is guarded by
    ``if __name__ == "__main__":``; a notebook user or a short study script should not need that
    guard. Workers only run module-level episode functions of importable modules, so they never
    need the caller's script: with ``__file__`` and ``__spec__`` hidden while the child's
    preparation data is taken (synchronously, inside ``Process.start``), it imports nothing of it.
    """
    main = sys.modules.get("__main__")
    saved = {name: getattr(main, name) for name in ("__file__", "__spec__") if hasattr(main, name)}
    try:
        for name in saved:
            if name == "__spec__":
                main.__spec__ = None
            else:
                delattr(main, name)
        yield
    finally:
        for name, value in saved.items():
            setattr(main, name, value)

