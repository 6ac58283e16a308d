"""The beta-binomial confidence sequence and stopping on its width (mcverify.analysis.sequential).

Coverage is a property of the estimator, so it is checked on synthetic Bernoulli episodes: stopping
at the first episode where the half-width is small enough must keep the 95 % coverage, and the
fixed-n Clopper-Pearson interval re-checked after every episode must not (it misses p at some
episode far more often than 5 %: the counter-example to peeking).
"""

from __future__ import annotations

import numpy as np
import pytest

from mcverify.analysis.intervals import clopper_pearson_arrays
from mcverify.analysis.sequential import (
    StopRule,
    confidence_sequence_arrays,
    log_mixture_martingale,
    running_bounds,
    sequential_estimate,
)


def test_interval_ends_are_where_the_martingale_crosses_one_over_alpha():
    k, n = np.array([3, 0, 10, 57]), np.array([40, 25, 10, 1000])
    low, high = confidence_sequence_arrays(k, n, 0.95)
    thr = np.log(20.0)
    inner = (k > 0) & (k < n)
    np.testing.assert_allclose(log_mixture_martingale(k[inner], n[inner], low[inner]), thr, atol=1e-6)
    np.testing.assert_allclose(log_mixture_martingale(k[k < n], n[k < n], high[k < n]), thr, atol=1e-6)
    assert low[1] == 0.0 and high[2] == 1.0
    assert np.all(low <= k / n) and np.all(k / n <= high)


def test_the_sequence_is_wider_than_clopper_pearson_at_the_same_counts():
    k, n = np.arange(0, 50, 7), np.full(8, 400)
    low, high = confidence_sequence_arrays(k, n)
    cp_low, cp_high = clopper_pearson_arrays(k, n)
    assert np.all(low <= cp_low + 1e-12) and np.all(high >= cp_high - 1e-12)


def test_empty_prefix_is_the_whole_unit_interval():
    low, high = confidence_sequence_arrays(0, 0)
    assert float(low) == 0.0 and float(high) == 1.0
    res = sequential_estimate([], StopRule(0.1))
    assert res.status == "running" and res.n == 0


def test_stops_at_the_first_episode_meeting_the_rule_and_ignores_later_ones():
    rng = np.random.default_rng(0)
    x = rng.random(5000) < 0.2
    res = sequential_estimate(x, StopRule(0.05, budget=5000))
    k, n, low, high = running_bounds(x)
    first = int(np.flatnonzero((high - low) / 2 <= 0.05)[0])
    assert res.status == "halfwidth" and res.n == first + 1 and res.k == int(k[first])
    later = x.copy()
    later[res.n:] = ~later[res.n:]  # what comes after the stop cannot change the result
    assert sequential_estimate(later, StopRule(0.05, budget=5000)) == res


def test_budget_and_running_status():
    x = np.zeros(30, dtype=bool)
    assert sequential_estimate(x, StopRule(0.001, budget=20)).status == "budget"
    res = sequential_estimate(x, StopRule(0.001, budget=100))
    assert res.status == "running" and res.n == 30 and res.low == 0.0
    assert sequential_estimate(x, StopRule(0.5, relative=True)).status == "running"  # no event yet


@pytest.mark.parametrize("bad", [dict(halfwidth=0.0), dict(halfwidth=-1.0), dict(budget=0), dict()])
def test_bad_rules_are_refused(bad):
    with pytest.raises(ValueError):
        StopRule(**bad)


def _coverage(p: float, rule: StopRule, reps: int, horizon: int, seed: int) -> tuple[float, float, float]:
    """Coverage at the stopping time for the sequence, Clopper-Pearson misses at *some* episode, and
    the sequence's misses at some episode, over ``reps`` synthetic runs."""
    rng = np.random.default_rng(seed)
    covered = cp_ever_missed = cs_ever_missed = 0
    n = np.arange(1, horizon + 1)
    for _ in range(reps):
        x = rng.random(horizon) < p
        res = sequential_estimate(x, rule)
        covered += res.low <= p <= res.high
        k = np.cumsum(x)
        cp_low, cp_high = clopper_pearson_arrays(k, n)
        cp_ever_missed += bool(np.any((cp_low > p) | (cp_high < p)))
        _, _, low, high = running_bounds(x)
        cs_ever_missed += bool(np.any((low > p) | (high < p)))
    return covered / reps, cp_ever_missed / reps, cs_ever_missed / reps


def test_stopping_on_the_half_width_keeps_coverage_small():
    cov, cp_missed, cs_missed = _coverage(0.05, StopRule(0.03, budget=1500), reps=120, horizon=1500, seed=11)
    assert cov >= 0.90
    assert cs_missed <= 0.10
    # Peeking at Clopper-Pearson after every episode: it excludes p at some episode much more often
    # than 5 % (about a third of the runs over 1500 episodes), so stopping when it first does so
    # (a "significant" result) has nothing like 95 % coverage.
    assert cp_missed >= 0.15


@pytest.mark.slow
def test_stopping_on_the_half_width_keeps_coverage_large():
    for p, rule in ((0.05, StopRule(0.02, budget=4000)), (0.1, StopRule(0.5, relative=True, budget=4000))):
        cov, cp_missed, cs_missed = _coverage(p, rule, reps=500, horizon=4000, seed=12)
        assert cov >= 0.94, (p, cov)
        assert cs_missed <= 0.06, (p, cs_missed)
        assert cp_missed >= 0.25, (p, cp_missed)
