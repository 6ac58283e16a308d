"""Continuous per-episode values (e.g. minimum distances): quantiles and percentile-bootstrap
intervals for a mean and for a difference of means, paired or unpaired [ET93].

Deterministic: the bootstrap takes an explicit seed. References are listed in
:mod:`mcverify.analysis.stats`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from numbers import Integral
from typing import Any

import numpy as np
import numpy.typing as npt

from mcverify.analysis.intervals import Interval, _check_level

#: Largest number of values one bootstrap chunk draws (bounds memory for large samples).
_BOOTSTRAP_CHUNK_VALUES = 2_000_000


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
