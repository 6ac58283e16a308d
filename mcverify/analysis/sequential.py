"""Anytime-valid confidence sequences for a Bernoulli rate, and sequential stopping on their width.

A fixed-n interval (Clopper-Pearson) covers p with probability >= level only at an n chosen before
looking at the data; re-computing it after every episode and stopping when it is narrow enough (or
when it excludes a value) loses that coverage: by the law of the iterated logarithm the running
interval eventually misses p with probability 1. A *confidence sequence* (C_n) covers p at every n
simultaneously, P(for all n: p in C_n) >= level, so it stays valid at any stopping time, data
dependent or not [Rob70], [HRMS21].

The one used here is Robbins' beta-binomial mixture martingale: with a prior Beta(a, b) on the rate,

    M_n(p) = B(a + k_n, b + n - k_n) / B(a, b) / (p^k_n (1 - p)^(n - k_n))

(k_n events in the first n episodes) is a non-negative martingale with M_0 = 1 under the true p, so
by Ville's inequality P(exists n: M_n(p) >= 1/alpha) <= alpha, and C_n = {p : M_n(p) < 1/alpha} is
a (1 - alpha) confidence sequence. log M_n(p) is convex in p with its minimum at k_n/n, so C_n is an
interval whose ends are found by bisection (vectorised over many (k, n) at once). The running
intersection of C_1..C_n is also a confidence sequence (every C_i holds simultaneously on the same
event), and it is what :func:`sequential_estimate` reports.

The prior only changes where the sequence is tight, never its validity; the default Jeffreys
prior Beta(1/2, 1/2) puts more mass near 0 than the uniform one, which suits small rates.

Everything here is a pure function of the outcomes *in the pre-assigned episode order*: a caller
must feed episodes 0, 1, 2, ... of a cell in that order, never in completion order (which would
favour episodes that end early), and any episode after the stopping index is ignored.

[Rob70] H. Robbins, Statistical methods related to the law of the iterated logarithm, Ann. Math.
Statist. 41 (1970). [HRMS21] S. R. Howard, A. Ramdas, J. McAuliffe, J. Sekhon, Time-uniform,
nonparametric, nonasymptotic confidence sequences, Ann. Statist. 49 (2021).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import special as sc

from mcverify.analysis.intervals import _check_level

#: Bisection steps for the interval ends: 2^-60 of [0, 1] is below float resolution near 1.
_BISECTION_STEPS = 60

#: Default mixture prior Beta(a, b) (Jeffreys).
DEFAULT_PRIOR: tuple[float, float] = (0.5, 0.5)


def log_mixture_martingale(k: npt.ArrayLike, n: npt.ArrayLike, p: npt.ArrayLike,
                           prior: tuple[float, float] = DEFAULT_PRIOR) -> np.ndarray:
    """log M_n(p) of the beta-binomial mixture (see the module docstring); broadcasts; p in (0, 1)."""
    a, b = _check_prior(prior)
    k, n, p = (np.asarray(x, dtype=np.float64) for x in (k, n, p))
    with np.errstate(divide="ignore", invalid="ignore"):
        like = np.where(k > 0, k * np.log(p), 0.0) + np.where(n - k > 0, (n - k) * np.log1p(-p), 0.0)
    return sc.betaln(a + k, b + n - k) - sc.betaln(a, b) - like


def confidence_sequence_arrays(
    k: npt.ArrayLike, n: npt.ArrayLike, level: float = 0.95, prior: tuple[float, float] = DEFAULT_PRIOR
) -> tuple[np.ndarray, np.ndarray]:
    """Ends (low, high) of C_n = {p : M_n(p) < 1/alpha} for k events in n episodes (broadcast arrays).

    n = 0 gives [0, 1]; k = 0 gives low = 0 and k = n gives high = 1 exactly.
    """
    level = _check_level(level)
    k_arr, n_arr = np.broadcast_arrays(np.asarray(k, dtype=np.float64), np.asarray(n, dtype=np.float64))
    if np.any(n_arr < 0) or np.any(k_arr < 0) or np.any(k_arr > n_arr):
        raise ValueError("need 0 <= k <= n everywhere")
    threshold = -math.log1p(-level)  # log(1/alpha)
    centre = np.where(n_arr > 0, k_arr / np.maximum(n_arr, 1.0), 0.5)

    def outside(p: np.ndarray) -> np.ndarray:
        return log_mixture_martingale(k_arr, n_arr, p, prior) >= threshold

    low = _bisect(outside, np.zeros_like(centre), centre, inside_high=True)
    high = _bisect(outside, centre, np.ones_like(centre), inside_high=False)
    low = np.where(k_arr == 0, 0.0, low)
    high = np.where(k_arr == n_arr, 1.0, high)
    return low, high


def _bisect(outside, lo: np.ndarray, hi: np.ndarray, *, inside_high: bool) -> np.ndarray:
    """The boundary between outside and inside C_n on [lo, hi], vectorised; the returned end is on
    the outer side of the boundary (a conservative interval)."""
    lo, hi = lo.copy(), hi.copy()
    for _ in range(_BISECTION_STEPS):
        mid = 0.5 * (lo + hi)
        out = outside(np.clip(mid, 1e-300, 1.0 - 1e-16))
        if inside_high:  # [lo: outside ... hi: inside]
            lo, hi = np.where(out, mid, lo), np.where(out, hi, mid)
        else:  # [lo: inside ... hi: outside]
            lo, hi = np.where(out, lo, mid), np.where(out, mid, hi)
    return lo if inside_high else hi


@dataclass(frozen=True)
class StopRule:
    """When to stop: half-width <= ``halfwidth`` (absolute, or relative to the estimate k/n when
    ``relative``), or after ``budget`` episodes. A relative rule cannot stop before the first event."""

    halfwidth: float | None = None
    relative: bool = False
    budget: int | None = None

    def __post_init__(self) -> None:
        if self.halfwidth is not None and not (self.halfwidth > 0 and math.isfinite(self.halfwidth)):
            raise ValueError(f"half-width must be a positive number, got {self.halfwidth}")
        if self.budget is not None and self.budget < 1:
            raise ValueError(f"budget must be >= 1 episode, got {self.budget}")
        if self.halfwidth is None and self.budget is None:
            raise ValueError("a stopping rule needs a half-width or a budget")

    def met(self, k: np.ndarray, n: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
        """Where the half-width criterion holds (elementwise; the budget is applied by the caller)."""
        if self.halfwidth is None:
            return np.zeros(np.shape(n), dtype=bool)
        half = 0.5 * (high - low)
        if not self.relative:
            return half <= self.halfwidth
        est = np.where(n > 0, k / np.maximum(n, 1), 0.0)
        return (k > 0) & (half <= self.halfwidth * est)


@dataclass(frozen=True)
class SequentialResult:
    """A sequential estimate of a rate: ``n`` episodes used (a prefix in episode order), ``k`` events,
    ``estimate`` = k/n, the running-intersection confidence sequence [low, high] at ``level``,
    ``halfwidth`` = (high - low)/2, and ``status``: ``"halfwidth"`` (the rule was met at n),
    ``"budget"`` (n reached the budget first) or ``"running"`` (neither yet: more episodes needed)."""

    n: int
    k: int
    estimate: float
    low: float
    high: float
    halfwidth: float
    level: float
    status: str
    method: str = "beta-binomial mixture confidence sequence (anytime-valid)"

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def running_bounds(outcomes: npt.ArrayLike, level: float = 0.95, prior: tuple[float, float] = DEFAULT_PRIOR
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For a 0/1 sequence in episode order: (k_n, n, low_n, high_n) for n = 1..len, where [low_n,
    high_n] is the running intersection of C_1..C_n."""
    x = np.asarray(outcomes, dtype=bool)
    n = np.arange(1, x.size + 1, dtype=np.int64)
    k = np.cumsum(x, dtype=np.int64)
    low, high = confidence_sequence_arrays(k, n, level, prior)
    return k, n, np.maximum.accumulate(low), np.minimum.accumulate(high)


def sequential_estimate(outcomes: npt.ArrayLike, rule: StopRule, level: float = 0.95,
                        prior: tuple[float, float] = DEFAULT_PRIOR) -> SequentialResult:
    """Walk ``outcomes`` (events as True, in the pre-assigned episode order) and stop at the first
    n where ``rule`` holds or n = budget; returns the estimate at that n (outcomes after it are
    ignored). With neither reached, the result at the last outcome has status ``"running"``."""
    level = _check_level(level)
    x = np.asarray(outcomes, dtype=bool)
    if rule.budget is not None:
        x = x[: rule.budget]
    if x.size == 0:
        return SequentialResult(0, 0, math.nan, 0.0, 1.0, 0.5, level, "running")
    k, n, low, high = running_bounds(x, level, prior)
    hits = np.flatnonzero(rule.met(k, n, low, high))
    if hits.size:
        i, status = int(hits[0]), "halfwidth"
    else:
        i = x.size - 1
        status = "budget" if rule.budget is not None and x.size >= rule.budget else "running"
    return SequentialResult(int(n[i]), int(k[i]), float(k[i] / n[i]), float(low[i]), float(high[i]),
                            float(0.5 * (high[i] - low[i])), level, status)


def _check_prior(prior: tuple[float, float]) -> tuple[float, float]:
    a, b = (float(x) for x in prior)
    if not (a > 0 and b > 0 and math.isfinite(a) and math.isfinite(b)):
        raise ValueError(f"the mixture prior Beta(a, b) needs a, b > 0, got {prior}")
    return a, b


#: ``interval_method`` of a rate summarised by :func:`sequence_rate_summary` (what an estimate folder's
#: ``summary.json`` says beside every rate).
CONFIDENCE_SEQUENCE = "confidence-sequence"


def sequence_rate_summary(outcomes: npt.ArrayLike, level: float = 0.95,
                          prior: tuple[float, float] = DEFAULT_PRIOR) -> dict[str, Any]:
    """A rate over a 0/1 sequence in episode order with the anytime-valid interval, in the keys of
    :func:`mcverify.analysis.intervals.rate_summary`: ``low``/``high`` are the running intersection of
    C_1..C_n at the last outcome, the interval :func:`sequential_estimate` reports for the same
    sequence. The one-sided bounds are the interval's ends: where k = 0 the interval is [0, high], so
    ``high`` bounds p from above at ``level`` on its own (and ``low`` from below where k = n); no exact
    fixed-n bound is mixed in, since the episode count was chosen by looking at the data.
    An empty sequence gives NaN, as ``rate_summary`` of an empty cell does."""
    level = _check_level(level)
    x = np.asarray(outcomes, dtype=bool)
    if x.size == 0:
        rate = low = high = math.nan
        k = 0
    else:
        ks, _, lows, highs = running_bounds(x, level, prior)
        k, rate, low, high = int(ks[-1]), float(ks[-1] / x.size), float(lows[-1]), float(highs[-1])
    return {"k": k, "n": int(x.size), "rate": rate, "low": low, "high": high, "level": level,
            "method": CONFIDENCE_SEQUENCE, "upper_one_sided": high, "lower_one_sided": low}
