"""Episode snapshots and branches in the real closed loop (mcverify.episode.snapshot).

Restoring a snapshot taken after control step k and continuing with the same key gives exactly the
uninterrupted episode (every column but the wall-clock solve times); a branch (fresh noise keyed by
(episode key, branch id, step)) replays bit for bit; and a run without branching is unchanged.
"""

from __future__ import annotations

import math

import pytest

from mcverify.campaign import executors
from mcverify.campaign.spec import campaign_from_dict
from mcverify.episode.rollout import run_episodes
from mcverify.episode.snapshot import Branching
from mcverify.schema import TIMING_COLUMNS

# Noisy and with a veh_o, long enough for the Q1/Q2 memory (warm starts, held plans) to matter.
MODEL = {"sim": {"control_period_s": 0.1, "substeps": 20, "max_time_s": 2.5}, "noise": {"kind": "paper"},
         "opposing": {"kind": "autonomous"}}


def _cell():
    camp = campaign_from_dict({"campaign": {"name": "snap", "seed": 3, "episodes": 2}, "model": MODEL})
    return camp, camp.cells[0], executors.solver_for(camp.cells[0].params)


def strip(row: dict) -> dict:
    return {k: v for k, v in row.items() if k not in TIMING_COLUMNS}


def assert_same(a: dict, b: dict) -> None:
    a, b = strip(a), strip(b)
    assert a.keys() == b.keys()
    for k in a:
        same = (isinstance(a[k], float) and math.isnan(a[k]) and math.isnan(b[k])) or a[k] == b[k]
        assert same, f"{k}: {a[k]!r} != {b[k]!r}"


@pytest.fixture(scope="module")
def whole():
    camp, cell, planner = _cell()
    plain = run_episodes(cell, [1], camp.seed, planner).rows[0]
    br = Branching(keep=lambda view: view.step in (3, 12))
    row = run_episodes(cell, [1], camp.seed, planner, branching=br).rows[0]
    return camp, cell, planner, plain, row, br


def test_branching_without_a_start_leaves_the_episode_unchanged(whole):
    _, _, _, plain, row, br = whole
    assert_same(plain, row)
    # control steps simulated: the planner's steps (row["steps"]) and the settling steps after the goal
    assert sorted(br.snapshots) == [3, 12] and br.steps == len(br.views) >= row["steps"]
    mins = [float(v.trace.min_h_front) for v in br.views]
    assert mins == sorted(mins, reverse=True) and mins[-1] == row["min_h_front"]
    # the planner's count of steps with neither problem solved, as the run's row reports it
    assert [v.both_infeasible_steps for v in br.views][-1] == row["both_infeasible_steps"]


@pytest.mark.parametrize("step", [3, 12])
def test_restoring_a_snapshot_with_the_same_key_gives_the_uninterrupted_episode(whole, step):
    camp, cell, planner, _, row, br = whole
    cont = Branching(start=br.snapshots[step])
    again = run_episodes(cell, [1], camp.seed, planner, branching=cont).rows[0]
    assert_same(row, again)
    assert cont.steps == br.steps - step - 1


def test_a_branch_replays_bit_for_bit_and_has_its_own_noise(whole):
    camp, cell, planner, _, row, br = whole
    a = run_episodes(cell, [1], camp.seed, planner, branching=Branching(start=br.snapshots[3], branch_id=5)).rows[0]
    b = run_episodes(cell, [1], camp.seed, planner, branching=Branching(start=br.snapshots[3], branch_id=5)).rows[0]
    c = run_episodes(cell, [1], camp.seed, planner, branching=Branching(start=br.snapshots[3], branch_id=6)).rows[0]
    assert_same(a, b)
    assert a["min_h_front"] != row["min_h_front"] and a["min_h_front"] != c["min_h_front"]


def test_a_snapshot_is_not_changed_by_running_from_it(whole):
    camp, cell, planner, _, row, br = whole
    snap = br.snapshots[12]
    before = (snap.state.steps, dict(snap.state.warm), snap.trace.min_h_front.copy())
    run_episodes(cell, [1], camp.seed, planner, branching=Branching(start=snap, branch_id=9))
    assert (snap.state.steps, dict(snap.state.warm)) == before[:2] and snap.trace.min_h_front == before[2]


def test_branching_is_for_one_episode(whole):
    camp, cell, planner, _, _, br = whole
    with pytest.raises(ValueError, match="one episode"):
        run_episodes(cell, [0, 1], camp.seed, planner, branching=Branching())
    with pytest.raises(ValueError, match="snapshot of episode 1"):
        run_episodes(cell, [0], camp.seed, planner, branching=Branching(start=br.snapshots[3]))


def _scheduled_cell(noise: dict):
    model = {**MODEL, "noise": {**MODEL["noise"], **noise}}
    return campaign_from_dict({"campaign": {"name": "snap", "seed": 3, "episodes": 2}, "model": model}).cells[0]


def test_scheduled_noise_branches_from_step_0_equal_snapshot_branches(whole):
    """noise.branch_after_steps / branch_ids re-simulate a branch (and a branch of a branch) from
    step 0, exactly as the snapshot branches of a splitting run continue it: what makes a splitting
    counterexample an ordinary, replayable episode."""
    camp, cell, planner, _, _, br = whole
    once = Branching(start=br.snapshots[3], branch_id=5, keep=lambda view: view.step == 12)
    first = run_episodes(cell, [1], camp.seed, planner, branching=once).rows[0]
    second = run_episodes(cell, [1], camp.seed, planner,
                          branching=Branching(start=once.snapshots[12], branch_id=7)).rows[0]
    scheduled = _scheduled_cell({"branch_after_steps": [3], "branch_ids": [5]})
    assert_same(first, run_episodes(scheduled, [1], camp.seed, planner).rows[0])
    twice = _scheduled_cell({"branch_after_steps": [3, 12], "branch_ids": [5, 7]})
    assert_same(second, run_episodes(twice, [1], camp.seed, planner).rows[0])
    with pytest.raises(ValueError, match="scheduled noise branches"):
        run_episodes(twice, [1], camp.seed, planner, branching=Branching(start=br.snapshots[3], branch_id=5))


@pytest.mark.slow  # two more closed-loop episodes; the fake episodes of tests/falsify cover the keying too
def test_noise_key_seed_replaces_the_campaign_seed_and_cell(whole):
    camp, cell, planner, plain, _, _ = whole
    keyed = _scheduled_cell({"key_seed": 11})
    a = run_episodes(keyed, [1], camp.seed, planner).rows[0]
    b = run_episodes(keyed, [1], camp.seed + 1, planner).rows[0]  # another campaign seed: the same noise
    assert strip(a) | {"seed": 0} == strip(b) | {"seed": 0}
    assert a["min_h_front"] != plain["min_h_front"]
