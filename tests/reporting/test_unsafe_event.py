"""mcverify.reporting.unsafe_event and the road panels: the first unsafe moment of a stored
trajectory (when, which constraint, which vehicle, what margin) and how the figures mark it."""

from __future__ import annotations

import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import synthetic  # noqa: E402

from mcverify.reporting import episode_figures, figure_common, road_panels  # noqa: E402
from mcverify.reporting.unsafe_event import first_unsafe_event, violations  # noqa: E402


def test_a_safe_trajectory_has_no_event():
    traj = synthetic.trajectory(opposing=True)
    assert np.nanmin(traj["h_front"]) > 0 and np.nanmin(traj["gap_front_m"]) > 0  # the fixture is safe
    assert first_unsafe_event(traj) is None


def test_ellipse_event_names_the_first_negative_h_and_the_minimum():
    traj = synthetic.trajectory(opposing=False, went_back=True)
    h = traj["h_front"]
    k = int(np.flatnonzero(h < 0)[0])
    ev = first_unsafe_event(traj)
    assert (ev.constraint, ev.vehicle, ev.index) == ("ellipse", "veh_f", k)
    assert ev.t_s == traj["t_s"][k] and ev.margin == h[k] < 0
    assert ev.worst == h.min() and ev.worst_t_s == traj["t_s"][int(np.argmin(h))]
    assert ev.label() == f"ellipse h_ef = {h[k]:.3f} at {traj['t_s'][k]:.2f} s (min {h.min():.3f} at " \
                         f"{ev.worst_t_s:.2f} s)"


def test_collision_flags_win_over_the_ellipse_at_the_same_step_and_later_ones_are_listed():
    traj = synthetic.trajectory(opposing=True)
    n = len(traj["t_s"])
    traj["collision_opp"] = np.zeros(n)
    traj["collision_opp"][120:] = 1.0
    traj["gap_opp_m"] = np.where(np.arange(n) >= 120, 0.0, 5.0)
    traj["collision_front"] = np.zeros(n)
    traj["collision_front"][200] = 1.0
    traj["h_front"] = np.where(np.arange(n) >= 120, -0.5, traj["h_front"])
    ev = first_unsafe_event(traj)
    assert (ev.constraint, ev.vehicle, ev.index, ev.margin) == ("collision_opp", "veh_o", 120, 0.0)
    assert ev.label() == f"collision with veh_o at {traj['t_s'][120]:.2f} s, gap 0.00 m"
    assert [c for c, _ in ev.later] == ["ellipse", "collision_front"]
    assert ev.then().startswith("then ellipse violated at")


def test_without_flags_a_non_positive_gap_is_a_collision_and_nan_never_is():
    traj = synthetic.trajectory(opposing=True)
    n = len(traj["t_s"])
    traj["gap_front_m"] = np.where(np.arange(n) == 300, -0.0, 1.0)
    traj["gap_opp_m"] = np.full(n, np.nan)  # veh_o never measured
    masks = violations(traj)
    assert not masks["collision_opp"].any() and masks["collision_front"].sum() == 1
    ev = first_unsafe_event(traj)
    assert (ev.constraint, ev.index) == ("collision_front", 300)
    assert ev.label() == f"collision with veh_f at {traj['t_s'][300]:.2f} s, gap 0.00 m"


def test_a_barrier_value_that_would_read_minus_zero_keeps_two_digits():
    traj = synthetic.trajectory(opposing=False)
    traj["h_front"] = np.where(np.arange(len(traj["t_s"])) >= 10, -2.3e-5, 1.0)
    assert "h_ef = -2.3e-05 at" in first_unsafe_event(traj).label()


def test_road_panel_is_to_scale_with_true_footprints_names_and_the_event_marked():
    traj = synthetic.trajectory(opposing=False, went_back=True)
    p = figure_common.params_dict(None)
    ev = first_unsafe_event(traj)
    fig, ax = plt.subplots()
    road_panels.road_panel(ax, traj, synthetic.plans(traj, opposing=False), p, ev.t_s, 60.0, 80.0, event=ev)
    fig.canvas.draw()
    assert ax.get_aspect() == 1.0  # metres are metres
    length, width = p["geometry"]["length_m"], p["geometry"]["width_m"]
    boxes = [pa for pa in ax.patches if isinstance(pa, matplotlib.patches.Polygon)]
    assert len(boxes) == 2  # ego and veh_f (no veh_o)
    front = boxes[0].get_xy()
    assert math.isclose(np.ptp(front[:, 0]), length) and math.isclose(np.ptp(front[:, 1]), width)
    texts = [t.get_text() for t in ax.texts]
    assert {"ego", "veh_f"} <= set(texts)
    assert any(t.startswith("first unsafe: ellipse h_ef = ") for t in texts)
    assert ax.spines["top"].get_edgecolor() == matplotlib.colors.to_rgba(road_panels.UNSAFE)
    plt.close(fig)


def test_snapshots_and_the_replay_figure_add_the_unsafe_moment(tmp_path):
    safe = synthetic.trajectory(opposing=True)
    unsafe = synthetic.trajectory(opposing=True, went_back=True)
    a = episode_figures.snapshots(safe, synthetic.plans(safe), None, tmp_path / "a.png", title="safe")
    b = episode_figures.snapshots(unsafe, synthetic.plans(unsafe), None, tmp_path / "b.png", title="unsafe")
    assert (a["axes"], b["axes"]) == (5, 6)  # one more panel: the first unsafe moment
    assert b["height_px"] > a["height_px"]
    over = episode_figures.episode_overview(unsafe, None, 0.3, tmp_path / "o.png", title="o",
                                            plans=synthetic.plans(unsafe))
    assert over["axes"] == 5 + 2  # four moments + the unsafe one, then h_ef(t) and the speeds


def test_a_moment_gets_its_own_panel_in_both_figures(tmp_path):
    safe = synthetic.trajectory(opposing=True)
    plans = synthetic.plans(safe)
    last = float(safe["t_s"][-1])
    a = episode_figures.snapshots(safe, plans, None, tmp_path / "a.png", title="safe", moment=last)
    assert a["axes"] == 5 + 1  # the moment (e.g. a counterexample's first violation) as one more panel
    over = episode_figures.episode_overview(safe, None, 0.3, tmp_path / "o.png", title="o", plans=plans,
                                            moment=last)
    assert over["axes"] == 4 + 1 + 2
