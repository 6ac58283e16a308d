"""mcverify.analysis.summary: per-cell statistics from an episode table (synthetic, no simulation)."""

from __future__ import annotations

import json
import math

import numpy as np
import pyarrow as pa
import pytest
import synthetic

from mcverify.analysis import stats, summary
from mcverify.analysis.cells import cells_table, json_ready
from mcverify.campaign.spec import campaign_from_dict


def _table(**cols) -> pa.Table:
    return pa.table(cols)


def test_rates_counts_intervals_and_zero_event_bounds():
    n = 30
    t = _table(
        cell=["a"] * n, cell_index=[0] * n, outcome=["overtook"] * 20 + ["went_back"] * 10,
        safe=[True] * 27 + [False] * 3, collision_front=[False] * 30, ellipse_violation=[False] * 27 + [True] * 3,
        min_dist_front_m=np.linspace(-0.2, 1.0, n),
    )
    s = summary.summarise(t)
    c = s["cells"][0]
    assert (c["episodes"], c["valid"], c["outcomes"]) == (30, 30, {"overtook": 20, "went_back": 10, "timeout": 0,
                                                                    "stopped": 0, "error": 0})
    assert c["rates"]["safe"] == stats.rate_summary(27, 30)
    assert c["rates"]["overtook"]["k"] == 20 and c["rates"]["went_back"]["k"] == 10
    # zero-failure cell: the exact one-sided bound, 1 - 0.05^(1/30) = 0.0950
    col = c["rates"]["collision_front"]
    assert col["k"] == 0 and col["upper_one_sided"] == pytest.approx(1 - 0.05 ** (1 / 30), rel=1e-12)
    assert c["rates"]["collision"] == col  # without an opposing vehicle, collision = collision with veh_f
    assert "collision_opp" not in c["rates"] and "min_gap_opp_m" not in c["values"]  # absent, not invented
    v = c["values"]["min_dist_front_m"]
    assert (v["count"], v["min"], v["max"]) == (30, pytest.approx(-0.2), pytest.approx(1.0))
    assert v["mean_low"] < v["mean"] < v["mean_high"]
    assert v["quantiles"]["q50"] == pytest.approx(0.4)


def test_error_episodes_are_counted_apart():
    t = _table(
        cell=["a"] * 5, cell_index=[0] * 5, outcome=["overtook", "error", "went_back", "error", "overtook"],
        safe=[True, False, True, False, False], collision_front=[False, False, False, False, True],
        collision_opp=[False, False, False, False, False], ellipse_violation=[False, False, False, False, True],
        min_dist_front_m=[1.0, math.nan, 0.5, math.nan, -0.1],
    )
    c = summary.summarise(t)["cells"][0]
    assert (c["episodes"], c["valid"]) == (5, 3)
    assert (c["rates"]["safe"]["k"], c["rates"]["safe"]["n"]) == (2, 3)  # errors are not unsafe episodes
    assert (c["rates"]["error"]["k"], c["rates"]["error"]["n"]) == (2, 5)
    assert c["rates"]["collision"]["k"] == 1 and c["rates"]["collision_opp"]["k"] == 0
    assert c["values"]["min_dist_front_m"]["count"] == 3


def test_collision_is_either_vehicle():
    t = _table(cell=["a"] * 4, cell_index=[0] * 4, outcome=["overtook"] * 4,
               collision_front=[True, False, False, False], collision_opp=[False, True, False, True])
    c = summary.summarise(t)["cells"][0]
    assert c["rates"]["collision"]["k"] == 3


def test_manifest_supplies_labels_and_empty_cells():
    camp = campaign_from_dict({"campaign": {"name": "x", "seed": 1, "episodes": 4},
                               "grid": {"barrier.epsilon": [0.1, 0.3], "noise.scale": [1.0, 2.0]}})
    from mcverify.campaign import runner

    manifest = runner.manifest_for(camp, 4, {})
    rows = synthetic.episode_rows(camp.cells[0], 1, synthetic.default_probs(camp.cells[0]), opposing=False, crn=False)
    s = summary.summarise(pa.Table.from_pylist(rows), manifest)
    assert [c["cell_index"] for c in s["cells"]] == [0, 1, 2, 3]  # cells without rows are listed too
    assert s["cells"][0]["labels"] == {"epsilon": "0.1", "scale": "1"}
    assert s["axes"] == {"epsilon": ["0.1", "0.3"], "scale": ["1", "2"]}
    empty = s["cells"][3]
    assert empty["episodes"] == 0 and empty["episodes_planned"] == 4
    assert math.isnan(empty["rates"]["error"]["rate"])
    assert summary.axis_value(s["cells"][1], "scale") == 2.0
    assert summary.axis_value(s["cells"][2], "epsilon") == pytest.approx(0.3)


def test_summary_is_deterministic_and_options_apply():
    camp = campaign_from_dict({"campaign": {"name": "x", "seed": 2, "episodes": 40}})
    t = pa.Table.from_pylist(synthetic.episode_rows(camp.cells[0], 2, {"unsafe": 0.2, "overtook": 0.6,
                                                                       "went_back": 0.3}, opposing=True, crn=False))
    a, b = summary.summarise(t), summary.summarise(t)
    assert json.dumps(json_ready(a)) == json.dumps(json_ready(b))
    w = summary.summarise(t, level=0.9, method="wilson", bootstrap_resamples=50)
    r = w["cells"][0]["rates"]["safe"]
    assert (r["method"], r["level"]) == ("wilson", 0.9)
    ci = stats.proportion_interval(r["k"], r["n"], 0.9, "wilson")
    assert (r["low"], r["high"]) == (ci.low, ci.high)
    with pytest.raises(ValueError, match="method must be one of"):
        summary.summarise(t, method="wald")


def test_coverage_through_summarise():
    # Acceptance: a synthetic Bernoulli source of known p; the intervals summarise stores cover p
    # in >= 93 % of 1,000 repetitions (here: 1,000 cells of one table, so the whole pipeline
    # from episode flags to stored interval is exercised). n = 100 episodes per cell for p = 0.5
    # and p = 0.03 (n p = 3, few events), n = 1000 for p = 0.001 (n p = 1).
    for p, n in ((0.5, 100), (0.03, 100), (0.001, 1000)):
        reps = 1000
        rng = np.random.default_rng(int(p * 1e6) + n)
        event = rng.random(reps * n) < p
        t = _table(cell_index=np.repeat(np.arange(reps), n), cell=np.repeat(np.arange(reps), n).astype(str),
                   outcome=np.full(reps * n, "overtook"), collision_front=event)
        cells = summary.summarise(t, bootstrap_resamples=1)["cells"]
        covered = np.mean([c["rates"]["collision_front"]["low"] <= p <= c["rates"]["collision_front"]["high"]
                           for c in cells])
        assert covered >= 0.93, (p, n, covered)
        one_sided = np.mean([p <= c["rates"]["collision_front"]["upper_one_sided"] for c in cells])
        assert one_sided >= 0.93, (p, n, one_sided)


def test_cells_table_is_flat_and_null_for_missing():
    camp = campaign_from_dict({"campaign": {"name": "x", "seed": 1, "episodes": 5},
                               "grid": {"barrier.epsilon": [0.1, 0.3]}})
    from mcverify.campaign import runner

    rows = []
    for cell in camp.cells:
        rows += synthetic.episode_rows(cell, 1, {"unsafe": 0.0, "overtook": 0.0, "went_back": 1.0}, opposing=False,
                                       crn=False)
    s = summary.summarise(pa.Table.from_pylist(rows), runner.manifest_for(camp, 4, {}))
    t = cells_table(s)
    assert t.num_rows == 2
    assert t.column("cell").to_pylist() == ["epsilon=0.1", "epsilon=0.3"]
    assert t.column("label_epsilon").to_pylist() == ["0.1", "0.3"]
    assert t.column("safe_k").to_pylist() == [5, 5]
    assert t.column("safe_lower_one_sided").to_pylist() == pytest.approx([0.05 ** (1 / 5)] * 2)
    # no overtake in either cell: the overtake-time statistics are nulls, not NaN or 0
    assert t.column("overtake_time_s_count").to_pylist() == [0, 0]
    assert t.column("overtake_time_s_mean").to_pylist() == [None, None]
    strict = json.dumps(json_ready(s), allow_nan=False)  # strict JSON: no NaN anywhere
    assert "overtake_time_s" in strict


def test_theorem_checks_counts_and_solver():
    t = _table(
        cell=["a"] * 4, cell_index=[0] * 4, outcome=["overtook", "went_back", "went_back", "error"],
        safe=[True, False, True, False], both_infeasible_steps=[0, 3, 0, 9], fallback_steps=[0, 2, 1, 9],
        held_steps=[0, 4, 0, 0], invariance_breach=[False, True, False, False],
        first_unsafe_cause=["", "held", "", "fallback"], went_back_reason=["", "q1_not_solved", "table_one_row_3", ""],
        table_one_rows=['{"1": 10}', '{"1": 5, "3": 2}', '{"3": 1}', "{}"], solves=[10, 20, 30, 5],
        cold_retries=[0, 1, 2, 7], iterations_mean=[10.0, 20.0, 30.0, 5.0], iterations_max=[12, 40, 33, 5],
        solver_statuses=['{"Solve_Succeeded": 10}', '{"Solve_Succeeded": 18, "Infeasible_Problem_Detected": 2}',
                         '{"Solve_Succeeded": 30}', "{}"],
    )
    c = summary.summarise(t)["cells"][0]  # the error episode is left out of everything below
    assert c["theorem_checks"] == {
        "invariance_breaches": 1, "episodes_with_both_infeasible": 1, "both_infeasible_steps": 3,
        "episodes_with_fallback": 2, "fallback_steps": 3, "episodes_with_held": 1, "held_steps": 4}
    assert c["counts"] == {"first_unsafe_cause": {"held": 1},
                           "went_back_reason": {"q1_not_solved": 1, "table_one_row_3": 1},
                           "table_one_rows": {"1": 15, "3": 3}}
    assert c["solver"]["solves"] == 60 and c["solver"]["cold_retries"] == 3
    assert c["solver"]["iterations_mean"] == pytest.approx((100 + 400 + 900) / 60)
    assert c["solver"]["statuses"] == {"Infeasible_Problem_Detected": 2, "Solve_Succeeded": 58}
    cells = cells_table(summary.summarise(t))
    assert json.loads(cells.column("count_went_back_reason")[0].as_py()) == {"q1_not_solved": 1,
                                                                             "table_one_row_3": 1}
    assert cells.column("thm_held_steps").to_pylist() == [4]


def test_opposing_metrics_are_left_out_of_cells_without_an_opposing_vehicle():
    # the rollout writes collision_opp = False and NaN gaps when there is no opposing vehicle
    t = _table(cell=["a", "a", "b", "b"], cell_index=[0, 0, 1, 1], outcome=["overtook"] * 4,
               opposing_kind=["none", "none", "human", "human"], collision_front=[False] * 4,
               collision_opp=[False, False, True, False], min_gap_opp_m=[np.nan, np.nan, 0.0, 30.0],
               opp_invariance_breach=[False] * 4)
    none, human = summary.summarise(t)["cells"]
    assert none["opposing_kind"] == "none" and human["opposing_kind"] == "human"
    assert "collision_opp" not in none["rates"] and "min_gap_opp_m" not in none["values"]
    assert "opp_invariance_breaches" not in none["theorem_checks"]
    assert human["rates"]["collision_opp"]["k"] == 1 and human["values"]["min_gap_opp_m"]["min"] == 0.0
    assert human["rates"]["collision"]["k"] == 1 and none["rates"]["collision"]["k"] == 0


def test_theorem_five_split_and_findings():
    t = _table(
        cell=["a"] * 4, cell_index=[0] * 4, episode_id=[7, 5, 6, 8], cell_episode=[2, 0, 1, 3],
        outcome=["overtook", "went_back", "overtook", "error"],
        both_infeasible_steps=[4, 0, 1, 9], both_certified_infeasible_steps=[1, 0, 0, 9],
        both_unsolved_uncertified_steps=[3, 0, 1, 0], both_infeasible_longest_run=[3, 0, 1, 9],
        q1_fail_certified_steps=[1, 2, 0, 0], q1_fail_presumed_steps=[0, 1, 0, 0],
        q1_fail_iteration_limit_steps=[5, 0, 1, 0], q1_fail_other_steps=[0, 0, 2, 0], q1_held_steps=[2, 0, 3, 0],
        went_back_q1_failure=["", "certified_infeasible", "", ""],
    )
    c = summary.summarise(t)["cells"][0]  # the error episode is left out
    assert c["theorem_checks"] == {
        "episodes_with_both_infeasible": 2, "both_infeasible_steps": 5, "episodes_with_both_certified": 1,
        "both_certified_infeasible_steps": 1, "both_unsolved_uncertified_steps": 4, "both_infeasible_longest_run": 3,
        "q1_fail_certified_steps": 3, "q1_fail_presumed_steps": 1, "q1_fail_iteration_limit_steps": 6,
        "q1_fail_other_steps": 2, "q1_held_steps": 5}
    assert c["theorem_findings"] == [  # every episode with such steps, in episode order
        {"episode_id": 6, "cell_episode": 1, "both_infeasible_steps": 1, "both_certified_infeasible_steps": 0,
         "both_unsolved_uncertified_steps": 1, "both_infeasible_longest_run": 1},
        {"episode_id": 7, "cell_episode": 2, "both_infeasible_steps": 4, "both_certified_infeasible_steps": 1,
         "both_unsolved_uncertified_steps": 3, "both_infeasible_longest_run": 3},
    ]
    assert c["counts"]["went_back_q1_failure"] == {"certified_infeasible": 1}
    cells = cells_table(summary.summarise(t))
    assert cells.column("thm_both_infeasible_longest_run").to_pylist() == [3]


def test_a_64_bit_seed_above_2_53_does_not_break_the_summary():
    """Campaign seeds may be any non-negative int64; Arrow's checked cast to float64 refused those
    above 2**53 and the report crashed after every episode had run."""
    big = 2**63 - 5
    t = _table(
        cell=["a"] * 2, cell_index=[0] * 2, seed=pa.array([big, big], pa.int64()),
        cell_episode=pa.array([0, 1], pa.int64()), outcome=["overtook"] * 2, safe=[True, False],
        collision_front=[False, True], ellipse_violation=[False, False], min_dist_front_m=[1.0, 0.0],
    )
    c = summary.summarise(t)["cells"][0]
    assert (c["rates"]["safe"]["k"], c["rates"]["safe"]["n"]) == (1, 2)


def test_episodes_stopped_at_a_violation_are_counted_as_their_own_outcome():
    """A falsification search ends episodes at their first violation (outcome "stopped")."""
    t = _table(
        cell=["a"] * 3, cell_index=[0] * 3, outcome=["stopped", "stopped", "overtook"],
        safe=[False, False, True], collision_front=[True, False, False], ellipse_violation=[False, True, False],
        min_dist_front_m=[0.0, -0.1, 0.8],
    )
    c = summary.summarise(t)["cells"][0]
    assert c["outcomes"] == {"overtook": 1, "went_back": 0, "timeout": 0, "stopped": 2, "error": 0}
    assert (c["rates"]["safe"]["k"], c["rates"]["safe"]["n"]) == (1, 3)
