"""Adaptive multilevel splitting on the real closed loop (mcverify.estimate.closed_loop): branches
start from the parent's snapshot at the first step above the level, inherit its score prefix, and
the whole run replays exactly. A short noisy episode keeps this to seconds; the estimate's coverage
is tested on the synthetic walk (test_splitting.py)."""

from __future__ import annotations

import numpy as np
import pytest

from mcverify.campaign import executors
from mcverify.campaign.spec import campaign_from_dict
from mcverify.estimate import splitting
from mcverify.estimate.closed_loop import ClosedLoopProcess

MODEL = {"sim": {"control_period_s": 0.1, "substeps": 20, "max_time_s": 1.5}, "noise": {"kind": "paper", "scale": 3.0}}


@pytest.fixture(scope="module")
def process():
    camp = campaign_from_dict({"campaign": {"name": "ams", "seed": 2, "episodes": 1}, "model": MODEL})
    cell = camp.cells[0]
    return lambda: ClosedLoopProcess(cell, camp.seed, executors.solver_for(cell.params), "h_ef")


def test_a_branch_inherits_its_parent_up_to_the_branch_step(process):
    proc = process()
    parent = proc.run(None, 4, 0.0)
    assert parent.steps == parent.scores.size and np.all(np.diff(parent.scores) >= 0)
    level = 0.5 * (parent.scores[0] + parent.scores[-1])
    t = splitting.first_step_above(parent, level)
    child = proc.run(parent.snapshot(t), 77, 0.0)
    np.testing.assert_array_equal(child.scores[: t + 1], parent.scores[: t + 1])
    assert child.scores[-1] > level and child.steps == parent.steps - t - 1
    again = proc.run(parent.snapshot(t), 77, 0.0)
    np.testing.assert_array_equal(again.scores, child.scores)
    assert proc.steps == parent.steps + child.steps + again.steps and proc.cpu_s > 0


def test_a_short_ams_run_replays_exactly(process):
    runs = []
    for _ in range(2):
        proc = process()
        runs.append((splitting.ams(proc, n=3, k=1, failure_level=0.0, seed=1, max_iterations=2), proc.steps))
    (a, steps_a), (b, steps_b) = runs
    assert a == b and steps_a == steps_b == a.steps
    assert a.iterations == 2 and a.levels == sorted(a.levels) and a.capped


def test_a_path_ends_once_its_score_reaches_the_stop_level(process):
    """The failure set is absorbing: a path stops after the first step with score >= stop_level, and
    up to there it is the uninterrupted path bit for bit (so the estimate is unchanged, the cost lower)."""
    proc = process()
    whole = proc.run(None, 4, np.inf)
    level = 0.5 * (whole.scores[0] + whole.scores[-1])
    hit = int(np.flatnonzero(whole.scores >= level)[0])
    assert hit < whole.scores.size - 1
    stopped = proc.run(None, 4, level)
    np.testing.assert_array_equal(stopped.scores, whole.scores[: hit + 1])
    assert stopped.steps == hit + 1 < whole.steps
