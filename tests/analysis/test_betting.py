"""The anytime-valid betting lower bound (mcverify.analysis.betting): it holds over many repetitions
and after a data-dependent number of samples, and it is informative when the mean is clear."""

from __future__ import annotations

import numpy as np
import pytest

from mcverify.analysis.betting import lower_bound


def test_informative_and_below_the_mean():
    rng = np.random.default_rng(0)
    y = rng.random(2000) * 0.2  # mean 0.1
    lb = lower_bound(y)
    assert 0.07 < lb < 0.1


def test_edge_cases():
    assert lower_bound([]) == 0.0
    assert lower_bound(np.zeros(100)) == 0.0
    with pytest.raises(ValueError):
        lower_bound([1.5])


@pytest.mark.parametrize("reps, ceiling", [pytest.param(30, 0.1, id="fast"),
                                            pytest.param(300, 0.06, id="large", marks=pytest.mark.slow)])
def test_holds_over_repetitions_for_a_rare_heavy_tailed_mean(reps, ceiling):
    """Values like alpha * weight * 1{event}: mostly 0, sometimes large. The bound must exceed the
    true mean in at most ~5 % of the repetitions, even read at the best of several sample counts."""
    rng = np.random.default_rng(1)
    mean = 0.002 * 0.6
    over = 0
    for _ in range(reps):
        y = np.where(rng.random(3000) < 0.002, rng.uniform(0.2, 1.0, 3000), 0.0)
        best = max(lower_bound(y[:n]) for n in (500, 1000, 2000, 3000))  # peeking at four counts
        over += best > mean
    assert over / reps <= ceiling
