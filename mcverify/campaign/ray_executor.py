"""The Ray executor: work units as Ray tasks, on a local Ray instance or an existing cluster."""

from __future__ import annotations

import contextlib
import os
import socket
from typing import Any

from mcverify.campaign.scheduler import Executor
from mcverify.campaign.work import ExecutorError, Outcome, Work, one_line, run_work


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
