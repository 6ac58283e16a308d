"""Comparisons of the rates of two cells: a difference of proportions with an interval and the test it inverts.

One answer per comparison: the interval excludes 0 exactly when its test rejects at the same level.

- Independent cells (:func:`compare_unpaired`): the Miettinen-Nurminen score interval for p1 - p2
  [MN85] and the score test of p1 = p2 that it inverts (the same statistic at d = 0).
- Paired episodes (the same seeds under two configurations; :func:`compare_paired`): the exact
  McNemar test [McN47] and the interval that agrees with it: the Clopper-Pearson interval of the
  share of discordant pairs that favour A, at the test's level, mapped to the difference
  d = psi (2 pi - 1) with the Clopper-Pearson bounds of the discordance rate psi
  (:func:`_paired_conditional_arrays`). References are listed in :mod:`mcverify.analysis.stats`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import optimize as so
from scipy import stats as sps

from mcverify.analysis.intervals import _check_count, _check_kn, _check_level, clopper_pearson_arrays

#: The interval and test of independent cells (one pair; names as stored in comparisons).
UNPAIRED_METHOD = "miettinen-nurminen-score"
UNPAIRED_TEST = "score"
#: The interval and test of paired episodes.
PAIRED_METHOD = "mcnemar-conditional-exact"
PAIRED_TEST = "mcnemar-exact"


def _restricted_mle(k1: int, n1: int, k2: int, n2: int, d: float) -> tuple[float, float]:
    """The maximum-likelihood (p1, p2) under p1 - p2 = d (the cubic of Farrington and Manning [FM90])."""
    p1_hat, p2_hat = k1 / n1, k2 / n2
    theta = n2 / n1
    a = 1.0 + theta
    b = -(1.0 + theta + p1_hat + theta * p2_hat + d * (theta + 2.0))
    c = d * d + d * (2.0 * p1_hat + theta + 1.0) + p1_hat + theta * p2_hat
    e = -p1_hat * d * (1.0 + d)
    v = b**3 / (27.0 * a**3) - b * c / (6.0 * a * a) + e / (2.0 * a)
    u_sq = max(b * b / (9.0 * a * a) - c / (3.0 * a), 0.0)
    u = math.copysign(math.sqrt(u_sq), v) if v != 0.0 else math.sqrt(u_sq)
    ratio = 0.0 if u == 0.0 else max(-1.0, min(1.0, v / u**3))
    w = (math.pi + math.acos(ratio)) / 3.0
    p1 = min(max(2.0 * u * math.cos(w) - b / (3.0 * a), 0.0), 1.0)
    return p1, min(max(p1 - d, 0.0), 1.0)


def _score_z(k1: int, n1: int, k2: int, n2: int, d: float) -> float:
    """The Miettinen-Nurminen statistic of p1 - p2 = d (variance at the restricted MLE, times N/(N-1))."""
    p1, p2 = _restricted_mle(k1, n1, k2, n2, d)
    n = n1 + n2
    var = (p1 * (1.0 - p1) / n1 + p2 * (1.0 - p2) / n2) * (n / (n - 1.0) if n > 1 else 1.0)
    diff = k1 / n1 - k2 / n2 - d
    if var <= 0.0:
        return 0.0 if abs(diff) < 1e-15 else math.copysign(math.inf, diff)
    return diff / math.sqrt(var)


def _score_bound(k1: int, n1: int, k2: int, n2: int, z_crit: float, side: int) -> float:
    """The end of the score interval on ``side`` (-1 low, +1 high): where z(d) = -side * z_crit."""
    estimate = k1 / n1 - k2 / n2
    edge = float(side) * (1.0 - 1e-12)

    def excess(d: float) -> float:
        return _score_z(k1, n1, k2, n2, d) + side * z_crit

    if side * excess(edge) >= 0.0:  # the statistic never reaches the critical value before the edge
        return float(side)
    return float(so.brentq(excess, estimate, edge, xtol=1e-12, rtol=4 * np.finfo(float).eps))


def _paired_conditional_arrays(
    only_a: npt.ArrayLike, only_b: npt.ArrayLike, n: npt.ArrayLike, level: float
) -> tuple[np.ndarray, np.ndarray]:
    """The interval for d = p_a - p_b on paired data that agrees with the exact McNemar test.

    With m = only_a + only_b discordant pairs, psi = P(discordant) and pi = P(A's | discordant),
    d = psi (2 pi - 1). (pi_lo, pi_hi) is the Clopper-Pearson interval of only_a / m and
    (psi_lo, psi_hi) that of m / n, both at ``level``; the ends take the bound of psi that moves
    them outwards: low = (2 pi_lo - 1) psi_hi when pi_lo < 1/2, else (2 pi_lo - 1) psi_lo (and high
    alike). The interval excludes 0 exactly when pi's interval excludes 1/2, which is when the
    two-sided exact McNemar test rejects at 1 - level. Coverage: at least 2 level - 1 by the union
    bound; its exact coverage is checked in tests/analysis/test_stats.py. With m = 0:
    [-psi_hi, psi_hi].
    """
    f, g, total = (np.asarray(x, dtype=np.int64) for x in (only_a, only_b, n))
    m = f + g
    psi_lo, psi_hi = clopper_pearson_arrays(m, total, level)
    pi_lo, pi_hi = clopper_pearson_arrays(f, np.maximum(m, 1), level)
    low = (2.0 * pi_lo - 1.0) * np.where(pi_lo < 0.5, psi_hi, psi_lo)
    high = (2.0 * pi_hi - 1.0) * np.where(pi_hi < 0.5, psi_lo, psi_hi)
    none = m == 0
    return np.where(none, -psi_hi, low), np.where(none, psi_hi, high)


def score_test_pvalue(k1: int, n1: int, k2: int, n2: int) -> float:
    """Two-sided p-value of the score test of p1 = p2 (the Miettinen-Nurminen statistic at d = 0)."""
    z = _score_z(k1, n1, k2, n2, 0.0)
    return float(min(1.0, 2.0 * sps.norm.sf(abs(z))))


def compare_unpaired(k1: int, n1: int, k2: int, n2: int, level: float = 0.95) -> dict[str, Any]:
    """Compare the rates of two independent cells: k1 of n1 against k2 of n2.

    Returns a JSON-friendly dict: ``k1, n1, k2, n2, p1, p2``, ``diff`` = p1 - p2, ``low``/``high``
    (the Miettinen-Nurminen score interval [MN85]), ``level``, ``method`` (:data:`UNPAIRED_METHOD`),
    ``test`` (:data:`UNPAIRED_TEST`) and ``p_value`` of the two-sided score test of p1 = p2 that the
    interval inverts: the interval excludes 0 exactly when ``p_value`` < 1 - ``level``.
    """
    k1, n1 = _check_kn(k1, n1, k_name="k1", n_name="n1")
    k2, n2 = _check_kn(k2, n2, k_name="k2", n_name="n2")
    level = _check_level(level)
    z_crit = float(sps.norm.ppf(0.5 + level / 2.0))
    return {
        "k1": k1,
        "n1": n1,
        "k2": k2,
        "n2": n2,
        "p1": k1 / n1,
        "p2": k2 / n2,
        "diff": k1 / n1 - k2 / n2,
        "low": _score_bound(k1, n1, k2, n2, z_crit, -1),
        "high": _score_bound(k1, n1, k2, n2, z_crit, +1),
        "level": level,
        "method": UNPAIRED_METHOD,
        "test": UNPAIRED_TEST,
        "p_value": score_test_pvalue(k1, n1, k2, n2),
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
    ``n``, ``p_a``, ``p_b``, ``diff`` = p_a - p_b, ``low``/``high`` (the interval that agrees with
    the exact McNemar test, :func:`_paired_conditional_arrays`), ``level``, ``method``
    (:data:`PAIRED_METHOD`), the 2x2 cell counts ``both``, ``only_a``, ``only_b``, ``neither``
    (only_a and only_b are McNemar's discordant counts b and c), ``test`` (:data:`PAIRED_TEST`) and
    ``p_value`` (:func:`mcnemar_exact_pvalue`): the interval excludes 0 exactly when ``p_value`` <
    1 - ``level``.
    """
    a = _as_outcomes(outcomes_a, "outcomes_a")
    b = _as_outcomes(outcomes_b, "outcomes_b")
    if a.shape != b.shape:
        raise ValueError(f"outcomes_a and outcomes_b must have equal lengths, got {a.size} and {b.size}")
    level = _check_level(level)
    both, only_a = int(np.sum(a & b)), int(np.sum(a & ~b))
    only_b, neither = int(np.sum(~a & b)), int(np.sum(~a & ~b))
    n = a.size
    low, high = _paired_conditional_arrays(only_a, only_b, n, level)
    return {
        "n": n,
        "p_a": (both + only_a) / n,
        "p_b": (both + only_b) / n,
        "diff": (only_a - only_b) / n,
        "low": float(low),
        "high": float(high),
        "level": level,
        "method": PAIRED_METHOD,
        "both": both,
        "only_a": only_a,
        "only_b": only_b,
        "neither": neither,
        "test": PAIRED_TEST,
        "p_value": mcnemar_exact_pvalue(only_a, only_b),
    }
