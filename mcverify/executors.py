"""Run a campaign's chunks: in this process (``workers=1``) or on a local process pool.

Workers receive plain data (a Cell, a seed, episode ids), never CasADi objects (they do not pickle,
casadi issue 1942), and each builds or loads the cached solver once. IPOPT is parallelised across
processes, not threads (casadi issue 3456). Results do not depend on the worker count or chunk
size: every episode's randomness comes from (seed, cell, episode id) alone.
"""

from __future__ import annotations

import multiprocessing as mp
import os
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

from mcverify.campaign import Campaign, Cell
from mcverify.model import ModelParams
from mcverify.store import Chunk

_SOLVERS: dict[ModelParams, object] = {}


def solver_for(params: ModelParams):
    """This process's planner for ``params`` (its solvers built or loaded from the kernel cache once)."""
    from mcverify.planner import Planner

    if params not in _SOLVERS:
        _SOLVERS[params] = Planner(params)
    return _SOLVERS[params]


def run_chunk(cell: Cell, chunk: Chunk, seed: int, common_random_numbers: bool) -> list[dict]:
    """Simulate one chunk and return its episode rows (runs in a worker or in-process)."""
    from mcverify.rollout import run_episodes

    result = run_episodes(
        cell, chunk.episode_ids, seed, solver_for(cell.params), common_random_numbers=common_random_numbers
    )
    return result.rows


def default_workers() -> int:
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)


def execute(
    campaign: Campaign,
    chunks: list[Chunk],
    on_done: Callable[[Chunk, list[dict]], None],
    *,
    workers: int = 1,
) -> None:
    """Run ``chunks`` and hand each finished one to ``on_done`` (in this process, in order of completion)."""
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if workers == 1 or len(chunks) <= 1:
        for chunk, rows in _serial(campaign, chunks):
            on_done(chunk, rows)
        return
    for chunk, rows in _pool(campaign, chunks, workers):
        on_done(chunk, rows)


def _serial(campaign: Campaign, chunks: Iterable[Chunk]) -> Iterator[tuple[Chunk, list[dict]]]:
    for chunk in chunks:
        cell = campaign.cells[chunk.cell_index]
        yield chunk, run_chunk(cell, chunk, campaign.seed, campaign.common_random_numbers)


def _pool(campaign: Campaign, chunks: list[Chunk], workers: int) -> Iterator[tuple[Chunk, list[dict]]]:
    # spawn, not fork: JAX and CasADi hold threads and state that do not survive a fork.
    ctx = mp.get_context("spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
        pending = {
            pool.submit(
                run_chunk,
                campaign.cells[c.cell_index],
                c,
                campaign.seed,
                campaign.common_random_numbers,
            ): c
            for c in chunks
        }
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                chunk = pending.pop(fut)
                yield chunk, fut.result()
