"""Falsify mode (sim.stop_at): an episode ends at its first violation, honestly and replayably."""

from __future__ import annotations

import numpy as np
import pytest

from mcverify.analysis import robustness as rb
from mcverify.campaign import executors, runner
from mcverify.campaign.replay import replay
from mcverify.campaign.spec import campaign_from_dict, load_campaign
from mcverify.episode.rollout import run_episodes
from mcverify.errors import CampaignError
from mcverify.model import REQUIREMENT_NAMES

# Table IV A with MPC-DC at 10 Hz: it squeezes in and enters veh_f's ellipse (tests/episode/test_rollout.py)
MODEL = {"opposing": {"kind": "human", "x_m": 220.0, "speed_mps": 18.0}, "scenario": {"front_speed_mps": 25 / 3.6},
         "sim": {"control_period_s": 0.1, "substeps": 20}, "mpc": {"controller": "mpcdc"}}


def _campaign(stop_at: str = ""):
    model = {**MODEL, "sim": {**MODEL["sim"], "stop_at": stop_at}}
    return campaign_from_dict({"campaign": {"name": "stop", "seed": 11, "episodes": 1}, "model": model})


@pytest.fixture(scope="module")
def episodes(tmp_path_factory):
    """The same MPC-DC episode run to its end (recorded) and, through a run folder, stopped at its first
    ellipse violation; the stopped one replayed from the folder (which checks every column bit for bit)."""
    full_camp = _campaign()
    cell = full_camp.cells[0]
    full = run_episodes(cell, [0], full_camp.seed, executors.solver_for(cell.params), record=True)
    run_dir = tmp_path_factory.mktemp("stop") / "run"
    runner.run(_campaign("ellipse"), run_dir, executor=executors.SerialExecutor(), progress=False)
    replayed = replay(run_dir, 0)  # raises ReplayMismatch unless the stored row is reproduced exactly
    stored = runner.store.read_episodes(run_dir).to_pylist()[0]
    return full, stored, replayed


@pytest.mark.slow  # the fixture runs three real MPC-DC episodes (about a minute of CPU with the kernel built)
def test_a_stopped_episode_ends_at_its_first_violation_and_says_so(episodes):
    full, stopped, _ = episodes
    whole = full.rows[0]
    assert not whole["stopped_at_violation"] and rb.robustness(whole, "ellipse") < 0  # a counterexample
    assert stopped["stopped_at_violation"] and stopped["outcome"] == "stopped"
    assert not (stopped["overtook"] or stopped["went_back"] or stopped["timeout"])
    assert rb.robustness(stopped, "ellipse") < 0  # still a counterexample of the requirement
    # it ended at the end of the control period in which it first left the safe set
    assert stopped["end_time_s"] == stopped["settle_end_s"] == pytest.approx(stopped["first_unsafe_s"] + 0.1)
    assert stopped["first_unsafe_s"] == whole["first_unsafe_s"]
    assert stopped["first_unsafe_cause"] == whole["first_unsafe_cause"]
    assert stopped["steps"] < whole["steps"]  # what it saves
    assert stopped["min_h_front"] >= whole["min_h_front"]  # a minimum over a shorter time


@pytest.mark.slow  # shares the fixture above
def test_the_stopped_trajectory_is_the_prefix_and_its_metrics_recompute(episodes):
    full, stopped, replayed = episodes
    import pyarrow.parquet as pq  # noqa: PLC0415

    traj = pq.read_table(replayed.trajectory_path).to_pydict()
    whole = full.recordings[0].trajectory
    n = len(traj["t_s"])
    assert 0 < n < len(whole["t_s"])
    for key, col in traj.items():  # bit for bit the first n sub-steps of the uninterrupted episode
        np.testing.assert_array_equal(np.asarray(col, dtype=float), np.asarray(whole[key][:n], dtype=float), key)
    assert traj["t_s"][-1] == pytest.approx(stopped["settle_end_s"])
    assert stopped["min_h_front"] == min(traj["h_front"])
    assert stopped["min_gap_front_m"] == min(traj["gap_front_m"])
    assert stopped["collision_front"] == bool(max(traj["collision_front"]))
    assert n == stopped["steps"] * MODEL["sim"]["substeps"]  # one control step per 20 recorded sub-steps


@pytest.mark.parametrize("name", REQUIREMENT_NAMES)
def test_every_requirement_can_stop_and_a_campaign_file_cannot(tmp_path, name):
    assert _campaign(name).cells[0].params.sim.stop_at == name
    f = tmp_path / "c.toml"
    f.write_text(f'[campaign]\nname = "c"\nseed = 1\nepisodes = 1\n[model.sim]\nstop_at = "{name}"\n')
    with pytest.raises(CampaignError, match="set by `mcverify falsify` only") as err:
        load_campaign(f)
    assert "\n" not in str(err.value)


def test_an_unknown_stop_requirement_is_one_line():
    with pytest.raises(CampaignError, match="sim.stop_at: unknown requirement"):
        _campaign("fast")
