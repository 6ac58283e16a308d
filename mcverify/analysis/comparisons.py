"""Comparisons of the rates of two cells: differences of proportions with intervals and exact tests.

Independent cells: Newcombe's hybrid score interval for p1 - p2 (method 10 of [New98a]) with
Fisher's or Boschloo's exact test (:func:`compare_unpaired`). Paired episodes (the same seeds run
under two configurations): Newcombe's method 10 for paired data [New98b] with the exact McNemar
test [McN47] (:func:`compare_paired`). References are listed in :mod:`mcverify.analysis.stats`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import stats as sps

from mcverify.analysis.intervals import _check_count, _check_kn, _check_level, wilson_arrays

#: Exact tests for two independent proportions that :func:`compare_unpaired` knows.
UNPAIRED_TESTS: tuple[str, ...] = ("fisher", "boschloo")


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
