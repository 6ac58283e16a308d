"""The peak resident memory of a benchmark trial: the benchmark process and every process it started.

``ru_maxrss`` is a process-lifetime maximum (it never falls back after an earlier, larger trial, and the
children's figure covers every child ever waited for), so it cannot isolate one trial. :class:`PeakRss`
instead samples, in a background thread, the summed resident set size of this process and all its
descendants (worker processes included) every ``interval_s`` during the trial, and keeps the largest sum.
A peak shorter than the interval can be missed, and pages shared between processes count once per process.
The sum includes the interpreter, JAX, CasADi and whatever earlier trials left loaded in this process, so
it is the footprint of running the trial, not the search's own data. Needs ``psutil``; without it the
peak is ``None`` (not measured).
"""

from __future__ import annotations

import threading
from types import TracebackType
from typing import Any

#: Seconds between samples.
INTERVAL_S = 0.1
MB = 1024.0 * 1024.0


def _psutil() -> Any | None:
    try:
        import psutil  # noqa: PLC0415 - optional: the peak is None without it
    except ImportError:
        return None
    return psutil


def tree_rss_bytes(psutil: Any) -> int:
    """Resident bytes of this process and its descendants now (a child that exits meanwhile counts 0)."""
    me = psutil.Process()
    total = me.memory_info().rss
    for child in me.children(recursive=True):
        try:
            total += child.memory_info().rss
        except (psutil.NoSuchProcess, psutil.AccessDenied, psutil.ZombieProcess):
            continue
    return total


class PeakRss:
    """``with PeakRss() as peak: ...``; then ``peak.peak_mb`` (None without psutil)."""

    def __init__(self, interval_s: float = INTERVAL_S) -> None:
        self.interval_s = interval_s
        self._psutil = _psutil()
        self._peak_bytes = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def measured(self) -> bool:
        return self._psutil is not None

    @property
    def peak_mb(self) -> float | None:
        return self._peak_bytes / MB if self.measured else None

    def _sample(self) -> None:
        self._peak_bytes = max(self._peak_bytes, tree_rss_bytes(self._psutil))

    def _loop(self) -> None:
        while not self._stop.wait(self.interval_s):
            self._sample()

    def __enter__(self) -> PeakRss:
        if self.measured:
            self._sample()
            self._thread = threading.Thread(target=self._loop, name="peak-rss", daemon=True)
            self._thread.start()
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        if self._thread is not None:
            self._stop.set()
            self._thread.join()
            self._sample()
