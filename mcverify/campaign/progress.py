"""The run's progress bar: episodes done and unsafe so far, moved per episode where it can be.

Executors that report episodes inside a running chunk (serial and local workers: see
:func:`mcverify.campaign.scheduler.execute`'s ``on_episode``) move the bar one episode at a time,
with the cumulative unsafe count; the Ray executor reports whole chunks, so there the bar moves per
chunk. When a chunk's rows arrive they are the truth: the bar adds the episodes it had not been
told of, and the unsafe count takes the rows' ``safe`` column in place of the chunk's messages (an
episode reported twice, by a retried chunk, counts once). tqdm gives the rate and the ETA.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from mcverify.campaign.work import EpisodeDone
from mcverify.store import Chunk


class ProgressTally:
    """Counts behind the bar. ``bar``: a tqdm bar (or anything with ``update(n)`` and
    ``set_postfix_str(text)``); ``unsafe``: unsafe episodes in chunks already on disk (a resume)."""

    def __init__(self, bar: Any, unsafe: int = 0) -> None:
        self.bar = bar
        self.unsafe_final = unsafe  # from stored rows
        self.errors = 0
        self.pending: dict[str, dict[int, bool]] = {}  # running chunk -> episode -> unsafe

    @property
    def unsafe(self) -> int:
        """Unsafe episodes so far: those of finished chunks, and those reported by running ones."""
        return self.unsafe_final + sum(sum(got.values()) for got in self.pending.values())

    def episode(self, chunk: Chunk, done: EpisodeDone) -> None:
        """One episode of a running chunk stopped."""
        got = self.pending.setdefault(chunk.name, {})
        first = done.episode not in got
        got[done.episode] = done.unsafe
        if first:
            self.bar.update(1)
        self._postfix()

    def chunk(self, chunk: Chunk, rows: Sequence[Mapping[str, Any]], errors: int) -> None:
        """A chunk's rows arrived: the bar moves by the episodes not reported one by one."""
        told = self.pending.pop(chunk.name, {})
        self.bar.update(len(rows) - len(told.keys() & {int(r["cell_episode"]) for r in rows}))
        self.unsafe_final += sum(r.get("safe") is False for r in rows)
        self.errors += errors
        self._postfix()

    def _postfix(self) -> None:
        self.bar.set_postfix_str(f"unsafe {self.unsafe}" + (f", error episodes {self.errors}" if self.errors else ""))
