"""Episodes per wall-minute against local workers, on a small Table IV run.

``python -m benchmarks.worker_scaling [--episodes N] [--workers 1,2,4] [--campaign FILE]`` runs the
campaign once per worker count (a fresh :class:`~mcverify.campaign.local.LocalExecutor` each time, so
the wall time includes starting the workers, as a real run does), checks that every run gives the
same rows as the first (all columns but timings, bit for bit), and writes its own section of
``results/BENCHMARKS.md``: the command, the commit, the machine and one line per worker count.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass

from benchmarks import section
from mcverify import store
from mcverify.campaign import executors, scheduler
from mcverify.campaign.replay import compare_rows
from mcverify.campaign.spec import Campaign, load_campaign
from mcverify.errors import UserError

NAME = "worker_scaling"
BEGIN, END = section.markers(NAME)


@dataclass(frozen=True)
class Point:
    workers: int
    episodes: int
    wall_s: float
    same_rows: bool  # as the first run's, bit for bit (timings aside)

    @property
    def per_minute(self) -> float:
        return 60.0 * self.episodes / self.wall_s


def measure(campaign: Campaign, workers: int, chunk_size: int) -> tuple[float, dict[int, dict]]:
    """Wall seconds of running every episode of ``campaign`` on ``workers`` local workers (their
    start included), and the rows by episode id."""
    chunks = store.plan_chunks([c.episodes for c in campaign.cells], chunk_size)
    rows: dict[int, dict] = {}

    def on_done(chunk, output) -> None:
        rows.update({int(r["episode_id"]): r for r in output.rows})

    start = time.perf_counter()
    with executors.LocalExecutor(workers) as ex:
        executors.execute(campaign, chunks, on_done, executor=ex)
    return time.perf_counter() - start, rows


def run(campaign: Campaign, worker_counts: Sequence[int], chunk_size: int) -> list[Point]:
    for cell in campaign.cells:  # build any missing solver kernel now, not inside the first timing
        executors.solver_for(cell.params)
    points, first = [], None
    for w in worker_counts:
        wall_s, rows = measure(campaign, w, chunk_size)
        first = rows if first is None else first
        same = rows.keys() == first.keys() and all(not compare_rows(first[k], rows[k]) for k in rows)
        points.append(Point(w, len(rows), wall_s, same))
        print(f"{w} worker(s): {len(rows)} episodes in {wall_s:.1f} s, {points[-1].per_minute:.2f} per minute",
              file=sys.stderr)
    return points


def render(points: Sequence[Point], campaign: Campaign, chunk_size: int, cmd: str) -> str:
    """The generated Markdown section, between its markers."""
    base = points[0]
    lines = [
        "## Worker scaling: episodes per wall-minute against local workers", "",
        f"{section.provenance_line(cmd)[:-1]}; load average at the end "
        f"{[round(x, 2) for x in os.getloadavg()]}.",
        f"Campaign `{campaign.source}`, {len(campaign.cells)} cells of {campaign.cells[0].episodes} episode(s), "
        f"chunks of up to {chunk_size} (dearest tasks first; a chunk dearer than 1/{scheduler.TASKS_PER_WORKER} of "
        "a worker's share of the run split, `mcverify.campaign.scheduler.plan_tasks`); wall time from starting "
        "the workers to the last row.", "",
        "| workers | episodes | wall s | episodes per wall-minute | speed-up | efficiency | rows as with "
        f"{base.workers} worker(s) |",
        "| ---: | ---: | ---: | ---: | ---: | ---: | --- |",
    ]
    for p in points:
        speedup = p.per_minute / base.per_minute
        lines.append(f"| {p.workers} | {p.episodes} | {p.wall_s:.1f} | {p.per_minute:.2f} | {speedup:.2f}x | "
                     f"{speedup * base.workers / p.workers:.0%} | {'identical' if p.same_rows else 'DIFFERENT'} |")
    return section.wrap(NAME, "\n".join(lines))


def _worker_counts(text: str | None) -> list[int]:
    cores = executors.default_workers()
    if text is None:
        counts = [1]
        while counts[-1] * 2 < cores:
            counts.append(counts[-1] * 2)
        return sorted(set(counts) | {cores})
    try:
        counts = [int(x) for x in text.split(",")]
    except ValueError:
        raise UserError(f"--workers: expected numbers like 1,2,4, got {text!r}") from None
    if not counts or min(counts) < 1:
        raise UserError(f"--workers: every count must be >= 1, got {text!r}")
    return counts


def _parser() -> argparse.ArgumentParser:
    p = section.parser(NAME, __doc__.splitlines()[0])
    p.add_argument("--campaign", default="campaigns/table4.toml", help="campaign file (default: Table IV)")
    p.add_argument("--episodes", type=int, default=2, help="episodes per cell (default 2)")
    p.add_argument("--workers", help="comma-separated worker counts (default: 1, 2, 4, ... up to the cores)")
    p.add_argument("--chunk-size", type=int, default=8, help="episodes per chunk (default 8, as mcverify run)")
    section.add_output_options(p)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    def body() -> int:
        args = _parser().parse_args(argv)
        if args.episodes < 1 or args.chunk_size < 1:
            raise UserError("--episodes and --chunk-size must be >= 1")
        counts = _worker_counts(args.workers)
        campaign = load_campaign(args.campaign, episodes=args.episodes)
        text = render(run(campaign, counts, args.chunk_size), campaign, args.chunk_size, section.command(NAME, argv))
        section.publish(NAME, text, args)
        return 0

    return section.run_main(NAME, body)


if __name__ == "__main__":
    sys.exit(main())
