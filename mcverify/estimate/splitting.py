"""Adaptive multilevel splitting (AMS) for the probability that an episode's score reaches a level.

The episode is a Markov chain driven by per-step noise; its *score* after step t is the running
maximum of an importance function (e.g. minus the running minimum of h_ef), so it never decreases,
and the target event is "the final score >= ``failure_level``" (h_ef < 0 for the score -min h_ef
and level 0). Generalised AMS with a fixed number ``k`` of killed particles per iteration
[CG07], [BLR16]:

1. run ``n`` independent episodes (particles);
2. z = the k-th smallest final score; stop if z >= failure_level;
3. kill every particle with score <= z (K >= k of them with ties); if all are killed the estimate
   is 0 (extinction); else multiply the weight by (1 - K/n);
4. replace each killed particle by a branch of a survivor drawn uniformly, restarted from the
   snapshot right after the first step at which that survivor's score exceeded z, continued with
   fresh noise keyed by a new branch id; go to 2.

The estimate weight x (fraction of the final particles at the failure level) is unbiased for every
n and k [BLR16, Thm. 4.1]. Its variance has no closed form off the idealised continuous case, so an
interval comes from ``replicates`` independent AMS runs: their mean is unbiased and a Student t
interval on the replicate estimates is asymptotic (labelled so). A run stopped by ``max_iterations``
before the level reached the failure set is *capped*: its weight times the share at the failure level
is not an unbiased estimate (it is biased towards 0), so its estimate is NaN and it is left out of the
mean and the interval, with a warning; with fewer than 2 uncapped runs there is no estimate at all. The
relative variance of one run is close to (-log p)/n for k = 1 in the idealised case [GHM11], which is
what the cost comparison with crude Monte Carlo builds on.

Determinism: every particle's noise comes from (seed, branch id) through the process, and the
survivor draws from a generator seeded by (run seed, selection key: the closed loop passes its campaign
seed and the cell index, so that no two estimates or cells share a stream); the whole estimate replays
exactly.
Cost is counted in simulated control steps (what the process reports), not in episodes.

[CG07] F. Cérou, A. Guyader, Adaptive multilevel splitting for rare event analysis, Stoch. Anal.
Appl. 25 (2007). [BLR16] C.-E. Bréhier, T. Lelièvre, M. Rousset, ..., Unbiasedness of some
generalized adaptive multilevel splitting algorithms, Ann. Appl. Probab. 26 (2016). [GHM11]
A. Guyader, N. Hengartner, E. Matzner-Løber, Simulation and estimation of extreme quantiles and
extreme probabilities, Appl. Math. Optim. 64 (2011).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any, Protocol

import numpy as np
from scipy import stats as sps


class Path(Protocol):
    """One episode, possibly a branch of another: ``scores[t]`` the running score after control step t
    from step 0 (a branch carries its parent's scores up to the branch step), ``steps`` the control
    steps *this* simulation cost, and ``snapshot(t)`` the full episode state right after step t, for
    any step t at which the running score rose (the only steps a level can first be exceeded at)."""

    scores: np.ndarray
    steps: int

    def snapshot(self, step: int) -> Any: ...


class BranchingProcess(Protocol):
    """An episode function that can start fresh or continue from a snapshot with fresh noise.

    ``run(None, branch_id, stop_level)``: a fresh episode whose noise is keyed by ``branch_id``;
    ``run(snapshot, branch_id, stop_level)``: continue after the snapshot's step with noise keyed by
    ``branch_id``. Either may stop early once the score reaches ``stop_level`` (the failure set is
    absorbing for the estimate)."""

    def run(self, start: Any, branch_id: int, stop_level: float) -> Path: ...


def first_step_above(path: Path, level: float) -> int:
    """The first control step after which ``path``'s running score exceeds ``level``."""
    above = np.flatnonzero(np.asarray(path.scores) > level)
    if not above.size:
        raise ValueError(f"the score never exceeded {level}")
    return int(above[0])


@dataclass(frozen=True)
class AMSRun:
    """One AMS run: estimate, iterations, the levels reached, particles, cost in control steps."""

    estimate: float
    iterations: int
    levels: list[float]
    n: int
    k: int
    steps: int
    extinct: bool
    reached: int  # particles at the failure level at the end
    killed: tuple[int, ...] = ()  # particles killed at each iteration (> k with ties)
    capped: bool = False  # stopped by max_iterations before the level reached the failure set: estimate NaN
    #: the particles at the failure level at the end, as their process describes them for a replay
    #: (``path.replay_record()``; empty for a process whose paths have none)
    failing: tuple[dict[str, Any], ...] = ()


def ams(process: BranchingProcess, *, n: int, k: int = 1, failure_level: float, seed: int,
        max_iterations: int = 100_000, selection_key: int | tuple[int, ...] | None = None) -> AMSRun:
    """One generalised AMS run (see the module docstring) with ``n`` particles, ``k`` killed per
    iteration at least; particle and branch ids are drawn from (seed, counter), the survivors to
    branch from a generator keyed by (seed, ``selection_key``). A process whose noise has a key of
    its own (the closed loop's campaign seed) passes it as ``selection_key``: runs with the same
    ``seed`` and distinct process keys then share no random stream (with one shared stream the
    choice among survivors in slot order would tie the runs together, weakly). A tuple key (the
    campaign seed and the cell index) separates the cells of one campaign as well."""
    if not 1 <= k < n:
        raise ValueError(f"need 1 <= k < n, got k={k}, n={n}")
    key = () if selection_key is None else (selection_key,) if isinstance(selection_key, int) else selection_key
    rng = np.random.default_rng([seed, 0x5A5, *key])
    next_id = 0

    def fresh_id() -> int:
        nonlocal next_id
        next_id += 1
        return seed * 1_000_003 + next_id  # distinct from other replicates' ids for seeds < 1e6 apart

    particles = [process.run(None, fresh_id(), failure_level) for _ in range(n)]
    steps = sum(p.steps for p in particles)
    log_weight, levels, killed_counts, iterations = 0.0, [], [], 0
    while iterations < max_iterations:
        scores = np.array([float(p.scores[-1]) for p in particles])
        z = float(np.sort(scores)[k - 1])
        if z >= failure_level:
            break
        killed = np.flatnonzero(scores <= z)
        if killed.size == n:
            return AMSRun(0.0, iterations, levels, n, k, steps, True, 0, tuple(killed_counts))
        survivors = np.flatnonzero(scores > z)
        log_weight += math.log1p(-killed.size / n)
        levels.append(z)
        killed_counts.append(int(killed.size))
        for i in killed:
            parent = particles[int(rng.choice(survivors))]
            child = process.run(parent.snapshot(first_step_above(parent, z)), fresh_id(), failure_level)
            steps += child.steps
            particles[int(i)] = child
        iterations += 1
    reached = int(sum(float(p.scores[-1]) >= failure_level for p in particles))
    capped = iterations >= max_iterations and float(np.sort([p.scores[-1] for p in particles])[k - 1]) < failure_level
    # a capped run stopped before its levels reached the failure set: weight * reached / n is not an
    # unbiased estimate (it reads low, often 0), so it gives none
    value = math.nan if capped else math.exp(log_weight) * reached / n
    failing = tuple(p.replay_record() for p in particles
                    if float(p.scores[-1]) >= failure_level and hasattr(p, "replay_record"))
    return AMSRun(value, iterations, levels, n, k, steps, False, reached, tuple(killed_counts), capped, failing)


@dataclass(frozen=True)
class SplittingEstimate:
    """Mean of ``replicates`` independent AMS runs with a Student t interval at ``level`` (asymptotic),
    the relative standard error, and the cost in control steps. Capped runs (``runs``: NaN) are left
    out of the mean and the interval; with fewer than 2 uncapped runs estimate, interval and relative
    half-width are NaN (not estimated), and ``warnings`` says why."""

    estimate: float
    low: float
    high: float
    level: float
    relative_halfwidth: float
    replicates: int
    n: int
    k: int
    steps: int
    runs: list[float] = field(default_factory=list)
    interval: str = "asymptotic: Student t on independent AMS replicates (each unbiased)"
    warnings: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def contains(self, p: float) -> bool:
        return bool(self.low <= p <= self.high)


def estimate(process: BranchingProcess, *, n: int, k: int = 1, failure_level: float, replicates: int = 10,
             level: float = 0.95, seed: int = 0, max_iterations: int = 100_000) -> SplittingEstimate:
    """``replicates`` independent AMS runs (seeds ``seed * replicates + r``) and their t interval.

    Independent estimates need seeds whose ranges [seed * replicates, (seed + 1) * replicates) do not
    overlap: calls with different ``replicates`` can share runs (seed 1 with 4 replicates runs seeds
    4-7, seed 2 with 2 replicates seeds 4-5)."""
    if replicates < 2:
        raise ValueError(f"an interval needs at least 2 replicates, got {replicates}")
    runs = [ams(process, n=n, k=k, failure_level=failure_level, seed=seed * replicates + r,
                max_iterations=max_iterations) for r in range(replicates)]
    return from_runs(runs, level)


def from_runs(runs: list[AMSRun], level: float = 0.95) -> SplittingEstimate:
    """The t interval of independent AMS runs, with warnings when it should not be trusted; capped runs
    are left out (see :func:`t_interval`)."""
    values = np.array([math.nan if r.capped else r.estimate for r in runs], dtype=float)
    mean, low, high, rel, warnings = t_interval(values, level)
    return SplittingEstimate(mean, low, high, level, rel, int(values.size), runs[0].n,
                             runs[0].k, sum(r.steps for r in runs), [float(v) for v in values], warnings=warnings)


#: Warn when the largest positive run estimate exceeds the smallest by this factor: an AMS run's
#: relative spread is about sqrt(-log p / n) with a good score, so runs orders of magnitude apart
#: mean a score with traps (docs/rare_events.md, "A score that traps").
SPREAD_WARNING = 100.0


def t_interval(values: np.ndarray, level: float = 0.95) -> tuple[float, float, float, float, list[str]]:
    """(mean, low, high, relative half-width, warnings) of independent AMS runs' estimates ``values``:
    the Student t interval, its low end clipped at 0. A NaN value is a run that gave no estimate (capped
    by the iteration limit before the failure level): it is left out of the mean and the interval, with
    a warning; with fewer than 2 estimates left, all four numbers are NaN (not estimated)."""
    values = np.asarray(values, dtype=float)
    capped = int(np.sum(np.isnan(values)))
    total = int(values.size)
    values = values[~np.isnan(values)]
    warnings = []
    if values.size < 2:
        why = (f"{capped} of {total} runs hit the iteration cap before the failure level (a capped run is not an "
               "estimate) and " if capped else "")
        warnings.append(f"not estimated: {why}{values.size} run(s) finished, an interval needs at least 2"
                        + ("; raise --max-iterations" if capped else ""))
        return math.nan, math.nan, math.nan, math.nan, warnings
    if capped:
        warnings.append(f"{capped} of {total} runs hit the iteration cap before the failure level and are left out "
                        "of the mean and the interval (a capped run is not an estimate, and leaving out the runs "
                        "that needed the most levels can bias the mean): raise --max-iterations")
    mean = float(values.mean())
    se = float(values.std(ddof=1) / math.sqrt(values.size))
    half = float(sps.t.ppf(0.5 + level / 2, values.size - 1)) * se
    rel = half / mean if mean > 0 else math.inf
    zero = int(np.sum(values == 0))
    if zero > values.size // 2:
        runs = f"{values.size} uncapped runs" if capped else f"{values.size} runs"
        warnings.append(f"{zero} of {runs} estimate 0 (extinct: every particle killed at one level): "
                        "the t interval is unreliable; use more particles")
    if mean > 0 and np.all(values == values[0]):
        # with few particles an AMS run's estimate takes few values ((1 - K/n)^levels * reached / n), so
        # runs can agree exactly: a zero-width interval then says nothing about the estimate's spread
        warnings.append(f"all {values.size} runs gave the same estimate {values[0]:.3g}: the t interval has width "
                        "0 and means nothing; add runs or particles")
    positive = values[values > 0]
    if positive.size >= 2 and positive.max() > SPREAD_WARNING * positive.min():
        warnings.append(f"the runs' estimates span {positive.max() / positive.min():.0f}x "
                        f"({positive.min():.2g} to {positive.max():.2g}): their distribution is heavy-tailed (a score "
                        "that traps runs, or ties; docs/rare_events.md), so the mean of few runs may read low "
                        "and the t interval miss; add runs or particles")
    return mean, max(0.0, mean - half), mean + half, rel, warnings
