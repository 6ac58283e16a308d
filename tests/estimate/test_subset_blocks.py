"""Subset simulation's block moves (mcverify.estimate.subset, ``Settings.block_steps``): the window law
is the one the acceptance ratio uses, the moves keep the estimate right on the surrogate (its exact p),
a run with them is deterministic and resumes bit for bit, and without them a run is what it was
(checkpoints made before them still resume). The closed loop names its focus from the row."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mcverify.estimate import subset
from mcverify.estimate.subset import Layout, _Windows
from mcverify.estimate.surrogate import Surrogate

SURROGATE = Surrogate.at(1e-3, clock="time")
BLOCKS = subset.Settings(n=500, block_steps=3)


class Killed:
    """The surrogate with its focus, killed (an exception) after ``calls`` evaluations."""

    def __init__(self, problem: Surrogate, calls: int) -> None:
        self.problem, self.calls, self.dimension, self.key = problem, calls, problem.dimension, repr(problem)
        self.layout = problem.layout

    def evaluate(self, x):
        return self.evaluate_focused(x)[:2]

    def evaluate_focused(self, x):
        self.calls -= 1
        if self.calls < 0:
            raise KeyboardInterrupt
        return self.problem.evaluate_focused(x)


@pytest.mark.parametrize("focus", [-1, 0, 1, 5, 17, 18, 19])
def test_the_windows_are_drawn_with_the_law_the_acceptance_ratio_uses(focus):
    """w(start | focus) sums to 1 over the starts, and draw() on a fine grid of its uniforms gives
    each start with that probability; the windows around a focus hold it."""
    windows = _Windows(Layout(offset=2, per_step=3, steps=20), length=3, share=0.8)
    starts = np.arange(windows.starts)
    focus_of = np.full(starts.size, focus)
    w = windows.probability(starts, focus_of)
    assert w.sum() == pytest.approx(1.0) and np.all(w > 0)
    grid = (np.arange(2000) + 0.5) / 2000  # the midpoints of a fine grid: an exact quadrature of the uniforms
    coin, position = np.meshgrid(grid, grid)
    drawn = windows.draw(np.full(coin.size, focus), coin.ravel(), position.ravel())
    share = np.bincount(drawn, minlength=windows.starts) / drawn.size
    np.testing.assert_allclose(share, w, atol=1e-3)
    if focus >= 0:
        around = (starts <= focus) & (focus < starts + 3)
        assert w[around].min() > w[~around].max()
    cols = windows.columns(np.array([0, windows.starts - 1]))
    assert cols[0, 0] == 2 and cols[1, -1] == 2 + 20 * 3 - 1 and cols.shape == (2, 9)


def test_block_moves_hold_the_surrogates_exact_p_deterministically():
    a = subset.estimate(SURROGATE, BLOCKS, runs=5, seed=3)
    assert a.contains(SURROGATE.exact_p())
    assert subset.estimate(SURROGATE, BLOCKS, runs=5, seed=3) == a
    plain = subset.estimate(SURROGATE, subset.Settings(n=500), runs=5, seed=3)
    assert plain.runs != a.runs
    r = subset.run(SURROGATE, BLOCKS, seed=3, run=0)
    conditional = r.stages[1:]
    assert r.stages[0].block_acceptance is None and all(0 < s.block_acceptance < 1 for s in conditional)
    assert conditional[0].block_scale == subset.INITIAL_BLOCK_SCALE  # the first window is a prior redraw
    assert all(0 < s.block_scale <= 1 for s in conditional) and all(0 < s.acceptance < 1 for s in conditional)
    g, _ = SURROGATE.evaluate(r.failing)
    np.testing.assert_array_equal(g, r.failing_g)  # failing samples replay with their input vector


def test_a_killed_run_with_block_moves_resumes_bit_for_bit(tmp_path):
    whole = subset.run(SURROGATE, BLOCKS, seed=5, run=2)
    path = tmp_path / "run.npz"
    for calls in (30, 80):
        with pytest.raises(KeyboardInterrupt):
            subset.run(Killed(SURROGATE, calls), BLOCKS, seed=5, run=2, checkpoint=path)
    with np.load(path) as data:  # the population's focus travels in the checkpoint
        assert data["focus"].shape == (500,)
    assert subset.run(Killed(SURROGATE, 10**6), BLOCKS, seed=5, run=2, checkpoint=path).same_as(whole)


def test_without_block_moves_the_checkpoint_fingerprint_is_unchanged(tmp_path):
    """A run without block moves keys its checkpoint as before they existed, so old checkpoints resume;
    one with them is another run."""
    assert set(subset.Settings().fingerprint()) == {"n", "p0", "target_acceptance", "initial_scale",
                                                    "chains_per_group", "max_stages", "failure_level"}
    path = tmp_path / "run.npz"
    subset.run(SURROGATE, subset.Settings(n=500), seed=5, run=0, checkpoint=path)
    with np.load(path) as data:
        assert "focus" not in data.files and "block_steps" not in json.loads(str(data["meta"]))["fingerprint"]
    with pytest.raises(ValueError, match="another run"):
        subset.run(SURROGATE, BLOCKS, seed=5, run=0, checkpoint=path)


class NoFocus:
    dimension, key = 10, "no focus"

    def evaluate(self, x):
        return 1.0 - x[:, 0], np.ones(len(x), dtype=int)


def test_block_moves_need_a_problem_with_a_focus():
    with pytest.raises(ValueError, match="layout and evaluate_focused"):
        subset.run(NoFocus(), BLOCKS)
    with pytest.raises(ValueError, match="exceeds"):
        subset.run(SURROGATE, subset.Settings(n=500, block_steps=SURROGATE.horizon_steps + 1))
    with pytest.raises(ValueError, match="block_steps"):
        subset.Settings(block_steps=-1)


def test_the_surrogates_focus_is_its_decision_step():
    x = np.random.default_rng(0).standard_normal((50, SURROGATE.dimension))
    g, steps, focus = SURROGATE.evaluate_focused(x)
    np.testing.assert_array_equal(focus, SURROGATE.scenario(x)[1])
    np.testing.assert_array_equal(g, SURROGATE.evaluate(x)[0])
    assert SURROGATE.layout == Layout(2, 1, SURROGATE.horizon_steps)
    decision = Surrogate.at(1e-3, clock="decision")
    assert np.all(decision.evaluate_focused(x)[2] == 0)
