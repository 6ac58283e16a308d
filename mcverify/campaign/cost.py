"""What a campaign will cost before it runs (``mcverify run --dry-run``): cells, episodes, chunks
and an estimate of the CPU time from per-episode costs measured on this project's reference machine.

The figures (CPU seconds per episode at the paper's 50 Hz planner, ``results/BENCHMARKS.md``) are
per kind of cell; a cell's episodes cost about the figure times (its planner rate / 50 Hz) ** 0.57
times min(1, its time limit / 10 s), since episodes last up to their time limit and most overtakes
take 5-10 s. A slower planner has fewer steps but harder ones: a 10 Hz control step costs about twice
a 50 Hz one (:data:`RATE_EXPONENT`). Episode costs vary by an order of magnitude within a kind (a
run that meets veh_o, or that IPOPT must certify infeasible, costs more), so the estimate is a
range, not a promise.
"""

from __future__ import annotations

from dataclasses import dataclass

from mcverify.campaign.spec import Campaign
from mcverify.cell import Cell

#: CPU seconds per episode at 50 Hz, (low, high), by (controller family, veh_o on the road), with the
#: fast path (``mpc.backend = "ipm"``). Source: results/BENCHMARKS.md - Table II with ipm 4.5 s (the
#: paired run 5.2 s); Table IV (34 episodes per cell, ipm): VL-CBF 1.2-12.7 s, MPC-DC 1.1-60.8 s.
SECONDS_PER_EPISODE: dict[tuple[str, bool], tuple[float, float]] = {
    ("vlcbf", False): (4.5, 5.2),
    ("vlcbf", True): (1.2, 12.7),
    ("mpcdc", False): (4.5, 5.2),
    ("mpcdc", True): (1.1, 60.8),
}
#: IPOPT (``mpc.backend = "ipopt"``) against the fast path, CPU per episode (paired, results/BENCHMARKS.md:
#: 15.06 vs 5.16 s on Table II, 56.6 vs 15.0 s on Table IV).
IPOPT_FACTOR = 3.4
#: The planner rate of the measured figures (Hz) and the episode length they stand for (s).
REFERENCE_RATE_HZ = 50.0
#: Cost per episode grows as (rate / 50 Hz) ** RATE_EXPONENT, not linearly: at 10 Hz a control step
#: costs 0.020-0.026 CPU-s (results/BENCHMARKS.md, the 10 Hz validation cell's splitting and importance
#: runs, 850 CPU-s per 42,935 steps and 642 per 24,830), at 50 Hz about 0.010 (Table II, 4.5-5.2 CPU-s
#: per 10 s episode of 500 steps): twice as much per step, so 1 - log(2) / log(5) = 0.57. The linear
#: rule made `--dry-run` of the 10 Hz smoke campaign read 2x low (a new-user audit, stop 39).
RATE_EXPONENT = 0.57
REFERENCE_EPISODE_S = 10.0
#: Typical CPU seconds per episode at 50 Hz, by the same kinds: what the scheduler starts first (the
#: dearest) and splits finer, not a promise. With veh_o the dual VL-CBF controller solves Q2 beside
#: Q1 and often fails it near veh_o: Table IV's VL-CBF cells cost about 2.5 solver-s per episode in
#: Scenario A and 16 in B (so about 9 for the kind), its MPC-DC cells about 2; without veh_o, Table II.
TYPICAL_SECONDS_PER_EPISODE: dict[tuple[str, bool], float] = {
    ("vlcbf", False): 4.8,
    ("vlcbf", True): 9.0,
    ("mpcdc", False): 4.8,
    ("mpcdc", True): 2.0,
}


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


def cell_seconds(cell: Cell) -> tuple[float, float]:
    """CPU seconds per episode of ``cell``, (low, high)."""
    low, high = SECONDS_PER_EPISODE[_kind(cell)]
    scale = _scale(cell)
    return low * scale, high * scale


def typical_seconds(cell: Cell) -> float:
    """Typical CPU seconds per episode of ``cell`` (:data:`TYPICAL_SECONDS_PER_EPISODE`, scaled
    like :func:`cell_seconds`): the scheduler's measure of which chunks are dearest."""
    return TYPICAL_SECONDS_PER_EPISODE[_kind(cell)] * _scale(cell)


def _kind(cell: Cell) -> tuple[str, bool]:
    p = cell.params
    return ("mpcdc" if p.mpc.is_mpcdc else "vlcbf"), p.opposing.kind != "none"


def _scale(cell: Cell) -> float:
    """The planner rate, the episode length and the backend against the measured figures."""
    p = cell.params
    rate = (1.0 / p.sim.control_period_s) / REFERENCE_RATE_HZ
    scale = rate**RATE_EXPONENT * min(1.0, p.sim.max_time_s / REFERENCE_EPISODE_S)
    return scale * IPOPT_FACTOR if p.mpc.backend == "ipopt" else scale


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


def render(campaign: Campaign, chunk_size: int, workers: int) -> str:
    """The dry run's report: the cells, the counts and the estimate."""
    from mcverify.campaign.runner import describe

    est = estimate(campaign, chunk_size)
    lo, hi = est.wall_s(workers)
    return "\n".join([
        describe(campaign),
        f"{est.episodes} episodes in {est.chunks} chunks of up to {chunk_size}",
        f"estimated CPU: {duration_range(est.cpu_s_low, est.cpu_s_high)}; wall time on {workers} worker(s): "
        f"{duration_range(lo, hi)}, plus about a minute of start-up (and 1-3 minutes per solver kernel "
        "not yet compiled)",
        "(per-episode costs measured on a 2-core machine, results/BENCHMARKS.md; a rough range)",
    ])
