"""The structure-matched surrogate (mcverify.estimate.surrogate): its exact p is right (against Monte
Carlo on the decisive draws and on whole input vectors), it is tuned to the target, only the decisive
units matter, both clocks have the same law, and its cost model counts the steps to the decision plus
the depth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mcverify.estimate.surrogate import SplittingProcess, Surrogate, union_probability


@pytest.mark.parametrize("a, b, c", [(0.01, 0.2, 0.1), (0.05, 0.1, 0.3), (0.001, 0.3, 0.8)])
def test_the_routes_union_has_the_closed_form(a, b, c):
    n = 2_000_000
    u = np.random.default_rng(3).random((n, 3))
    hits = (u[:, 0] > 1 - a) | np.all(u > 1 - b, axis=1) | ((u[:, 0] < c) & (u[:, 1] > 1 - c))
    exact = float(union_probability(a, b, c))
    assert abs(hits.mean() - exact) < 4 * math.sqrt(exact * (1 - exact) / n)
    assert union_probability(0.0, 0.0, 0.0) == 0.0 and union_probability(1.0, 0.0, 0.0) == 1.0


@pytest.mark.parametrize("p", [1e-3, 1e-4, 1e-6])
def test_the_surrogate_is_tuned_to_its_exact_p(p):
    s = Surrogate.at(p)
    assert s.exact_p() == pytest.approx(p, rel=1e-10)
    routes = s.route_probabilities()
    # each route carries about its share of p (they overlap a little)
    assert routes["jump"] / p == pytest.approx(0.40, abs=0.01)
    assert routes["sustained"] / p == pytest.approx(0.35, abs=0.01)
    assert routes["away_then_towards"] / p == pytest.approx(0.25, abs=0.01)


def test_the_decision_instants_masses_sum_to_one_and_match_draws():
    s = Surrogate()
    t, masses = s.tau_masses()
    assert masses.sum() == pytest.approx(1.0, abs=1e-12)
    x = np.random.default_rng(1).standard_normal((200_000, 2))  # the decision instant reads the scenario units only
    k, tau = s.scenario(x)
    for cls in range(masses.shape[0]):
        empirical = np.bincount(tau[k == cls], minlength=t.size) / x.shape[0]
        assert np.max(np.abs(empirical - masses[cls])) < 0.002


@pytest.mark.parametrize("clock", ["time", "decision"])
def test_crude_monte_carlo_on_whole_inputs_agrees_with_the_exact_p(clock):
    s = Surrogate.at(1e-2, clock=clock)
    n = 100_000
    hits = s.crude(n, np.random.default_rng(7))
    p = s.exact_p()
    assert abs(hits / n - p) < 4 * math.sqrt(p * (1 - p) / n)


@pytest.mark.parametrize("clock", ["time", "decision"])
def test_only_the_scenario_and_the_three_decisive_units_matter(clock):
    s = Surrogate.at(1e-3, clock=clock)
    rng = np.random.default_rng(2)
    x = rng.standard_normal((50, s.dimension))
    _, tau = s.scenario(x)
    first = tau if clock == "time" else np.zeros_like(tau)
    y = rng.standard_normal(x.shape)
    keep = np.zeros(x.shape, dtype=bool)
    keep[:, :2] = True
    for j in range(3):
        keep[np.arange(x.shape[0]), 2 + first + j] = True
    np.testing.assert_array_equal(s.performance(np.where(keep, x, y)), s.performance(x))
    assert not np.array_equal(s.performance(np.where(keep, y, x)), s.performance(x))


def test_the_event_is_g_at_most_zero_and_g_is_graded():
    s = Surrogate.at(1e-2)
    x = np.random.default_rng(4).standard_normal((20_000, s.dimension))
    g = s.performance(x)
    np.testing.assert_array_equal(g <= 0, s.routes(x).any(axis=1))
    assert np.unique(np.round(g, 6)).size > 1000  # a margin, not a 0/1 plateau


def test_the_cost_is_the_steps_to_the_decision_its_draws_and_the_depth():
    s = Surrogate()
    x = np.random.default_rng(5).standard_normal((20_000, s.dimension))
    _, tau = s.scenario(x)
    np.testing.assert_array_equal(s.steps(x), tau + 3 + s.depth_steps)
    assert s.steps(x).mean() == pytest.approx(s.mean_steps(), rel=0.02)
    g, steps = s.evaluate(x[:10])
    np.testing.assert_array_equal(g, s.performance(x[:10]))
    np.testing.assert_array_equal(steps, s.steps(x[:10]))


@pytest.mark.parametrize("options", [{"clock": "sideways"}, {"margin": "metres"}, {"class_probs": (0.5, 0.6, -0.1)},
                                     {"horizon_steps": 100}, {"speeds_mps": (4.0,)}])
def test_bad_options_are_refused(options):
    with pytest.raises(ValueError):
        Surrogate(**options)


def test_bad_inputs_are_refused():
    with pytest.raises(ValueError):
        Surrogate.at(0.5)
    with pytest.raises(ValueError):
        Surrogate().performance(np.zeros((2, 10)))


def test_the_splitting_process_scores_the_event_and_branches_keep_the_past():
    s = Surrogate.at(1e-2)
    process = SplittingProcess(s, seed=1)
    whole = process.run(None, 5, math.inf)
    # the final running danger is minus the robustness: the score reaches 0 exactly on the event
    assert whole.scores[-1] == pytest.approx(max(-s.performance(whole.x[None, :])[0], whole.scores[-2]))
    assert whole.steps == s.steps(whole.x[None, :])[0]
    _, tau = s.scenario(whole.x[None, :])
    t = int(tau[0])
    again = process.run(whole.snapshot(t), 5, math.inf)  # the same branch id replays the episode
    np.testing.assert_array_equal(again.x, whole.x)
    other = process.run(whole.snapshot(t), 6, math.inf)
    np.testing.assert_array_equal(other.x[: 2 + t + 1], whole.x[: 2 + t + 1])  # the scenario and steps <= t kept
    assert not np.array_equal(other.x, whole.x) and other.steps == whole.steps - (t + 1)
