"""What one episode of a cell costs, by kind of cell: the measured figures behind the dry run's
estimate (:mod:`mcverify.campaign.cost`) and the scheduler's order (dearest first).

The figures (CPU seconds per episode at the paper's 50 Hz planner, ``results/BENCHMARKS.md``) are
per kind of cell; a cell's episodes cost about the figure times (its planner rate / 50 Hz) ** 0.57
times min(1, its time limit / 10 s), since episodes last up to their time limit and most overtakes
take 5-10 s. A slower planner has fewer steps but harder ones: a 10 Hz control step costs about twice
a 50 Hz one (:data:`RATE_EXPONENT`). Apart from :mod:`mcverify.campaign.cost` so that the scheduler
can read them without importing the dry run's report (which imports the runner).
"""

from __future__ import annotations

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
