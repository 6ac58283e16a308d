"""mcverify.analysis.stats: coverage on synthetic Bernoulli sources, known values, edge cases, bad arguments."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats as sps

from mcverify.analysis import bootstrap, comparisons, stats
from mcverify.analysis.stats import (
    Interval,
    bootstrap_mean_difference,
    bootstrap_mean_interval,
    clopper_pearson_arrays,
    compare_paired,
    compare_unpaired,
    mcnemar_exact_pvalue,
    one_sided_lower,
    one_sided_upper,
    proportion_interval,
    quantiles,
    rate_summary,
    wilson_arrays,
    zero_event_upper_bound,
)

COVERAGE_PS = (0.001, 0.01, 0.1, 0.5)
# n = 30 is the paper's group size; n = 1000 makes n p = 1 at p = 0.001, where a rare-event
# interval is hardest to get right; n = 3000 (n p = 3 at p = 0.001, 1500 at p = 0.5) is the size of
# a large campaign cell. Each (p, n) is 1,000 synthetic Bernoulli-source repetitions, vectorised.
COVERAGE_NS = (30, 100, 1000, 3000)
REPS = 1000


def _mc_coverage(fn, p: float, n: int, seed: int) -> float:
    k = np.random.default_rng(seed).binomial(n, p, size=REPS)
    low, high = fn(k, n, 0.95)
    return float(np.mean((low <= p) & (p <= high)))


def _exact_coverage(fn, p: float, n: int) -> float:
    """P(interval covers p) summed over the binomial distribution of k (no Monte-Carlo noise)."""
    k = np.arange(n + 1)
    low, high = fn(k, n, 0.95)
    return float(np.sum(sps.binom.pmf(k, n, p) * ((low <= p) & (p <= high))))


# ------------------------------------------------------------------------------------------
# coverage on a synthetic Bernoulli source of known p


@pytest.mark.parametrize("p", COVERAGE_PS)
@pytest.mark.parametrize("n", COVERAGE_NS)
def test_clopper_pearson_monte_carlo_coverage(p, n):
    # Conservative: true coverage >= 95 % for every (n, p); 93 % leaves room for MC noise.
    assert _mc_coverage(clopper_pearson_arrays, p, n, seed=1000 * n + int(1e4 * p)) >= 0.93


@pytest.mark.parametrize("p", COVERAGE_PS)
@pytest.mark.parametrize("n", COVERAGE_NS)
def test_wilson_monte_carlo_coverage(p, n):
    # Wilson dips below nominal when n p is small (Brown, Cai & DasGupta 2001): with these seeds
    # 0.905 (exact 0.9048) at p = 0.001, n = 100 and 0.913-0.914 where n p = 1; where n p >= 5 it
    # stays >= 0.93 (exact >= 0.936). Thresholds leave about 3 Monte-Carlo standard errors.
    threshold = 0.86 if n * p < 5 else 0.91
    assert _mc_coverage(wilson_arrays, p, n, seed=1000 * n + int(1e4 * p)) >= threshold


@pytest.mark.parametrize("n", (1, 2, 5, 30, 100, 1000))
def test_clopper_pearson_exact_coverage_never_below_nominal(n):
    # Exact coverage over a fine p grid (the theorem of Clopper & Pearson 1934).
    for p in np.concatenate([np.geomspace(1e-4, 0.5, 60), np.linspace(0.5, 0.9999, 60)]):
        assert _exact_coverage(clopper_pearson_arrays, float(p), n) >= 0.95 - 1e-9


def test_wilson_exact_coverage_on_grid():
    cov = {(p, n): _exact_coverage(wilson_arrays, p, n) for p in COVERAGE_PS for n in COVERAGE_NS}
    assert min(cov.values()) >= 0.90
    assert cov[(0.001, 100)] == pytest.approx(0.9048, abs=1e-4)  # the documented dip
    assert all(c >= 0.93 for (p, n), c in cov.items() if n * p >= 5)


def test_score_interval_coverage():
    rng = np.random.default_rng(11)
    for p1, p2, n1, n2 in [(0.5, 0.4, 100, 100), (0.9, 0.8, 200, 150), (0.05, 0.02, 300, 300)]:
        k1, k2 = rng.binomial(n1, p1, 400), rng.binomial(n2, p2, 400)
        hits = [(r["low"] <= p1 - p2 <= r["high"]) for r in (compare_unpaired(int(a), n1, int(b), n2)
                                                              for a, b in zip(k1, k2, strict=True))]
        assert np.mean(hits) >= 0.92


def test_paired_interval_coverage():
    rng = np.random.default_rng(12)
    for cells, n in [((0.5, 0.1, 0.05, 0.35), 100), ((0.85, 0.05, 0.02, 0.08), 200), ((0.9, 0.03, 0.01, 0.06), 500)]:
        c = rng.multinomial(n, cells, size=REPS)
        low, high = comparisons._paired_conditional_arrays(c[:, 1], c[:, 2], n, 0.95)
        d = cells[1] - cells[2]
        assert np.mean((low <= d) & (d <= high)) >= 0.94


def _exact_paired_coverage(n: int, p_a_only: float, p_b_only: float) -> float:
    """Coverage of the paired interval by enumerating every (only_a, only_b) of n pairs."""
    f, g = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    ok = f + g <= n
    f, g = f[ok], g[ok]
    log_pmf = sps.multinomial.logpmf(np.stack([f, g, n - f - g], axis=1), n, [p_a_only, p_b_only,
                                                                             1.0 - p_a_only - p_b_only])
    low, high = comparisons._paired_conditional_arrays(f, g, n, 0.95)
    d = p_a_only - p_b_only
    return float(np.sum(np.exp(log_pmf)[(low <= d) & (d <= high)]))


@pytest.mark.parametrize("n", [5, 10, 30])
def test_paired_interval_exact_coverage_on_small_samples(n):
    """Its guarantee is 2 level - 1 (union bound); on this grid it keeps the nominal 95 %."""
    grid = np.linspace(0.0, 0.6, 7)
    worst = min(_exact_paired_coverage(n, a, b) for a in grid for b in grid if a + b <= 1.0)
    assert worst >= 0.95


# ------------------------------------------------------------------------------------------
# one proportion: known values and properties


KN_GRID = [(0, 1), (1, 1), (0, 30), (1, 30), (3, 30), (15, 30), (29, 30), (30, 30), (7, 1000), (500, 1000)]


@pytest.mark.parametrize("k, n", KN_GRID)
@pytest.mark.parametrize("level", (0.9, 0.95, 0.99))
def test_intervals_match_scipy_binomtest(k, n, level):
    for method, scipy_method in (("clopper-pearson", "exact"), ("wilson", "wilson")):
        ours = proportion_interval(k, n, level, method)
        ref = sps.binomtest(k, n).proportion_ci(confidence_level=level, method=scipy_method)
        assert ours.low == pytest.approx(ref.low, abs=1e-12, rel=1e-9)
        assert ours.high == pytest.approx(ref.high, abs=1e-12, rel=1e-9)
        assert (ours.level, ours.method) == (level, method)


@pytest.mark.parametrize("k, n", [(k, n) for k, n in KN_GRID if 0 < k < n])
def test_clopper_pearson_tails_equal_alpha_over_two(k, n):
    ci = proportion_interval(k, n)
    assert sps.binom.sf(k - 1, n, ci.low) == pytest.approx(0.025, rel=1e-8)  # P(X >= k | low)
    assert sps.binom.cdf(k, n, ci.high) == pytest.approx(0.025, rel=1e-8)  # P(X <= k | high)


@pytest.mark.parametrize("method", ("clopper-pearson", "wilson"))
@pytest.mark.parametrize("n", (1, 30, 1000))
def test_edges_are_exact(method, n):
    assert proportion_interval(0, n, method=method).low == 0.0
    assert proportion_interval(n, n, method=method).high == 1.0


@settings(max_examples=150, deadline=None)
@given(st.integers(1, 5000).flatmap(lambda n: st.tuples(st.integers(0, n), st.just(n))))
def test_interval_properties(kn):
    k, n = kn
    cp, w = proportion_interval(k, n), proportion_interval(k, n, method="wilson")
    for ci in (cp, w):
        assert 0.0 <= ci.low <= k / n <= ci.high <= 1.0
        assert ci.contains(k / n)
    upper = one_sided_upper(k, n)
    assert k / n <= upper <= cp.high  # one-sided 95 % bound uses the 0.95 quantile, two-sided 0.975
    assert proportion_interval(k, n, level=0.99).high >= cp.high  # wider at higher level


def test_zero_event_upper_bound_values():
    assert zero_event_upper_bound(30) == pytest.approx(0.09503, abs=1e-5)
    assert zero_event_upper_bound(30) == pytest.approx(1 - 0.05 ** (1 / 30), rel=1e-12)
    assert zero_event_upper_bound(1) == pytest.approx(0.95)
    assert zero_event_upper_bound(3000) == pytest.approx(3 / 3000, rel=2e-3)  # rule of three
    assert zero_event_upper_bound(100, level=0.99) == pytest.approx(1 - 0.01 ** (1 / 100), rel=1e-12)
    # P(0 events | p = bound) = 1 - level
    assert sps.binom.pmf(0, 30, zero_event_upper_bound(30)) == pytest.approx(0.05, rel=1e-10)


@pytest.mark.parametrize("k, n", [(0, 30), (1, 30), (5, 100), (99, 100), (100, 100)])
def test_one_sided_upper(k, n):
    ub = one_sided_upper(k, n)
    if k == n:
        assert ub == 1.0
    else:
        assert sps.binom.cdf(k, n, ub) == pytest.approx(0.05, rel=1e-8)
        assert ub == pytest.approx(sps.binomtest(k, n, alternative="less").proportion_ci(0.95).high, rel=1e-9)
    if k == 0:
        assert ub == zero_event_upper_bound(n)


@pytest.mark.parametrize("n", (1, 30, 1000))
@pytest.mark.parametrize("method", ("clopper-pearson", "wilson"))
def test_rate_summary_zero_failures(n, method):
    r = rate_summary(0, n, method=method)
    assert set(r) == {"k", "n", "rate", "low", "high", "level", "method", "upper_one_sided", "lower_one_sided"}
    assert (r["k"], r["n"], r["rate"], r["low"], r["method"]) == (0, n, 0.0, 0.0, method)
    assert r["upper_one_sided"] == pytest.approx(1 - 0.05 ** (1 / n), rel=1e-12)
    assert r["upper_one_sided"] == zero_event_upper_bound(n)
    if n == 30:
        assert r["upper_one_sided"] == pytest.approx(0.0950, abs=1e-4)
    assert all(type(r[key]) is float for key in ("rate", "low", "high", "level", "upper_one_sided"))


def test_rate_summary_general_and_empty():
    r = rate_summary(3, 30, level=0.9)
    ci = proportion_interval(3, 30, 0.9)
    assert (r["rate"], r["low"], r["high"], r["level"]) == (0.1, ci.low, ci.high, 0.9)
    assert r["upper_one_sided"] == one_sided_upper(3, 30, 0.9)
    empty = rate_summary(0, 0)
    assert (empty["k"], empty["n"]) == (0, 0)
    assert all(math.isnan(empty[key]) for key in ("rate", "low", "high", "upper_one_sided"))


def test_interval_contains():
    ci = Interval(0.1, 0.3, 0.95, "wilson")
    assert ci.contains(0.1) and ci.contains(0.3) and ci.contains(0.2)
    assert not ci.contains(0.05) and not ci.contains(0.31)
    assert not Interval(math.nan, math.nan, 0.95, "x").contains(0.5)


# ------------------------------------------------------------------------------------------
# continuous values


def test_bootstrap_deterministic_and_contains_mean():
    x = np.random.default_rng(3).normal(5.0, 2.0, size=200)
    a, b = bootstrap_mean_interval(x, seed=7), bootstrap_mean_interval(x, seed=7)
    assert a == b
    assert a.contains(float(x.mean()))
    assert bootstrap_mean_interval(x, seed=8) != a
    # Close to the t interval for a normal sample.
    half = sps.t.ppf(0.975, x.size - 1) * x.std(ddof=1) / math.sqrt(x.size)
    assert a.low == pytest.approx(x.mean() - half, abs=0.1)
    assert a.high == pytest.approx(x.mean() + half, abs=0.1)
    assert bootstrap_mean_interval(x, level=0.99, seed=7).high > a.high


def test_bootstrap_chunking_is_invisible(monkeypatch):
    x = np.random.default_rng(4).exponential(size=50)
    whole = bootstrap_mean_interval(x, n_resamples=500, seed=1)
    monkeypatch.setattr(bootstrap, "_BOOTSTRAP_CHUNK_VALUES", 50 * 7)  # 7 resamples a chunk
    assert bootstrap_mean_interval(x, n_resamples=500, seed=1) == whole


def test_bootstrap_drops_nans_and_handles_tiny_samples():
    x = np.random.default_rng(5).normal(size=100)
    with_nans = np.concatenate([x[:50], [np.nan, np.inf], x[50:]])
    assert bootstrap_mean_interval(with_nans) == bootstrap_mean_interval(x)
    for tiny in ([], [1.0], [np.nan, 2.0]):
        ci = bootstrap_mean_interval(np.asarray(tiny))
        assert math.isnan(ci.low) and math.isnan(ci.high)
    assert bootstrap_mean_interval(np.array([2.0, 2.0, 2.0])) == Interval(2.0, 2.0, 0.95, "percentile-bootstrap")


def test_quantiles():
    q = quantiles(np.array([4.0, np.nan, 1.0, 3.0, 2.0, 5.0]))
    assert list(q) == ["q0", "q5", "q50", "q95", "q100"]
    assert (q["q0"], q["q50"], q["q100"]) == (1.0, 3.0, 5.0)
    assert q["q5"] == pytest.approx(1.2) and q["q95"] == pytest.approx(4.8)
    assert quantiles([1.0, 2.0], qs=(0.025,)) == {"q2.5": pytest.approx(1.025)}
    assert all(math.isnan(v) for v in quantiles(np.array([np.nan])).values())
    assert all(type(v) is float for v in q.values())


# ------------------------------------------------------------------------------------------
# comparisons


# Newcombe (1998a), Table II, method 6 (Miettinen-Nurminen): (k1, n1, k2, n2) -> (low, high)
SCORE_UNPAIRED = [
    ((56, 70, 48, 80), (0.0528, 0.3382)),
    ((9, 10, 3, 10), (0.1700, 0.8406)),
    ((6, 7, 2, 7), (0.0342, 0.8534)),
    ((5, 56, 0, 29), (-0.0326, 0.1933)),
]


@pytest.mark.parametrize("counts, expected", SCORE_UNPAIRED)
def test_score_interval_worked_examples(counts, expected):
    r = compare_unpaired(*counts)
    assert r["diff"] == pytest.approx(counts[0] / counts[1] - counts[2] / counts[3])
    assert (r["low"], r["high"]) == (pytest.approx(expected[0], abs=5e-5), pytest.approx(expected[1], abs=5e-5))


def test_score_test_is_pearsons_chi_square_times_n_minus_1_over_n():
    for k1, n1, k2, n2 in [(12, 100, 3, 100), (3, 4, 1, 4), (56, 70, 48, 80), (0, 9, 4, 11)]:
        chi2 = sps.chi2_contingency([[k1, n1 - k1], [k2, n2 - k2]], correction=False)[0]
        n = n1 + n2
        r = compare_unpaired(k1, n1, k2, n2)
        assert r["test"] == "score" and r["method"] == "miettinen-nurminen-score"
        assert r["p_value"] == pytest.approx(sps.chi2.sf(chi2 * (n - 1) / n, 1), rel=1e-9)
    same = compare_unpaired(5, 50, 5, 50)
    assert same["p_value"] == 1.0 and same["low"] < 0 < same["high"]


def test_score_interval_ends_are_where_the_statistic_meets_the_critical_value():
    z = sps.norm.ppf(0.975)
    r = compare_unpaired(9, 10, 3, 10)
    assert comparisons._score_z(9, 10, 3, 10, r["low"]) == pytest.approx(z, abs=1e-7)
    assert comparisons._score_z(9, 10, 3, 10, r["high"]) == pytest.approx(-z, abs=1e-7)


def test_unpaired_interval_excludes_zero_exactly_when_its_test_rejects():
    for n1, n2 in [(1, 1), (2, 2), (3, 5), (8, 8), (12, 7), (15, 15)]:
        for k1 in range(n1 + 1):
            for k2 in range(n2 + 1):
                r = compare_unpaired(k1, n1, k2, n2)
                assert (r["p_value"] < 0.05) == (r["low"] > 0 or r["high"] < 0), (k1, n1, k2, n2)


def test_paired_interval_excludes_zero_exactly_when_mcnemar_rejects():
    for n in range(1, 26):
        f, g = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        ok = f + g <= n
        for level in (0.9, 0.95, 0.99):
            low, high = comparisons._paired_conditional_arrays(f[ok], g[ok], n, level)
            p = np.array([mcnemar_exact_pvalue(int(a), int(b)) for a, b in zip(f[ok], g[ok], strict=True)])
            assert np.array_equal(p < 1 - level, (low > 0) | (high < 0)), n


def test_two_discordant_pairs_are_no_evidence():
    """The case a user met: +1.000 [+0.070, +1.000] beside McNemar's p = 0.5; now one answer."""
    r = compare_paired(np.array([True, True]), np.array([False, False]))
    assert r["diff"] == 1.0 and r["p_value"] == 0.5 and r["low"] < 0 < r["high"]


# (both, only_a, only_b, neither) -> (low, high), by hand: psi = m/n and pi = only_a/m with their
# Clopper-Pearson bounds (scipy's beta quantiles), low = (2 pi_lo - 1) psi_lo, high = (2 pi_hi - 1) psi_hi.
PAIRED = [(36, 12, 2, 0), (18, 12, 2, 18), (0, 30, 0, 0)]


def _paired_arrays(both: int, only_a: int, only_b: int, neither: int, seed: int = 0):
    a = np.array([True] * both + [True] * only_a + [False] * only_b + [False] * neither)
    b = np.array([True] * both + [False] * only_a + [True] * only_b + [False] * neither)
    perm = np.random.default_rng(seed).permutation(a.size)  # the order of episodes is irrelevant
    return a[perm], b[perm]


@pytest.mark.parametrize("cells", PAIRED)
def test_paired_interval_worked_examples(cells):
    r = compare_paired(*_paired_arrays(*cells))
    assert (r["both"], r["only_a"], r["only_b"], r["neither"]) == cells
    assert r["diff"] == pytest.approx((cells[1] - cells[2]) / sum(cells))
    n, f, g = sum(cells), cells[1], cells[2]
    m = f + g
    psi_lo, psi_hi = sps.beta.ppf(0.025, m, n - m + 1), (1.0 if m == n else sps.beta.ppf(0.975, m + 1, n - m))
    pi_lo, pi_hi = sps.beta.ppf(0.025, f, m - f + 1), (1.0 if f == m else sps.beta.ppf(0.975, f + 1, m - f))
    assert pi_lo > 0.5 and pi_hi > 0.5  # A's side in all three
    assert r["low"] == pytest.approx((2 * pi_lo - 1) * psi_lo, rel=1e-9)
    assert r["high"] == pytest.approx((2 * pi_hi - 1) * psi_hi, rel=1e-9)
    assert r["method"] == "mcnemar-conditional-exact"


def test_paired_interval_is_narrower_than_unpaired_with_positive_correlation():
    a, b = _paired_arrays(40, 6, 1, 53)
    paired = compare_paired(a, b)
    unpaired = compare_unpaired(int(a.sum()), a.size, int(b.sum()), b.size)
    assert paired["diff"] == pytest.approx(unpaired["diff"])
    assert paired["high"] - paired["low"] < unpaired["high"] - unpaired["low"]


@pytest.mark.parametrize("b, c", [(0, 0), (0, 5), (1, 9), (7, 3), (12, 12), (20, 41)])
def test_mcnemar_exact_against_hand_computed_binomial(b, c):
    m = b + c
    hand = 1.0 if m == 0 else min(1.0, 2 * sum(math.comb(m, i) for i in range(min(b, c) + 1)) / 2**m)
    assert mcnemar_exact_pvalue(b, c) == pytest.approx(hand, rel=1e-12)
    a_out, b_out = _paired_arrays(10, b, c, 15)
    r = compare_paired(a_out, b_out)
    assert r["test"] == "mcnemar-exact" and r["p_value"] == pytest.approx(hand, rel=1e-12)
    assert (r["only_a"], r["only_b"], r["n"]) == (b, c, 25 + m)


def test_mcnemar_hand_values():
    assert mcnemar_exact_pvalue(1, 9) == pytest.approx(22 / 1024)  # 2 * (1 + 10) / 2**10
    assert mcnemar_exact_pvalue(0, 5) == pytest.approx(1 / 16)


def test_compare_paired_accepts_01_integers():
    r = compare_paired(np.array([1, 1, 0, 0, 1]), np.array([1, 0, 1, 0, 0]))
    assert (r["both"], r["only_a"], r["only_b"], r["neither"]) == (1, 2, 1, 1)
    assert r["p_a"] == 0.6 and r["p_b"] == 0.4


# ------------------------------------------------------------------------------------------
# bad arguments


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: proportion_interval(5, 3), "k must be <= n"),
        (lambda: proportion_interval(0, 0), "n must be > 0"),
        (lambda: proportion_interval(-1, 3), "k must be >= 0"),
        (lambda: proportion_interval(1, -3), "n must be >= 0"),
        (lambda: proportion_interval(1.5, 3), "k must be an integer"),
        (lambda: proportion_interval(1, 3, level=1.0), "level must be"),
        (lambda: proportion_interval(1, 3, level=0.0), "level must be"),
        (lambda: proportion_interval(1, 3, level=95), "level must be"),
        (lambda: proportion_interval(1, 3, method="wald"), "method must be one of"),
        (lambda: clopper_pearson_arrays(np.array([1, 4]), 3), "k must be <= n"),
        (lambda: wilson_arrays(np.array([1.0]), 3), "k must hold integers"),
        (lambda: zero_event_upper_bound(0), "n must be > 0"),
        (lambda: zero_event_upper_bound(10, level=1.5), "level must be"),
        (lambda: one_sided_upper(4, 3), "k must be <= n"),
        (lambda: rate_summary(1, 0), "k must be <= n"),
        (lambda: rate_summary(1, 3, method="exact"), "method must be one of"),
        (lambda: bootstrap_mean_interval(np.ones(5), n_resamples=0), "n_resamples"),
        (lambda: bootstrap_mean_interval(np.ones(5), level=-0.1), "level must be"),
        (lambda: quantiles(np.ones(3), qs=(0.5, 1.5)), "qs must be"),
        (lambda: compare_unpaired(3, 2, 1, 5), "k1 must be <= n1"),
        (lambda: compare_unpaired(1, 2, 1, 0), "n2 must be > 0"),
        (lambda: compare_unpaired(1, 2, 1, 5, level=2), "level must be"),
        (lambda: compare_paired(np.ones(3, bool), np.ones(4, bool)), "equal lengths"),
        (lambda: compare_paired(np.array([], bool), np.array([], bool)), "outcomes_a must not be empty"),
        (lambda: compare_paired(np.ones((2, 2), bool), np.ones((2, 2), bool)), "outcomes_a must be one-dim"),
        (lambda: compare_paired(np.ones(3, bool), np.array([0, 2, 1])), "outcomes_b must hold booleans"),
        (lambda: compare_paired(np.ones(3, bool), np.ones(3, bool), level=0), "level must be"),
        (lambda: mcnemar_exact_pvalue(-1, 3), "only_a must be >= 0"),
    ],
)
def test_bad_arguments_raise(call, match):
    with pytest.raises(ValueError, match=match):
        call()


# ------------------------------------------------------------------------------------------
# the path the reports use: rate_summary, one-sided bounds, differences of means


@pytest.mark.parametrize("p, n", [(0.001, 1000), (0.001, 3000), (0.01, 300), (0.1, 30), (0.5, 30), (0.5, 1000)])
@pytest.mark.parametrize("method", ("clopper-pearson", "wilson"))
def test_rate_summary_coverage_on_bernoulli_source(p, n, method):
    # What summary.py stores for every cell: 1,000 cells of n Bernoulli(p) episodes each. The
    # two-sided interval must cover p in >= 93 % of them (Clopper-Pearson is >= 95 % in exact
    # coverage; Wilson, the option, is allowed its documented dip where n p is small), and the
    # exact one-sided bounds must cover from their side in >= 93 %.
    rng = np.random.default_rng(int(1e6 * p) + n)
    episodes = rng.random((REPS, n)) < p  # the synthetic Bernoulli source, episode by episode
    ks = episodes.sum(axis=1)
    summaries = [rate_summary(int(k), n, method=method) for k in ks]
    covered = np.mean([s["low"] <= p <= s["high"] for s in summaries])
    assert covered >= (0.93 if method == "clopper-pearson" or n * p >= 5 else 0.86)
    assert np.mean([p <= s["upper_one_sided"] for s in summaries]) >= 0.93
    assert np.mean([s["lower_one_sided"] <= p for s in summaries]) >= 0.93


def test_zero_failure_cells_report_the_exact_one_sided_bound():
    for n in (1, 30, 100, 3000):
        r = rate_summary(0, n)
        assert r["upper_one_sided"] == pytest.approx(1 - 0.05 ** (1 / n), rel=1e-12)
        assert sps.binom.pmf(0, n, r["upper_one_sided"]) == pytest.approx(0.05, rel=1e-9)
        safe = rate_summary(n, n)  # every episode safe: the safe rate's exact lower bound
        assert safe["lower_one_sided"] == pytest.approx(0.05 ** (1 / n), rel=1e-12)
        assert safe["lower_one_sided"] == pytest.approx(1 - r["upper_one_sided"], rel=1e-12)


@pytest.mark.parametrize("k, n", [(0, 30), (1, 30), (5, 100), (29, 30), (30, 30)])
def test_one_sided_lower(k, n):
    lb = one_sided_lower(k, n)
    if k == 0:
        assert lb == 0.0
    else:
        assert sps.binom.sf(k - 1, n, lb) == pytest.approx(0.05, rel=1e-8)  # P(X >= k | lb) = alpha
        assert lb == pytest.approx(sps.binomtest(k, n, alternative="greater").proportion_ci(0.95).low, rel=1e-9)
    assert lb <= k / n
    # symmetric to the upper bound of the complementary count
    assert lb == pytest.approx(1 - one_sided_upper(n - k, n), abs=1e-12)


def test_interval_arrays_dispatch():
    k = np.array([0, 3, 30])
    assert np.array_equal(np.stack(stats.interval_arrays(k, 30)), np.stack(clopper_pearson_arrays(k, 30)))
    assert np.array_equal(np.stack(stats.interval_arrays(k, 30, method="wilson")), np.stack(wilson_arrays(k, 30)))
    with pytest.raises(ValueError, match="method must be one of"):
        stats.interval_arrays(k, 30, method="wald")


def test_bootstrap_mean_difference_paired_and_unpaired():
    rng = np.random.default_rng(9)
    base = rng.normal(0.0, 3.0, size=400)  # a shared disturbance makes the pairs correlated
    a = base + 1.0 + rng.normal(0.0, 0.2, size=400)
    b = base + rng.normal(0.0, 0.2, size=400)
    paired = bootstrap_mean_difference(a, b, paired=True, seed=1)
    unpaired = bootstrap_mean_difference(a, b, paired=False, seed=1)
    for r in (paired, unpaired):
        assert r["diff"] == pytest.approx(a.mean() - b.mean())
        assert r["low"] <= r["diff"] <= r["high"]
    assert paired["low"] <= 1.0 <= paired["high"]
    assert paired["high"] - paired["low"] < 0.2 * (unpaired["high"] - unpaired["low"])  # pairing pays
    assert paired == bootstrap_mean_difference(a, b, paired=True, seed=1)  # deterministic
    assert (paired["method"], unpaired["method"]) == ("paired-percentile-bootstrap", "percentile-bootstrap")


def test_bootstrap_mean_difference_drops_non_finite_and_small_samples():
    a = np.array([1.0, np.nan, 3.0, 4.0])
    b = np.array([0.0, 1.0, np.inf, 2.0])
    r = bootstrap_mean_difference(a, b, paired=True)
    assert (r["n_a"], r["n_b"]) == (2, 2) and r["diff"] == pytest.approx(1.5)  # pairs 0 and 3 only
    u = bootstrap_mean_difference(a, b, paired=False)
    assert (u["n_a"], u["n_b"]) == (3, 3)
    tiny = bootstrap_mean_difference([1.0], [2.0, 3.0], paired=False)
    assert math.isnan(tiny["diff"]) and math.isnan(tiny["low"]) and tiny["mean_a"] == 1.0
    with pytest.raises(ValueError, match="equal lengths"):
        bootstrap_mean_difference([1.0, 2.0], [1.0], paired=True)
    with pytest.raises(ValueError, match="n_resamples"):
        bootstrap_mean_difference([1.0, 2.0], [1.0, 2.0], paired=False, n_resamples=0)
