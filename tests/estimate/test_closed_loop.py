"""Adaptive multilevel splitting on the real closed loop (mcverify.estimate.closed_loop): branches
start from the parent's snapshot at the first step above the level, inherit its score prefix, and
the whole run replays exactly; the scores reach 0 exactly at their target event. A short noisy
episode keeps this to seconds; the estimate's coverage is tested on the synthetic walk
(test_splitting.py)."""

from __future__ import annotations

import numpy as np
import pytest

from mcverify.campaign import executors
from mcverify.campaign.spec import campaign_from_dict
from mcverify.episode.snapshot import StepView
from mcverify.estimate import splitting
from mcverify.estimate.closed_loop import HELD_FACTOR, ClosedLoopProcess, score_of
from mcverify.sim.plant import SafetyTrace

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


def _view(min_h: float, unsolved: int, run: int = 0) -> StepView:
    trace = SafetyTrace(*([np.float64(np.inf)] * len(SafetyTrace._fields)))._replace(min_h_front=np.float64(min_h))
    return StepView(0, trace, unsolved, run)


def test_the_held_score_reaches_zero_exactly_at_the_ellipse_and_never_decreases():
    """h_ef_held is brought forward by the steps with neither problem solved, but it is >= 0 exactly
    when h_ef is <= 0 (the same target event as h_ef), and it cannot fall along an episode (min h_ef
    only falls, the count only rises)."""
    for m in (0.4, 0.05, 1e-9):
        for unsolved in (0, 3, 8, 30):
            assert score_of(_view(m, unsolved), "h_ef_held") < 0
            assert score_of(_view(m, unsolved), "h_ef_held") >= score_of(_view(m, 0), "h_ef")
    for m in (0.0, -1e-9, -0.5):
        assert score_of(_view(m, 0), "h_ef_held") == score_of(_view(m, 12), "h_ef_held") == -m
    path = [(0.45, 0), (0.40, 0), (0.40, 2), (0.31, 2), (0.31, 9), (0.12, 9), (-0.3, 9), (-0.3, 10)]
    scores = [score_of(_view(m, b), "h_ef_held") for m, b in path]
    assert scores == sorted(scores) and scores[2] > scores[1]  # an unsolved step alone raises it
    # one more unsolved step outranks an ordinary approach's closer min h_ef
    assert score_of(_view(0.45, 1), "h_ef_held") > score_of(_view(0.2, 0), "h_ef_held")
    assert score_of(_view(0.4, 3), "h_ef_held") == pytest.approx(-0.4 * HELD_FACTOR**3)


def test_the_run_score_follows_the_current_run_and_falls_back_when_it_ends():
    """h_ef_run is brought forward by the current run of steps with neither problem solved only: the
    state's value falls back to -m when a run ends (so an episode that recovered is not kept near 0
    for good, unlike h_ef_held), and it is >= 0 exactly when h_ef is <= 0."""
    for m in (0.4, 0.05, 1e-9):
        for run in (0, 3, 8, 30):
            assert score_of(_view(m, 99, run), "h_ef_run") < 0
            assert score_of(_view(m, 99, run), "h_ef_run") == pytest.approx(-m * HELD_FACTOR**run)
    for m in (0.0, -1e-9, -0.5):
        assert score_of(_view(m, 12, 5), "h_ef_run") == -m
    # a run of 4 that ended: the held score stays brought forward, the run score falls back to -m
    assert score_of(_view(0.3, 4, 0), "h_ef_held") == pytest.approx(-0.3 * HELD_FACTOR**4)
    assert score_of(_view(0.3, 4, 0), "h_ef_run") == -0.3


def _gap_view(gap_front: float, gap_opp: float, run: int) -> StepView:
    trace = SafetyTrace(*([np.float64(np.inf)] * len(SafetyTrace._fields)))._replace(
        min_gap_front_m=np.float64(gap_front), min_gap_opp_any_m=np.float64(gap_opp))
    return StepView(0, trace, 99, run)


def test_the_gap_run_score_is_the_collision_event_brought_forward_by_the_current_run():
    """gap_run: -g 0.3^r while the smaller footprint gap g is positive, 0 at a contact (gap 0), so it
    is >= 0 exactly at a collision, as gap; a run that ends takes it back to -g."""
    for g in (2.0, 0.3, 1e-9):
        for run in (0, 2, 7):
            assert score_of(_gap_view(g, np.inf, run), "gap_run") == pytest.approx(-g * HELD_FACTOR**run)
            assert score_of(_gap_view(g, np.inf, run), "gap_run") < 0
    assert score_of(_gap_view(0.0, 3.0, 4), "gap_run") == 0.0 == score_of(_gap_view(5.0, 0.0, 0), "gap_run")
    assert score_of(_gap_view(1.0, 0.4, 2), "gap_run") == pytest.approx(-0.4 * HELD_FACTOR**2)  # the smaller gap
    assert score_of(_gap_view(0.8, np.inf, 0), "gap_run") == score_of(_gap_view(0.8, np.inf, 0), "gap") == -0.8
    assert score_of(_gap_view(np.inf, np.inf, 3), "gap_run") == -np.inf


def test_the_step_views_carry_the_planners_current_run(repo_root):
    """On the validation cell's episode 40 (its planner solved neither problem for several steps in a
    row) the views' run restarts at 0 after a solved step and adds 1 after an unsolved one, and it
    sums up to the row's counts."""
    from mcverify.campaign.spec import load_campaign
    from mcverify.episode.rollout import run_episodes
    from mcverify.episode.snapshot import Branching

    camp = load_campaign(repo_root / "campaigns/rare_validation_10hz.toml")
    cell = camp.cells[0]
    br = Branching()
    row = run_episodes(cell, [40], camp.seed, executors.solver_for(cell.params), branching=br).rows[0]
    runs = np.array([v.both_infeasible_run for v in br.views])
    totals = np.array([v.both_infeasible_steps for v in br.views])
    assert row["both_infeasible_steps"] >= 3
    assert np.all((runs[1:] == 0) | (runs[1:] == runs[:-1] + 1))
    assert np.array_equal(np.diff(totals), (runs[1:] > 0).astype(int))
    assert runs.max() == row["both_infeasible_longest_run"] and totals[-1] == row["both_infeasible_steps"]
    # the row's first step of that run: the view (control step) where the run first reached its length, minus it
    steps = np.array([v.step for v in br.views])
    ended = int(np.flatnonzero(runs == runs.max())[0])
    assert row["both_infeasible_longest_run_first_step"] == steps[ended] - runs.max() + 1


def _replayed_scores(proc: ClosedLoopProcess, record: dict) -> np.ndarray:
    """The running score of ``record``'s particle re-simulated from step 0 as an ordinary episode with
    its noise branches scheduled (what ``mcverify replay`` of a splitting folder does)."""
    import dataclasses  # noqa: PLC0415

    from mcverify.campaign.overrides import apply_overrides  # noqa: PLC0415
    from mcverify.episode.rollout import run_episodes  # noqa: PLC0415
    from mcverify.episode.snapshot import Branching  # noqa: PLC0415

    lineage = {"noise.branch_after_steps": record["branch_after_steps"], "noise.branch_ids": record["branch_ids"]}
    cell = dataclasses.replace(proc.cell, params=apply_overrides(proc.cell.params, lineage, "test"))
    watch = Branching()
    run_episodes(cell, [record["episode_id"]], proc.seed, proc.planner, branching=watch)
    return np.maximum.accumulate([score_of(v, proc.score) for v in watch.views])


def test_a_particles_lineage_replays_it_from_step_0(process):
    """A branch of a branch (later than its parent's branch step, and earlier, on an inherited snapshot)
    carries the noise branches that re-simulate it bit for bit as an ordinary episode."""
    proc = process()
    parent = proc.run(None, 4, np.inf)
    t = splitting.first_step_above(parent, 0.5 * (parent.scores[0] + parent.scores[-1]))
    child = proc.run(parent.snapshot(t), 77, np.inf)
    later = proc.run(child.snapshot(splitting.first_step_above(child, 0.5 * (child.scores[t] + child.scores[-1]))),
                     91, np.inf)
    earlier_step = min(child.snapshots)
    assert earlier_step < t
    earlier = proc.run(child.snapshot(earlier_step), 93, np.inf)
    assert parent.lineage == () and child.lineage == ((t, 77),)
    assert later.lineage[0] == (t, 77) and later.lineage[1][1] == 91 and later.lineage[1][0] > t
    assert earlier.lineage == ((earlier_step, 93),)  # the child's own branch came after: not inherited
    for path in (parent, child, later, earlier):
        record = path.replay_record()
        assert record["end_step"] == path.scores.size - 1 and record["score"] == path.scores[-1]
        np.testing.assert_array_equal(_replayed_scores(proc, record)[: path.scores.size], path.scores)
