"""Cross-entropy importance sampling (mcverify.estimate.importance) on a score with a known failure
probability: theta uniform on [0, 1]^2, failure where theta_1 + theta_2 >= 1.9, p = 0.005 exactly."""

from __future__ import annotations

import numpy as np
import pytest

from mcverify.estimate import importance

BOUNDS = [(0.0, 1.0), (0.0, 1.0)]
P = 0.1**2 / 2


def score(theta: np.ndarray) -> np.ndarray:
    return theta.sum(axis=1) - 1.9


def test_the_proposal_moves_to_the_failure_corner_and_the_estimate_is_close():
    est = importance.estimate(score, BOUNDS, samples=2000, seed=1)
    assert est.ce_levels[-1] == 0.0 and est.ce_levels == sorted(est.ce_levels)
    assert all(a > b for a, b in zip(est.proposal_a, est.proposal_b, strict=True))  # mass near 1
    assert est.contains(P) and est.failures > 200 and not est.warnings
    assert est.ess > 100 and est.max_weight_share < 0.05
    # the defensive mixture bounds every weight by 1 / alpha
    assert est.estimate <= 10.0


def test_deterministic():
    assert importance.estimate(score, BOUNDS, samples=500, seed=3) == importance.estimate(
        score, BOUNDS, samples=500, seed=3)


def test_warns_when_it_cannot_find_failures():
    est = importance.estimate(lambda t: t.sum(axis=1) - 2.5, BOUNDS, samples=300, seed=0)
    assert est.estimate == 0.0 and any("failing samples" in w for w in est.warnings)


def test_bad_input():
    with pytest.raises(ValueError):
        importance.estimate(score, [(1.0, 0.0)])
    with pytest.raises(ValueError):
        importance.estimate(score, BOUNDS, alpha=0.0)


@pytest.mark.parametrize("reps, floor", [pytest.param(20, 0.8, id="fast"),
                                          pytest.param(200, 0.9, id="large", marks=pytest.mark.slow)])
def test_coverage(reps, floor):
    ests = [importance.estimate(score, BOUNDS, samples=1000, seed=100 + r) for r in range(reps)]
    coverage = np.mean([e.contains(P) for e in ests])
    values = np.array([e.estimate for e in ests])
    assert coverage >= floor
    assert abs(values.mean() / P - 1) < 0.05


def test_the_anytime_lower_bound_holds():
    ests = [importance.estimate(score, BOUNDS, samples=1000, seed=300 + r) for r in range(20)]
    assert all(e.anytime_lower <= e.estimate for e in ests)
    assert np.mean([e.anytime_lower > P for e in ests]) <= 0.1
    assert np.mean([e.anytime_lower for e in ests]) > 0.3 * P  # informative, not just 0


def test_warns_when_the_cross_entropy_elite_is_too_small_to_fit():
    small = importance.estimate(score, BOUNDS, samples=200, seed=1, per_iteration=16, rho=0.1)
    assert any("elite holds about 2 samples" in w and "at least 100 per iteration" in w for w in small.warnings)
    enough = importance.estimate(score, BOUNDS, samples=200, seed=1, per_iteration=100, rho=0.1)
    assert not any("elite" in w for w in enough.warnings)


def test_a_refit_never_gives_a_beta_with_a_pole():
    """An elite spread over the whole range fits near Beta(1, 1); over-dispersing it must not take a
    parameter below 1 (a U-shaped proposal piles its draws on the bounds), and the mean is kept."""
    nominal = importance.Proposal.nominal([(0.5, 2.0)])
    spread = np.random.default_rng(0).uniform(0.5, 2.0, size=(40, 1))
    g = nominal.refit(spread, np.ones(40))
    assert g.a[0] >= 1.0 and g.b[0] >= 1.0 and min(g.a[0], g.b[0]) == pytest.approx(1.0)
    near_low = 0.5 + 1.5 * np.random.default_rng(1).beta(2.0, 8.0, size=(40, 1))
    h = nominal.refit(near_low, np.ones(40))
    unit_mean = (near_low[:, 0].mean() - 0.5) / 1.5
    smoothed_mean = h.a[0] / (h.a[0] + h.b[0])
    assert h.a[0] >= 1.0 and h.b[0] >= 1.0 and 0.15 < smoothed_mean < 0.5 and smoothed_mean > unit_mean


def test_the_stream_separates_estimates_that_share_a_seed():
    """Stream 0 is the seed's own stream (single-cell estimates as before); another stream (another
    cell) draws independently."""
    base = importance.estimate(score, BOUNDS, samples=200, seed=4, per_iteration=100)
    assert importance.estimate(score, BOUNDS, samples=200, seed=4, per_iteration=100, stream=0) == base
    other = importance.estimate(score, BOUNDS, samples=200, seed=4, per_iteration=100, stream=1)
    assert other.estimate != base.estimate
