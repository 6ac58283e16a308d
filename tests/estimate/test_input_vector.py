"""mcverify.estimate.input_vector: the closed loop as a function of standard normals has the campaign's
law (an episode's own drawn units, mapped to normals, re-simulate its row), is deterministic, and refuses
cells whose noise is not i.i.d. uniform units."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

import jax
import numpy as np
import pytest
from scipy.special import ndtri

from mcverify.campaign import executors
from mcverify.campaign.overrides import apply_overrides
from mcverify.campaign.spec import load_campaign
from mcverify.episode.draws import episode_key
from mcverify.episode.rollout import run_episodes
from mcverify.errors import RunError
from mcverify.estimate.input_vector import ClosedLoopProblem
from mcverify.sim import noise
from mcverify.sim.plant import STREAM_FRONT

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "tiny.toml"


@pytest.fixture(scope="module")
def cell():
    return load_campaign(FIXTURE).cells[1]


def test_an_episodes_own_draws_as_normals_re_simulate_it(cell):
    """The input vector is the campaign's law: episode e's drawn units u, as x = Phi^-1((u + 1) / 2), give
    back the units (2 Phi(x) - 1) and so the episode, up to the last bits of that round trip."""
    planner = executors.solver_for(cell.params)
    seed, episode = 11, 2
    problem = ClosedLoopProblem(cell, seed, "ellipse", planner)
    assert problem.draws == () and problem.channels == (0, 1, 2)  # no drawn scenario, no veh_o
    assert problem.dimension == 10 * 3  # 1 s at 10 Hz, veh_f's x, y and v
    key = episode_key(seed, cell.index, episode)
    units = np.array([np.asarray(noise.unit_draws(noise.step_key(key, k, STREAM_FRONT))) for k in range(10)])
    x = ndtri((units + 1.0) / 2.0).reshape(1, -1)
    mapped = problem.simulate(x).rows[0]
    drawn = run_episodes(cell, [episode], seed, planner).rows[0]
    for column in ("min_h_front", "min_dist_front", "min_gap_front_m", "final_speed_mps"):
        if column in drawn:
            assert mapped[column] == pytest.approx(drawn[column], rel=1e-9, abs=1e-9), column
    assert mapped["steps"] == drawn["steps"] and mapped["outcome"] == drawn["outcome"]


def test_evaluate_is_a_pure_function_of_the_rows(cell):
    problem = ClosedLoopProblem(cell, 11, "collision", executors.solver_for(cell.params))
    x = np.random.default_rng(3).standard_normal((2, problem.dimension))
    g1, steps1 = problem.evaluate(x)
    g2, _ = problem.evaluate(x[::-1])  # batch order and company change nothing
    assert np.array_equal(g1, g2[::-1]) and list(steps1) == [10, 10]
    assert problem.steps_run == 40 and problem.episodes_run == 4
    with pytest.raises(ValueError, match="inputs need 30 units per row"):
        problem.evaluate(x[:, :5])


@pytest.mark.parametrize(("field", "value", "message"), [
    ("noise.structured_share", 0.5, "noise.structured_share = 0.5"),
    ("noise.key_seed", 3, "fixes its noise"),
])
def test_a_cell_with_another_noise_law_is_refused(cell, field, value, message):
    other = dataclasses.replace(cell, params=apply_overrides(cell.params, {field: value}, "test"))
    with pytest.raises(RunError, match=message):
        ClosedLoopProblem(other, 11, "collision", None)


def test_an_unknown_target_is_refused(cell):
    with pytest.raises(RunError, match="unknown target"):
        ClosedLoopProblem(cell, 11, "crash", None)


def test_jax_is_in_double_precision():  # the law test above compares to 1e-9
    assert jax.config.read("jax_enable_x64")


@pytest.mark.parametrize(("h_ef", "longest_run", "expected"), [
    (0.3, 0, 0.3), (0.3, 2, 0.1), (-0.03, 2, -0.01), (0.0, 5, 0.0), (-0.2, 0, -0.2),
])
def test_the_precursor_ladder_divides_the_robustness_by_one_plus_the_longest_unsolved_run(
        cell, h_ef, longest_run, expected):
    plain = ClosedLoopProblem(cell, 11, "ellipse", None)
    ladder = ClosedLoopProblem(cell, 11, "ellipse", None, "precursor-ladder")
    row = {"outcome": "completed", "min_h_front": h_ef, "both_infeasible_longest_run": longest_run}
    assert plain.performance(row) == h_ef
    assert ladder.performance(row) == pytest.approx(expected, abs=1e-15)
    assert (ladder.performance(row) <= 0) == (plain.performance(row) <= 0)  # the same event


@pytest.mark.parametrize(("h_ef", "margin", "expected"), [
    (0.3, 0.2, 0.3), (0.3, -0.1, 0.15), (0.3, -0.5, 0.05), (-0.06, -0.5, -0.01), (0.3, float("nan"), 0.3),
    (0.0, -1.0, 0.0),
])
def test_the_margin_ladder_divides_the_robustness_by_the_depth_of_the_theorem5_margin(cell, h_ef, margin, expected):
    ladder = ClosedLoopProblem(cell, 11, "ellipse", None, "margin-ladder")
    row = {"outcome": "completed", "min_h_front": h_ef, "theorem5_margin": margin, "both_infeasible_longest_run": 4}
    assert ladder.performance(row) == pytest.approx(expected, abs=1e-15)
    assert (ladder.performance(row) <= 0) == (h_ef <= 0)  # the same event


def test_the_performance_function_names_the_problem_but_the_default_keeps_old_keys(cell):
    plain = ClosedLoopProblem(cell, 11, "ellipse", None)
    ladder = ClosedLoopProblem(cell, 11, "ellipse", None, "precursor-ladder")
    assert plain.key != ladder.key
    old = hashlib.sha256(json.dumps({"cell": cell.name, "params": repr(cell.params), "seed": 11,
                                     "target": "ellipse"}, sort_keys=True).encode()).hexdigest()
    assert plain.key == old  # checkpoints written before there was a choice still resume
    with pytest.raises(RunError, match="unknown performance function 'gap'; valid: robustness, precursor-ladder, "
                       "margin-ladder"):
        ClosedLoopProblem(cell, 11, "ellipse", None, "gap")

