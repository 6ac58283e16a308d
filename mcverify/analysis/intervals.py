"""Confidence intervals and exact bounds for one binomial proportion (a rate k/n of a campaign cell).

Two-sided intervals:

- ``"clopper-pearson"``: the exact equal-tailed interval from beta quantiles [CP34]; its coverage
  is at least the nominal level for every p and n (it is conservative).
- ``"wilson"``: the score interval [Wil27]; its coverage oscillates around the nominal level and
  dips below it for some (n, p), most markedly when n p is small [BCD01].

Exact one-sided bounds (:func:`one_sided_upper`, :func:`one_sided_lower`) are what a cell with no
event (or only events) reports: 0 collisions in 30 episodes bounds the collision rate by 0.095 at
95 %, and 30/30 safe bounds the safe rate below by 0.905. The argument checks here are shared by
the other statistics modules. References are listed in :mod:`mcverify.analysis.stats`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from numbers import Integral, Real
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import special as sc
from scipy import stats as sps

#: Interval methods for one proportion that :func:`proportion_interval` knows.
PROPORTION_METHODS: tuple[str, ...] = ("clopper-pearson", "wilson")


@dataclass(frozen=True)
class Interval:
    """A confidence interval [low, high] at confidence ``level`` computed by ``method``.

    ``low``/``high`` are NaN when the interval is undefined (e.g. no data).
    """

    low: float
    high: float
    level: float
    method: str

    def contains(self, p: float) -> bool:
        """Whether ``low <= p <= high`` (False when the interval is undefined)."""
        return bool(self.low <= p <= self.high)


# --------------------------------------------------------------------------------------------
# argument checks (raise early, naming the argument)


def _check_level(level: float, name: str = "level") -> float:
    if isinstance(level, bool) or not isinstance(level, Real) or not 0.0 < float(level) < 1.0:
        raise ValueError(f"{name} must be a number in (0, 1), got {level!r}")
    return float(level)


def _check_count(value: Any, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, Integral):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    if value < 0:
        raise ValueError(f"{name} must be >= 0, got {value}")
    return int(value)


def _check_kn(k: Any, n: Any, *, k_name: str = "k", n_name: str = "n", allow_empty: bool = False) -> tuple[int, int]:
    k, n = _check_count(k, k_name), _check_count(n, n_name)
    if n == 0 and not allow_empty:
        raise ValueError(f"{n_name} must be > 0, got {n}")
    if k > n:
        raise ValueError(f"{k_name} must be <= {n_name}, got {k_name}={k} > {n_name}={n}")
    return k, n


def _check_kn_arrays(k: npt.ArrayLike, n: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    k_arr, n_arr = np.asarray(k), np.asarray(n)
    for arr, name in ((k_arr, "k"), (n_arr, "n")):
        if not np.issubdtype(arr.dtype, np.integer):
            raise ValueError(f"{name} must hold integers, got dtype {arr.dtype}")
    if np.any(n_arr <= 0):
        raise ValueError("n must be > 0 everywhere")
    if np.any(k_arr < 0):
        raise ValueError("k must be >= 0 everywhere")
    if np.any(k_arr > n_arr):
        raise ValueError("k must be <= n everywhere")
    k_b, n_b = np.broadcast_arrays(k_arr, n_arr)
    return k_b.astype(np.float64), n_b.astype(np.float64)


def _check_method(method: str) -> str:
    if method not in PROPORTION_METHODS:
        raise ValueError(f"method must be one of {PROPORTION_METHODS}, got {method!r}")
    return method


def _z(level: float) -> float:
    """Two-sided standard-normal quantile z_{1 - (1 - level)/2}."""
    return float(sps.norm.ppf(0.5 + level / 2.0))


# --------------------------------------------------------------------------------------------
# one proportion


def clopper_pearson_arrays(k: npt.ArrayLike, n: npt.ArrayLike, level: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised two-sided Clopper-Pearson interval for k successes out of n (broadcast).

    Returns ``(low, high)`` float arrays: low = Beta(alpha/2; k, n-k+1), high = Beta(1-alpha/2;
    k+1, n-k) with alpha = 1 - level (beta quantiles by ``scipy.special.betaincinv``, the same
    Boost routine as ``scipy.stats.beta.ppf`` without its per-call overhead), and exactly 0 at
    k = 0 and exactly 1 at k = n [CP34].
    Equivalently, P(X >= k | low) = P(X <= k | high) = alpha/2 for X ~ Bin(n, p).
    """
    level = _check_level(level)
    kf, nf = _check_kn_arrays(k, n)
    alpha = 1.0 - level
    # Safe shape parameters where the edge value is used instead (avoids NaN warnings).
    low = np.where(kf == 0, 0.0, sc.betaincinv(np.maximum(kf, 1.0), nf - kf + 1.0, alpha / 2.0))
    high = np.where(kf == nf, 1.0, sc.betaincinv(kf + 1.0, np.maximum(nf - kf, 1.0), 1.0 - alpha / 2.0))
    return low, high


def wilson_arrays(k: npt.ArrayLike, n: npt.ArrayLike, level: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised Wilson score interval for k successes out of n (broadcast).

    Returns ``(low, high)``: (k + z^2/2 -+ z sqrt(k(n-k)/n + z^2/4)) / (n + z^2) with
    z = z_{1-alpha/2} [Wil27], [BCD01 eq. (4)]; exactly 0 at k = 0 and exactly 1 at k = n.
    """
    level = _check_level(level)
    kf, nf = _check_kn_arrays(k, n)
    z2 = _z(level) ** 2
    center = (kf + z2 / 2.0) / (nf + z2)
    half = math.sqrt(z2) / (nf + z2) * np.sqrt(kf * (nf - kf) / nf + z2 / 4.0)
    low = np.where(kf == 0, 0.0, np.clip(center - half, 0.0, 1.0))
    high = np.where(kf == nf, 1.0, np.clip(center + half, 0.0, 1.0))
    return low, high


def proportion_interval(k: int, n: int, level: float = 0.95, method: str = "clopper-pearson") -> Interval:
    """Two-sided confidence interval for a binomial proportion from k successes in n trials.

    Returns an :class:`Interval`; ``method`` is ``"clopper-pearson"`` (exact, conservative
    [CP34]) or ``"wilson"`` (score interval [Wil27]). See :func:`clopper_pearson_arrays` and
    :func:`wilson_arrays` for the formulas. Raises ValueError unless 0 <= k <= n, n > 0 and
    0 < level < 1.
    """
    k, n = _check_kn(k, n)
    level, method = _check_level(level), _check_method(method)
    fn = clopper_pearson_arrays if method == "clopper-pearson" else wilson_arrays
    low, high = fn(k, n, level)
    return Interval(float(low), float(high), level, method)


def zero_event_upper_bound(n: int, level: float = 0.95) -> float:
    """Exact one-sided upper confidence bound on p after 0 events in n trials.

    Returns 1 - (1 - level)^(1/n), the p at which P(0 events) = 1 - level; about 3/n at 95 %
    (the "rule of three" [HL83]). Equal to :func:`one_sided_upper` with k = 0.
    """
    _, n = _check_kn(0, n)
    level = _check_level(level)
    return float(-math.expm1(math.log1p(-level) / n))


def one_sided_upper(k: int, n: int, level: float = 0.95) -> float:
    """Exact one-sided (Clopper-Pearson) upper confidence bound on p after k events in n trials.

    Returns Beta(level; k+1, n-k), the p at which P(X <= k) = 1 - level [CP34]; 1 at k = n and
    :func:`zero_event_upper_bound` at k = 0 (computed in closed form there).
    """
    k, n = _check_kn(k, n)
    level = _check_level(level)
    if k == n:
        return 1.0
    if k == 0:
        return zero_event_upper_bound(n, level)
    return float(sc.betaincinv(k + 1, n - k, level))


def one_sided_lower(k: int, n: int, level: float = 0.95) -> float:
    """Exact one-sided (Clopper-Pearson) lower confidence bound on p after k events in n trials.

    Returns Beta(1 - level; k, n-k+1), the p at which P(X >= k) = 1 - level [CP34]; 0 at k = 0 and
    (1 - level)^(1/n) at k = n (closed form). It is the bound to quote for a rate such as the safe
    rate when every episode was safe: 30/30 safe gives p >= 0.905 at 95 %, i.e. the unsafe rate is
    at most :func:`zero_event_upper_bound` (30) = 0.095.
    """
    k, n = _check_kn(k, n)
    level = _check_level(level)
    if k == 0:
        return 0.0
    if k == n:
        return 1.0 - zero_event_upper_bound(n, level)
    return float(sc.betaincinv(k, n - k + 1, 1.0 - level))


def interval_arrays(
    k: npt.ArrayLike, n: npt.ArrayLike, level: float = 0.95, method: str = "clopper-pearson"
) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised two-sided interval by name: :func:`clopper_pearson_arrays` or :func:`wilson_arrays`."""
    fn = clopper_pearson_arrays if _check_method(method) == "clopper-pearson" else wilson_arrays
    return fn(k, n, level)


def rate_summary(k: int, n: int, level: float = 0.95, method: str = "clopper-pearson") -> dict[str, Any]:
    """JSON-friendly summary of a rate: k events in n episodes.

    Returns a dict with ``k``, ``n`` (ints), ``rate`` = k/n, ``low``/``high`` (two-sided interval
    of :func:`proportion_interval` with ``method``), ``level``, ``method``, ``upper_one_sided``
    (exact one-sided upper bound of :func:`one_sided_upper`; for k = 0 it equals
    :func:`zero_event_upper_bound`) and ``lower_one_sided`` (exact one-sided lower bound of
    :func:`one_sided_lower`; for k = n it is 1 - zero_event_upper_bound). The one-sided bounds are
    always exact (Clopper-Pearson), whatever ``method`` the two-sided interval uses. All numbers
    but k and n are Python floats.

    An empty cell (n = 0, which requires k = 0) does not raise: rate, low, high and the one-sided
    bounds are NaN.
    """
    k, n = _check_kn(k, n, allow_empty=True)
    level, method = _check_level(level), _check_method(method)
    if n == 0:
        rate = low = high = upper = lower = math.nan
    else:
        ci = proportion_interval(k, n, level, method)
        rate, low, high = k / n, ci.low, ci.high
        upper, lower = one_sided_upper(k, n, level), one_sided_lower(k, n, level)
    return {
        "k": k,
        "n": n,
        "rate": float(rate),
        "low": float(low),
        "high": float(high),
        "level": level,
        "method": method,
        "upper_one_sided": float(upper),
        "lower_one_sided": float(lower),
    }


# --------------------------------------------------------------------------------------------
# continuous values


def crude_steps_for(p: float, relative_halfwidth: float, steps_per_episode: float, level: float = 0.95) -> float:
    """Control steps crude Monte Carlo needs for the relative half-width ``relative_halfwidth`` at rate ``p``
    (normal approximation: z^2 (1 - p) / (p r^2) episodes of ``steps_per_episode`` steps); NaN where p or
    the width is not positive. The yardstick of every rare-event estimator's cost."""
    if not (p > 0 and relative_halfwidth > 0):
        return math.nan
    z = _z(level)
    return z * z * (1.0 - p) / (p * relative_halfwidth**2) * steps_per_episode
