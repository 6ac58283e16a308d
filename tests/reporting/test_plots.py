"""mcverify.reporting.episode_plot: the replay figure, from a trajectory as `mcverify replay` stores it."""

from __future__ import annotations

import dataclasses

import matplotlib.image as mpimg
import numpy as np
import synthetic

from mcverify.campaign.spec import campaign_from_dict
from mcverify.reporting import episode_plot


def _cell():
    return campaign_from_dict({"campaign": {"name": "p", "seed": 1, "episodes": 1},
                               "model": {"barrier": {"epsilon": 0.4}}}).cells[0]


ROW = {"episode_id": 3, "outcome": "overtook", "safe": True, "min_dist_front_m": 0.7, "min_h_front": 0.55}


def test_replay_figure_from_the_replay_columns(tmp_path):
    # today's replay trajectory: no opposing or plan columns, measured front columns instead
    traj = {k: v for k, v in synthetic.trajectory(opposing=False).items() if not k.startswith(("opp_", "h_opp",
                                                                                               "gap_opp"))}
    traj["meas_front_speed_mps"] = traj["front_speed_mps"] + 0.3 * np.sin(traj["t_s"])
    path = episode_plot.episode_figure(traj, _cell(), ROW, tmp_path / "e.png")
    img = mpimg.imread(path)
    assert img.shape[1] == 1200 and img.shape[0] > 900 and img[..., :3].std() > 0.05


def test_replay_figure_with_opposing_vehicle_and_missing_heading(tmp_path):
    traj = {k: v for k, v in synthetic.trajectory(opposing=True).items() if k != "ego_psi_rad"}
    path = episode_plot.episode_figure(traj, _cell(), ROW, tmp_path / "o.png")
    assert mpimg.imread(path).shape[1] == 1200
    assert path.read_bytes() == episode_plot.episode_figure(traj, _cell(), ROW, tmp_path / "o2.png").read_bytes()


def test_a_stopped_episode_gets_a_panel_at_its_stop(tmp_path):
    # falsify's stop_episodes: the episode ended at its first violation, which the last panel shows
    # (the panels sit at plan times, and the last plan comes before the trajectory's end)
    traj = synthetic.trajectory(opposing=True)
    plans = synthetic.plans(traj)
    assert plans["t_s"].max() < traj["t_s"][-1]
    plain = mpimg.imread(episode_plot.episode_figure(traj, _cell(), ROW, tmp_path / "a.png", plans=plans))
    stopped = mpimg.imread(episode_plot.episode_figure(traj, _cell(), {**ROW, "stopped_at_violation": True},
                                                       tmp_path / "b.png", plans=plans))
    assert stopped.shape[0] > plain.shape[0]  # one more road panel


def test_an_episode_that_ran_on_gets_a_panel_at_its_first_step_without_a_plan(tmp_path):
    # a Theorem 5 counterexample of a campaign (not stopped at it): the panel is at the first certified
    # step when there is one, else at the first step with neither Q1 nor Q2 solved
    traj = synthetic.trajectory(opposing=True)
    plans = synthetic.plans(traj)
    n = len(traj["t_s"])
    k_any, k_cert = n // 3, n // 2
    traj["q1_solved"] = np.where(np.arange(n) >= k_any, 0.0, 1.0)
    traj["q2_solved"] = np.where(np.arange(n) >= k_any, 0.0, 1.0)
    traj["both_certified"] = np.where(np.arange(n) >= k_cert, 1.0, 0.0)
    row = {**ROW, "both_infeasible_steps": 5, "both_certified_infeasible_steps": 2}
    cell = _cell()
    assert episode_plot.theorem5_moment(traj, row, cell) == (traj["t_s"][k_cert], "Q1 and Q2 certified infeasible")
    uncertified = {**row, "both_certified_infeasible_steps": 0}
    assert episode_plot.theorem5_moment(traj, uncertified, cell) == (traj["t_s"][k_any], "neither Q1 nor Q2 solved")
    assert episode_plot.theorem5_moment(traj, {**row, "both_infeasible_steps": 0,
                                               "both_certified_infeasible_steps": 0}, cell) is None
    plain = mpimg.imread(episode_plot.episode_figure(traj, cell, ROW, tmp_path / "a.png", plans=plans))
    broke = mpimg.imread(episode_plot.episode_figure(traj, cell, row, tmp_path / "b.png", plans=plans))
    assert broke.shape[0] > plain.shape[0]  # one more road panel


def test_plain_mpcdc_panels_draw_no_level_it_does_not_keep():
    """Issue 51: plain MPC-DC keeps h >= 0 only; its panels showed the cell's ε as if it kept it."""
    from mcverify.model import kept_level
    from mcverify.reporting.episode_figures import barrier_panel
    from mcverify.reporting.figure_common import subplots

    assert kept_level("mpcdc", 0.4) is None and kept_level("mpcdc_eps", 0.4) == kept_level("vlcbf", 0.4) == 0.4
    traj = synthetic.trajectory(opposing=False)
    labels = {}
    for controller in ("vlcbf", "mpcdc"):
        _, ax = subplots(figsize=(6.0, 3.0))
        barrier_panel(ax, traj, kept_level(controller, 0.4))
        labels[controller] = [line.get_label() for line in ax.lines]
    assert "level ε = 0.4" in labels["vlcbf"]
    assert not any("level ε =" in label for label in labels["mpcdc"])


def test_a_late_unsafe_moment_is_labelled_to_its_left_and_the_legend_sits_beside_the_panel(tmp_path):
    """Issue 51: the label of a late first unsafe moment ran under the h_ef panel's legend."""
    from mcverify.reporting.episode_figures import mark_event
    from mcverify.reporting.figure_common import subplots
    from mcverify.reporting.unsafe_event import first_unsafe_event

    traj = synthetic.trajectory(opposing=False)
    traj["h_front"] = traj["h_front"] - 1.5 * np.exp(-((traj["t_s"] - 7.2) / 0.3) ** 2)
    event = first_unsafe_event(traj)
    assert event is not None and event.t_s > 6.0
    _, ax = subplots(figsize=(6.0, 3.0))
    ax.plot(traj["t_s"], traj["h_front"])
    mark_event(ax, event)
    assert ax.texts[-1].get_ha() == "right"  # runs leftwards, into the panel
    _, early = subplots(figsize=(6.0, 3.0))
    early.plot(traj["t_s"], traj["h_front"])
    mark_event(early, dataclasses.replace(event, t_s=1.0))
    assert early.texts[-1].get_ha() == "left"
    path = episode_plot.episode_figure(traj, _cell(), {**ROW, "safe": False}, tmp_path / "late.png")
    assert mpimg.imread(path).shape[1] == 1200
