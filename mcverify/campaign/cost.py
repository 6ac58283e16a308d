"""What a campaign will cost before it runs (``mcverify run --dry-run``): cells, episodes, chunks
and an estimate of the CPU time from per-episode costs measured on this project's reference machine.

The figures per kind of cell and their scaling live in :mod:`mcverify.campaign.episode_cost`.
Episode costs vary by an order of magnitude within a kind (a
run that meets veh_o, or that IPOPT must certify infeasible, costs more), so the estimate is a
range, not a promise.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from mcverify.campaign.episode_cost import (  # noqa: F401 - the figures, read through this module too
    IPOPT_FACTOR,
    RATE_EXPONENT,
    SECONDS_PER_EPISODE,
    cell_seconds,
)
from mcverify.campaign.spec import Campaign
from mcverify.cell import Cell


@dataclass(frozen=True)
class Estimate:
    cells: int
    episodes: int
    chunks: int
    cpu_s_low: float
    cpu_s_high: float

    def wall_s(self, workers: int) -> tuple[float, float]:
        """Wall time on ``workers`` cores, if every core runs episodes all the time."""
        return self.cpu_s_low / workers, self.cpu_s_high / workers


def estimate(campaign: Campaign, chunk_size: int) -> Estimate:
    low = high = 0.0
    chunks = 0
    for cell in campaign.cells:
        lo, hi = cell_seconds(cell)
        low += lo * cell.episodes
        high += hi * cell.episodes
        chunks += -(-cell.episodes // chunk_size)
    return Estimate(len(campaign.cells), campaign.total_episodes, chunks, low, high)


def duration(seconds: float) -> str:
    """``42 s``, ``7.5 min``, ``3.2 h``, ``12 days``."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.1f} min"
    if seconds < 3 * 86400:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86400:.0f} days"


def duration_range(low_s: float, high_s: float) -> str:
    """``7.5 min``, or ``7.5 min to 1.2 h`` where the two ends read differently."""
    low, high = duration(low_s), duration(high_s)
    return low if low == high else f"{low} to {high}"


@dataclass(frozen=True)
class KernelCount:
    """The solver kernels some cells need (one per problem structure: the plain problem, and the one
    with veh_o where the cells have opposing traffic) and how many of them are not compiled yet."""

    needed: int
    missing: int

    def text(self) -> str:
        """What the kernels add to a dry run's wall time, e.g. "1 of the 2 solver kernels it needs is not
        compiled yet: add 1-3 minutes for it (once per machine)"."""
        kernels = f"solver kernel{'s' if self.needed != 1 else ''}"
        if not self.missing:
            return f"the {kernels} it needs ({self.needed}) {'are' if self.needed != 1 else 'is'} compiled already"
        each = "it" if self.missing == 1 else "each"
        return (f"{self.missing} of the {self.needed} {kernels} it needs {'is' if self.missing == 1 else 'are'} not "
                f"compiled yet: add 1-3 minutes for {each} (once per machine)")


def kernels_to_build(cells: Sequence[Cell], kernel_dir=None) -> KernelCount:
    """Count the kernels ``cells`` need and those missing from the cache (``kernel_dir``, default the
    one the run would use); looks only, builds nothing."""
    from mcverify.ocp.layout import OcpStructure  # noqa: PLC0415 - CasADi only for a dry run
    from mcverify.solver import kernels  # noqa: PLC0415

    structures = {OcpStructure.from_params(c.params, with_opposing=opp) for c in cells
                  for opp in ((False, True) if c.params.opposing.kind != "none" else (False,))}
    return KernelCount(len(structures), sum(not kernels.is_cached(s, kernel_dir) for s in structures))


def render(campaign: Campaign, chunk_size: int, workers: int) -> str:
    """The dry run's report: the cells, the counts and the estimate."""
    from mcverify.campaign.runner import describe

    est = estimate(campaign, chunk_size)
    lo, hi = est.wall_s(workers)
    return "\n".join([
        describe(campaign),
        f"{est.episodes} episodes in {est.chunks} chunks of up to {chunk_size}",
        f"estimated CPU: {duration_range(est.cpu_s_low, est.cpu_s_high)}; wall time on {workers} worker(s): "
        f"{duration_range(lo, hi)}, plus about a minute of start-up; {kernels_to_build(campaign.cells).text()}",
        "(per-episode costs measured on a 2-core machine, results/BENCHMARKS.md; a rough range)",
    ])
