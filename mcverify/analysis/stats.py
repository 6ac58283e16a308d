"""Statistics of Monte-Carlo campaigns: rates with confidence intervals and comparisons of cells.

Every function is pure and deterministic (the bootstrap takes an explicit seed). Intervals for a
binomial proportion k/n:

- ``"clopper-pearson"``: the exact equal-tailed interval from beta quantiles [CP34]; its coverage
  is at least the nominal level for every p and n (it is conservative).
- ``"wilson"``: the score interval [Wil27]; its coverage oscillates around the nominal level and
  dips below it for some (n, p), most markedly when n p is small [BCD01].

Exact one-sided bounds (:func:`one_sided_upper`, :func:`one_sided_lower`) are what a cell with no
event (or only events) reports: 0 collisions in 30 episodes bounds the collision rate by 0.095 at
95 %, and 30/30 safe bounds the safe rate below by 0.905.

Comparisons of two cells: Newcombe's hybrid score interval for p1 - p2 (method 10 of [New98a])
with Fisher's or Boschloo's exact test for independent cells, and for paired episodes (the same
seeds run under two configurations) Newcombe's method 10 for paired data [New98b] with the exact
McNemar test; differences of means (e.g. of minimum distances) by a paired or unpaired
percentile bootstrap (:func:`bootstrap_mean_difference`).

References:
    [CP34] Clopper, C. J. & Pearson, E. S. (1934). The use of confidence or fiducial limits
        illustrated in the case of the binomial. Biometrika 26(4), 404-413.
    [Wil27] Wilson, E. B. (1927). Probable inference, the law of succession, and statistical
        inference. JASA 22(158), 209-212.
    [BCD01] Brown, L. D., Cai, T. T. & DasGupta, A. (2001). Interval estimation for a binomial
        proportion. Statistical Science 16(2), 101-133.
    [HL83] Hanley, J. A. & Lippman-Hand, A. (1983). If nothing goes wrong, is everything all
        right? JAMA 249(13), 1743-1745 (the "rule of three").
    [New98a] Newcombe, R. G. (1998). Interval estimation for the difference between independent
        proportions: comparison of eleven methods. Statistics in Medicine 17, 873-890.
    [New98b] Newcombe, R. G. (1998). Improved confidence intervals for the difference between
        binomial proportions based on paired data. Statistics in Medicine 17, 2635-2650.
    [McN47] McNemar, Q. (1947). Note on the sampling error of the difference between correlated
        proportions or percentages. Psychometrika 12(2), 153-157.
    [ET93] Efron, B. & Tibshirani, R. J. (1993). An Introduction to the Bootstrap, ch. 13
        (percentile intervals). Chapman & Hall.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from numbers import Integral, Real
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import special as sc
from scipy import stats as sps

#: Interval methods for one proportion that :func:`proportion_interval` knows.
PROPORTION_METHODS: tuple[str, ...] = ("clopper-pearson", "wilson")
#: Exact tests for two independent proportions that :func:`compare_unpaired` knows.
UNPAIRED_TESTS: tuple[str, ...] = ("fisher", "boschloo")

#: Largest number of values one bootstrap chunk draws (bounds memory for large samples).
_BOOTSTRAP_CHUNK_VALUES = 2_000_000


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


def bootstrap_mean_interval(
    values: npt.ArrayLike, level: float = 0.95, n_resamples: int = 2000, seed: int = 0
) -> Interval:
    """Percentile-bootstrap confidence interval for the mean of ``values`` [ET93].

    Non-finite values (NaN, +-inf) are dropped first. Draws ``n_resamples`` resamples with
    replacement from ``np.random.default_rng(seed)`` and returns the alpha/2 and 1 - alpha/2
    quantiles of their means; deterministic given (values, level, n_resamples, seed). Fewer than
    2 finite values give Interval(nan, nan).
    """
    level = _check_level(level)
    if isinstance(n_resamples, bool) or not isinstance(n_resamples, Integral) or n_resamples < 1:
        raise ValueError(f"n_resamples must be an integer >= 1, got {n_resamples!r}")
    if isinstance(seed, bool) or not isinstance(seed, Integral):
        raise ValueError(f"seed must be an integer, got {seed!r}")
    x = np.asarray(values, dtype=np.float64).ravel()
    x = x[np.isfinite(x)]
    method = "percentile-bootstrap"
    if x.size < 2:
        return Interval(math.nan, math.nan, level, method)
    means = _resample_means(x, n_resamples, np.random.default_rng(seed))
    low, high = np.quantile(means, [(1.0 - level) / 2.0, (1.0 + level) / 2.0])
    return Interval(float(low), float(high), level, method)


def bootstrap_mean_difference(
    values_a: npt.ArrayLike,
    values_b: npt.ArrayLike,
    *,
    paired: bool,
    level: float = 0.95,
    n_resamples: int = 2000,
    seed: int = 0,
) -> dict[str, Any]:
    """Difference of means mean(a) - mean(b) with a percentile-bootstrap interval [ET93].

    ``paired=True``: a[i] and b[i] belong to the same episode (equal lengths required); pairs with
    a non-finite member are dropped and the interval is that of the mean of d = a - b
    (:func:`bootstrap_mean_interval`). ``paired=False``: non-finite values are dropped from each
    sample separately and the two samples are resampled independently from one generator seeded
    with ``seed``. Returns a JSON-friendly dict: ``n_a``, ``n_b`` (finite values used; equal when
    paired), ``mean_a``, ``mean_b``, ``diff``, ``low``, ``high``, ``level``, ``method``
    ("paired-percentile-bootstrap" or "percentile-bootstrap") and ``paired``. With fewer than 2
    usable values on a side, diff/low/high are NaN (the means are NaN only for 0 values).
    """
    level = _check_level(level)
    if isinstance(n_resamples, bool) or not isinstance(n_resamples, Integral) or n_resamples < 1:
        raise ValueError(f"n_resamples must be an integer >= 1, got {n_resamples!r}")
    a = np.asarray(values_a, dtype=np.float64).ravel()
    b = np.asarray(values_b, dtype=np.float64).ravel()
    if paired:
        if a.shape != b.shape:
            raise ValueError(f"paired samples must have equal lengths, got {a.size} and {b.size}")
        keep = np.isfinite(a) & np.isfinite(b)
        a, b = a[keep], b[keep]
        ci = bootstrap_mean_interval(a - b, level=level, n_resamples=n_resamples, seed=seed)
        low, high = ci.low, ci.high
        method = "paired-percentile-bootstrap"
    else:
        a, b = a[np.isfinite(a)], b[np.isfinite(b)]
        method = "percentile-bootstrap"
        low = high = math.nan
        if a.size >= 2 and b.size >= 2:
            rng = np.random.default_rng(seed)
            diffs = _resample_means(a, n_resamples, rng) - _resample_means(b, n_resamples, rng)
            low, high = (float(x) for x in np.quantile(diffs, [(1.0 - level) / 2.0, (1.0 + level) / 2.0]))
    usable = a.size >= 2 and b.size >= 2
    mean_a = float(a.mean()) if a.size else math.nan
    mean_b = float(b.mean()) if b.size else math.nan
    return {
        "n_a": int(a.size),
        "n_b": int(b.size),
        "mean_a": mean_a,
        "mean_b": mean_b,
        "diff": mean_a - mean_b if usable else math.nan,
        "low": float(low),
        "high": float(high),
        "level": level,
        "method": method,
        "paired": bool(paired),
    }


def _resample_means(x: np.ndarray, n_resamples: int, rng: np.random.Generator) -> np.ndarray:
    """Means of ``n_resamples`` resamples of ``x`` with replacement, drawn in memory-bounded chunks."""
    chunk = max(1, _BOOTSTRAP_CHUNK_VALUES // x.size)
    return np.concatenate(
        [
            x[rng.integers(0, x.size, size=(min(chunk, n_resamples - start), x.size))].mean(axis=1)
            for start in range(0, n_resamples, chunk)
        ]
    )


def quantile_key(q: float) -> str:
    """Dict key of quantile q in :func:`quantiles`: ``"q"`` + percent, e.g. 0.05 -> ``"q5"``."""
    return f"q{100.0 * q:g}"


def quantiles(values: npt.ArrayLike, qs: Sequence[float] = (0.0, 0.05, 0.5, 0.95, 1.0)) -> dict[str, float]:
    """Empirical quantiles of ``values`` with NaNs ignored.

    Returns ``{quantile_key(q): value}`` (e.g. ``{"q0": min, "q5": ..., "q50": median, ...}``)
    using linear interpolation between order statistics (numpy's default, Hyndman & Fan type 7);
    every value is NaN when no non-NaN value is given. Raises ValueError unless every q is in
    [0, 1].
    """
    q_arr = np.asarray(qs, dtype=np.float64).ravel()
    if q_arr.size == 0 or not np.all((q_arr >= 0.0) & (q_arr <= 1.0)):
        raise ValueError(f"qs must be a non-empty sequence of numbers in [0, 1], got {qs!r}")
    x = np.asarray(values, dtype=np.float64).ravel()
    x = x[~np.isnan(x)]
    out = np.quantile(x, q_arr) if x.size else np.full(q_arr.shape, np.nan)
    return {quantile_key(float(q)): float(v) for q, v in zip(q_arr, out, strict=True)}


# --------------------------------------------------------------------------------------------
# comparisons of two cells


def _newcombe_unpaired_arrays(
    k1: npt.ArrayLike, n1: npt.ArrayLike, k2: npt.ArrayLike, n2: npt.ArrayLike, level: float
) -> tuple[np.ndarray, np.ndarray]:
    """Newcombe's hybrid score interval (method 10 of [New98a]) for p1 - p2, vectorised.

    With Wilson intervals (l_i, u_i) for p_i and D = p1 - p2:
    low = D - sqrt((p1 - l1)^2 + (u2 - p2)^2), high = D + sqrt((u1 - p1)^2 + (p2 - l2)^2).
    """
    l1, u1 = wilson_arrays(k1, n1, level)
    l2, u2 = wilson_arrays(k2, n2, level)
    p1 = np.asarray(k1, dtype=np.float64) / np.asarray(n1, dtype=np.float64)
    p2 = np.asarray(k2, dtype=np.float64) / np.asarray(n2, dtype=np.float64)
    d = p1 - p2
    return d - np.hypot(p1 - l1, u2 - p2), d + np.hypot(u1 - p1, p2 - l2)


def _newcombe_paired_arrays(
    both: npt.ArrayLike, only_a: npt.ArrayLike, only_b: npt.ArrayLike, neither: npt.ArrayLike, level: float
) -> tuple[np.ndarray, np.ndarray]:
    """Newcombe's score interval for a paired difference (method 10 of [New98b]), vectorised.

    With cell counts e = both, f = only_a, g = only_b, h = neither, n = e+f+g+h,
    p_a = (e+f)/n, p_b = (e+g)/n, D = p_a - p_b = (f-g)/n, Wilson intervals (l, u) for p_a and
    p_b, and the correlation phi = C / sqrt((e+f)(g+h)(e+g)(f+h)) where A = eh - fg and
    C = A - n/2 if A > n/2, 0 if 0 <= A <= n/2, A if A < 0 (phi = 0 when a margin is empty):
    low = D - sqrt(da^2 - 2 phi da eb + eb^2) with da = p_a - l_a, eb = u_b - p_b;
    high = D + sqrt(ea^2 - 2 phi ea db + db^2) with ea = u_a - p_a, db = p_b - l_b.
    """
    e, f, g, h = (np.asarray(x, dtype=np.int64) for x in (both, only_a, only_b, neither))
    n = e + f + g + h
    la, ua = wilson_arrays(e + f, n, level)
    lb, ub = wilson_arrays(e + g, n, level)
    pa, pb = (e + f) / n, (e + g) / n
    a = (e * h - f * g).astype(np.float64)
    c = np.where(a > n / 2.0, a - n / 2.0, np.where(a < 0.0, a, 0.0))
    margins = ((e + f) * (g + h) * (e + g) * (f + h)).astype(np.float64)
    phi = np.where(margins > 0, c / np.sqrt(np.where(margins > 0, margins, 1.0)), 0.0)
    da, eb, ea, db = pa - la, ub - pb, ua - pa, pb - lb
    d = pa - pb
    low = d - np.sqrt(np.maximum(da**2 - 2.0 * phi * da * eb + eb**2, 0.0))
    high = d + np.sqrt(np.maximum(ea**2 - 2.0 * phi * ea * db + db**2, 0.0))
    return low, high


def compare_unpaired(k1: int, n1: int, k2: int, n2: int, level: float = 0.95, test: str = "fisher") -> dict[str, Any]:
    """Compare the rates of two independent cells: k1 of n1 against k2 of n2.

    Returns a JSON-friendly dict: ``k1, n1, k2, n2, p1, p2``, ``diff`` = p1 - p2, ``low``/``high``
    (Newcombe's hybrid score interval, method 10 of [New98a]; see :func:`_newcombe_unpaired_arrays`),
    ``level``, ``method`` = "newcombe-hybrid-score", ``test`` and ``p_value`` of the two-sided
    exact test of p1 = p2 on the 2x2 table [[k1, n1-k1], [k2, n2-k2]]: ``"fisher"``
    (scipy.stats.fisher_exact) or ``"boschloo"`` (scipy.stats.boschloo_exact, unconditional and
    uniformly more powerful than Fisher's; slower for large n).
    """
    k1, n1 = _check_kn(k1, n1, k_name="k1", n_name="n1")
    k2, n2 = _check_kn(k2, n2, k_name="k2", n_name="n2")
    level = _check_level(level)
    if test not in UNPAIRED_TESTS:
        raise ValueError(f"test must be one of {UNPAIRED_TESTS}, got {test!r}")
    low, high = _newcombe_unpaired_arrays(k1, n1, k2, n2, level)
    table = np.array([[k1, n1 - k1], [k2, n2 - k2]])
    if test == "fisher":
        p_value = sps.fisher_exact(table, alternative="two-sided").pvalue
    else:
        p_value = sps.boschloo_exact(table, alternative="two-sided").pvalue
    return {
        "k1": k1,
        "n1": n1,
        "k2": k2,
        "n2": n2,
        "p1": k1 / n1,
        "p2": k2 / n2,
        "diff": k1 / n1 - k2 / n2,
        "low": float(low),
        "high": float(high),
        "level": level,
        "method": "newcombe-hybrid-score",
        "test": test,
        "p_value": float(min(1.0, p_value)),
    }


def _as_outcomes(x: npt.ArrayLike, name: str) -> np.ndarray:
    arr = np.asarray(x)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be one-dimensional, got shape {arr.shape}")
    if arr.size == 0:
        raise ValueError(f"{name} must not be empty")
    if arr.dtype != np.bool_:
        if not (np.issubdtype(arr.dtype, np.number) and np.all((arr == 0) | (arr == 1))):
            raise ValueError(f"{name} must hold booleans (or 0/1), got dtype {arr.dtype}")
        arr = arr.astype(np.bool_)
    return arr


def mcnemar_exact_pvalue(only_a: int, only_b: int) -> float:
    """Two-sided exact McNemar p-value from the discordant counts [McN47].

    Returns the two-sided binomial test of only_a successes in only_a + only_b trials with
    p = 1/2, i.e. min(1, 2 P(X <= min(only_a, only_b))), X ~ Bin(only_a + only_b, 1/2);
    1.0 when there is no discordant pair.
    """
    b, c = _check_count(only_a, "only_a"), _check_count(only_b, "only_b")
    if b + c == 0:
        return 1.0
    return float(sps.binomtest(b, b + c, 0.5, alternative="two-sided").pvalue)


def compare_paired(outcomes_a: npt.ArrayLike, outcomes_b: npt.ArrayLike, level: float = 0.95) -> dict[str, Any]:
    """Compare two configurations run on the same episodes (paired boolean outcomes).

    ``outcomes_a[i]`` and ``outcomes_b[i]`` are the outcomes of episode i under each
    configuration (equal-length 1-D boolean or 0/1 arrays). Returns a JSON-friendly dict:
    ``n``, ``p_a``, ``p_b``, ``diff`` = p_a - p_b, ``low``/``high`` (Newcombe's score interval for
    paired data, method 10 of [New98b]; see :func:`_newcombe_paired_arrays`), ``level``,
    ``method`` = "newcombe-paired-score", the 2x2 cell counts ``both``, ``only_a``, ``only_b``,
    ``neither`` (only_a and only_b are McNemar's discordant counts b and c), ``test`` =
    "mcnemar-exact" and ``p_value`` (:func:`mcnemar_exact_pvalue`).
    """
    a = _as_outcomes(outcomes_a, "outcomes_a")
    b = _as_outcomes(outcomes_b, "outcomes_b")
    if a.shape != b.shape:
        raise ValueError(f"outcomes_a and outcomes_b must have equal lengths, got {a.size} and {b.size}")
    level = _check_level(level)
    both, only_a = int(np.sum(a & b)), int(np.sum(a & ~b))
    only_b, neither = int(np.sum(~a & b)), int(np.sum(~a & ~b))
    n = a.size
    low, high = _newcombe_paired_arrays(both, only_a, only_b, neither, level)
    return {
        "n": n,
        "p_a": (both + only_a) / n,
        "p_b": (both + only_b) / n,
        "diff": (only_a - only_b) / n,
        "low": float(low),
        "high": float(high),
        "level": level,
        "method": "newcombe-paired-score",
        "both": both,
        "only_a": only_a,
        "only_b": only_b,
        "neither": neither,
        "test": "mcnemar-exact",
        "p_value": mcnemar_exact_pvalue(only_a, only_b),
    }
