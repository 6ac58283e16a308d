"""The closed loop (mcverify.episode.rollout): chunk independence, Theorem 2 on noise-free episodes, opposing
traffic end to end, scenario draws."""

from __future__ import annotations

import dataclasses
import math

import jax
import numpy as np
import pytest

from mcverify.campaign import executors
from mcverify.campaign.spec import campaign_from_dict, load_campaign
from mcverify.episode.draws import episode_key, sample_scenario
from mcverify.episode.rollout import run_episodes
from mcverify.schema import COLUMN_NAMES, ERROR_COLUMN, TIMING_COLUMNS

FAST_SIM = {"control_period_s": 0.1, "substeps": 20}


def cell_of(model: dict, *, episodes: int = 3, seed: int = 11):
    camp = campaign_from_dict({"campaign": {"name": "t", "seed": seed, "episodes": episodes}, "model": model})
    return camp, camp.cells[0]


def strip(row: dict) -> dict:
    return {k: v for k, v in row.items() if k not in TIMING_COLUMNS}


def same(a: dict, b: dict) -> bool:
    return all(
        (isinstance(a[k], float) and math.isnan(a[k]) and math.isnan(b[k])) or a[k] == b[k] for k in a
    ) and a.keys() == b.keys()


def test_an_episode_does_not_depend_on_its_chunk():
    """The same episode alone, first, last or with others gives bit-identical rows (every column but
    the wall-clock solve times): the plant runs in fixed lane groups, the solver per episode."""
    camp, cell = cell_of({"sim": {**FAST_SIM, "max_time_s": 3.0}})
    planner = executors.solver_for(cell.params)
    together = {r["cell_episode"]: strip(r) for r in run_episodes(cell, [0, 1, 2], camp.seed, planner).rows}
    for ids in ([1], [2, 0]):
        for r in run_episodes(cell, ids, camp.seed, planner).rows:
            assert same(strip(r), together[r["cell_episode"]]), r["cell_episode"]
    assert len({r["min_h_front"] for r in together.values()}) == 3  # different noise, different episodes


def test_rows_have_the_declared_columns_in_file_order_and_recordings_their_tables():
    camp, cell = cell_of({"sim": {**FAST_SIM, "max_time_s": 1.0}}, episodes=1)
    result = run_episodes(cell, [0], camp.seed, executors.solver_for(cell.params), record=True)
    assert tuple(result.rows[0]) == tuple(n for n in COLUMN_NAMES if n != ERROR_COLUMN)
    recording = result.recordings[0]
    steps = recording.trajectory["t_s"].size
    assert steps > 0 and all(col.shape == (steps,) for col in recording.trajectory.values())
    assert recording.plans is not None and set(recording.to_columns()) == {"", "-plans"}


@pytest.mark.parametrize("front_kmh", [25, 36])
def test_noise_free_episode_keeps_the_vlcbf_level_set(front_kmh):
    """Theorem 2 (thm.VL-CBF_levelset) on the paper's Table II set-up at 50 Hz without noise: h_ef
    starts above eps = 0.3 and stays >= eps at every integration sub-step; the overtake completes."""
    camp = load_campaign("campaigns/table2.toml", episodes=1)
    cell = next(c for c in camp.cells if c.name == f"front_speed_kmh={front_kmh}")
    p = cell.params
    cell = dataclasses.replace(cell, params=dataclasses.replace(p, noise=dataclasses.replace(p.noise, kind="none")))
    row = run_episodes(cell, [0], camp.seed, executors.solver_for(cell.params)).rows[0]
    assert row["h0_front"] > cell.epsilon
    assert not row["invariance_breach"] and row["min_h_front"] >= cell.epsilon
    assert row["outcome"] == "overtook" and row["safe"]
    assert row["both_infeasible_steps"] == 0 and row["fallback_steps"] == 0


def test_scenario_draws_are_in_the_left_open_range_and_keyed():
    camp, cell = cell_of({"scenario": {"front_accel_range_mps2": [3.0, 5.0]}})
    draws = [sample_scenario(episode_key(7, 0, e), cell.params)["front_accel_mps2"] for e in range(400)]
    assert all(3.0 < d <= 5.0 for d in draws) and np.std(draws) > 0.4
    assert draws[17] == sample_scenario(episode_key(7, 0, 17), cell.params)["front_accel_mps2"]
    # common random numbers: the key (and so the draw) does not depend on the cell
    k_crn = episode_key(7, None, 17)
    assert jax.numpy.array_equal(k_crn, episode_key(7, None, 17))
    assert not jax.numpy.array_equal(episode_key(7, 0, 17), episode_key(7, 1, 17))


TABLE4_B = {"opposing": {"kind": "human", "x_m": 330.0, "speed_mps": 10.0},
            "scenario": {"front_speed_mps": 25 / 3.6}, "sim": FAST_SIM}
TABLE4_A = {"opposing": {"kind": "human", "x_m": 220.0, "speed_mps": 18.0},
            "scenario": {"front_speed_mps": 25 / 3.6}, "sim": FAST_SIM}


def test_vlcbf_with_a_human_opposing_driver_overtakes_safely():
    camp, cell = cell_of(TABLE4_B, episodes=1)
    row = run_episodes(cell, [0], camp.seed, executors.solver_for(cell.params)).rows[0]
    assert row["outcome"] == "overtook" and row["safe"], row
    assert row["opp_detected_steps"] > 0 and row["min_gap_opp_m"] > 0  # veh_o was seen while borrowing
    assert not row["collision_opp"] and row["min_h_front"] >= 0


@pytest.mark.slow  # two full opposing-traffic episodes, 72 s: the default suite was 9 min 50 s
def test_mpcdc_squeezes_in_where_vlcbf_declines():
    """Table IV Scenario A: veh_o too close and fast. The dual TO-CBF-MPC goes back at once (Table I);
    MPC-DC, with no Q2 and the ellipses only at its nodes, overtakes and leaves the safe set."""
    camp, cell = cell_of(TABLE4_A, episodes=1)
    vl = run_episodes(cell, [0], camp.seed, executors.solver_for(cell.params)).rows[0]
    assert vl["outcome"] == "went_back" and vl["safe"] and math.isnan(vl["min_gap_opp_m"])
    assert vl["first_unsafe_cause"] == "" and math.isnan(vl["first_unsafe_s"])
    camp, cell = cell_of({**TABLE4_A, "mpc": {"controller": "mpcdc"}}, episodes=1)
    dc = run_episodes(cell, [0], camp.seed, executors.solver_for(cell.params)).rows[0]
    assert dc["controller"] == "mpcdc" and not dc["safe"], dc
    assert dc["min_gap_opp_m"] < 5.0
    assert dc["first_unsafe_cause"] in ("planned", "held", "fallback") and dc["first_unsafe_s"] > 0


SETTLE_COLUMNS = ("settle_end_s", "conv_heading_rad", "conv_lateral_speed_mps", "conv_line_excess_m",
                  "end_heading_rad", "end_lateral_speed_mps", "end_line_excess_m", "settle_line_excess_max_m",
                  "settled_in_lane", "unsafe_in_settling")


@pytest.fixture(scope="module")
def settled():
    """Episodes 0 and 1 overtaking (goal test at about 6.7 s) with 3 s of settling, together and apart,
    and episode 0 without settling."""
    out = {}
    for settle_s, ids in ((3.0, [0, 1]), (3.0, [1]), (0.0, [0])):
        camp, cell = cell_of({"sim": {**FAST_SIM, "max_time_s": 12.0, "settle_s": settle_s}}, episodes=2)
        steps, reports = [-1], []  # the progress hook: (episode, unsafe, the last step run when it was told)
        rows = run_episodes(cell, ids, camp.seed, executors.solver_for(cell.params), on_step=steps.append,
                            on_episode=lambda e, unsafe, steps=steps, reports=reports:
                            reports.append((e, unsafe, steps[-1]))).rows
        out[settle_s, tuple(ids)] = {r["cell_episode"]: strip(r) for r in rows}
        out["reports", settle_s, tuple(ids)] = reports
    return out


def test_each_episode_is_reported_once_as_it_stops_with_its_row_safety(settled):
    """The rollout's on_episode hook (per-episode progress): once per episode, when its settling
    ends (well before the 12 s limit here), saying unsafe exactly when its row says not safe."""
    for key in ((3.0, (0, 1)), (0.0, (0,))):
        reports = settled[("reports", *key)]
        assert sorted(e for e, _, _ in reports) == list(key[1])
        rows = settled[key]
        for e, unsafe, step in reports:
            assert unsafe is (not rows[e]["safe"])
            stop_s = rows[e]["settle_end_s"]
            assert stop_s < 12.0 and step == pytest.approx(stop_s / FAST_SIM["control_period_s"], abs=1.01)


def test_settling_extends_the_checked_time_and_fills_the_end_state(settled):
    for e, row in settled[3.0, (0, 1)].items():
        assert row["outcome"] == "overtook", e
        assert row["settle_end_s"] == pytest.approx(row["end_time_s"] + 3.0)  # 3 s more of every check
        assert row["overtake_time_s"] == row["end_time_s"]  # the outcome and its time stay the goal test's
        assert row["conv_heading_rad"] < -0.05 and row["conv_lateral_speed_mps"] < -1.0  # still swerving at the goal
        assert abs(row["end_heading_rad"]) < 0.01 and abs(row["end_lateral_speed_mps"]) < 0.1  # settled
        assert row["end_line_excess_m"] == 0.0 and row["settle_line_excess_max_m"] >= row["conv_line_excess_m"] >= 0
        assert row["settled_in_lane"] and not row["unsafe_in_settling"]
        assert all(row[c] == row[c] for c in SETTLE_COLUMNS), e  # no NaN


def test_settling_does_not_change_the_decisions_and_settle_s_0_ends_at_the_goal_test(settled):
    """settle_s = 0 is the loop without settling (the campaign check compares it with rows from before
    settling existed); with settling only the safety and settling columns can differ."""
    with_settling, without = settled[3.0, (0, 1)][0], settled[0.0, (0,)][0]
    assert without["settle_end_s"] == without["end_time_s"]
    assert without["end_heading_rad"] == without["conv_heading_rad"]
    assert without["end_lateral_speed_mps"] == without["conv_lateral_speed_mps"]
    assert without["settle_line_excess_max_m"] == without["conv_line_excess_m"] == without["end_line_excess_m"]
    safety = {"collision_front", "collision_opp", "min_h_front", "min_dist_front_m", "min_gap_front_m",
              "min_gap_opp_m", "min_gap_opp_any_m", "min_h_opp", "ellipse_violation", "safe", "first_unsafe_s",
              "first_unsafe_cause", "invariance_breach", "invariance_margin", "opp_invariance_breach",
              "lane_borrow_time_s", *SETTLE_COLUMNS,
              # the ego's limits are checked over the settling period too
              "speed_excess_mps", "speed_excess_t_s", "accel_excess_mps2", "accel_excess_t_s", "slip_excess_rad",
              "slip_excess_t_s"}
    for k in without.keys() - safety:
        assert same({k: with_settling[k]}, {k: without[k]}), k
    for k in ("conv_heading_rad", "conv_lateral_speed_mps", "conv_line_excess_m"):
        assert with_settling[k] == without[k], k
    assert with_settling["min_h_front"] <= without["min_h_front"]  # the minima run over a longer time


def test_a_settling_episode_does_not_depend_on_its_chunk(settled):
    assert same(settled[3.0, (1,)][1], settled[3.0, (0, 1)][1])
