"""mcverify.reporting.paper_tables: the layouts of the paper's Tables II, III and IV beside our numbers."""

from __future__ import annotations

import math

import pyarrow as pa
import pytest
import synthetic

from mcverify.analysis import stats, summary
from mcverify.campaign import runner
from mcverify.campaign.spec import campaign_from_dict
from mcverify.reporting import paper_tables
from mcverify.reporting.tables import Section, to_latex, to_markdown


def _summary(raw, *, opposing=False, probs=synthetic.default_probs):
    camp = campaign_from_dict(raw)
    rows = []
    for cell in camp.cells:
        rows += synthetic.episode_rows(cell, camp.seed, probs(cell), opposing=opposing, crn=False)
    manifest = runner.manifest_for(camp, 8, {})
    return summary.summarise(pa.Table.from_pylist(rows), manifest, bootstrap_resamples=200), manifest


def _rows(table):
    return {row[0]: row[1:] for row in table.rows if not isinstance(row, Section)}


def test_table2_layout_with_gaps():
    raw = {
        "campaign": {"name": "t2", "seed": 1, "episodes": 30},
        "grid": {"scenario.front_speed_kmh": [25, 28]},
        "reference": {"table": "II", "source": "Yuan et al., Table II", "note": "two  clocks\n here",
                      "cells": {"front_speed_kmh=25": {"overtake_time_s.min": 4.13, "overtake_time_s.mean": 4.64},
                                "front_speed_kmh=28": {"overtake_time_s.min": 4.83,
                                                       "lane_borrow_time_s.mean": 5.02}}},
    }
    summ, manifest = _summary(raw)
    t = paper_tables.paper_table(summ, manifest["campaign"]["reference"])
    assert t.key == "paper-table-II" and t.columns == ["", "v_f = 25 km/h", "v_f = 28 km/h"]
    rows = _rows(t)
    c25 = summ["cells"][0]["values"]["overtake_time_s"]
    assert rows["min (s): ours"][0] == f"{c25['min']:.2f}"
    assert rows["min (s): paper"] == ["4.13", "4.83"]
    gap = c25["min"] - 4.13
    assert rows["min (s): ours − paper"][0] == f"{gap:+.2f} ({gap / 4.13:+.0%})"
    assert rows["mean (s): ours"][0].startswith(f"{c25['mean']:.2f} [")  # with its bootstrap interval
    assert rows["mean (s): paper"] == ["4.64", "–"]
    assert "max (s): paper" not in rows  # no paper value: only our row
    assert rows["lane-borrow time mean (s): paper"] == ["–", "5.02"]  # a reference quantity beyond the layout
    assert "two clocks here" in t.notes[-1] and "Paper: Yuan et al., Table II." in t.notes


def test_table3_counts_carry_intervals_and_newcombe_gaps():
    summ, manifest = _summary(synthetic.TABLE3, opposing=True)
    t = paper_tables.paper_table(summ, manifest["campaign"]["reference"])
    assert t.columns == ["", "α_f ∈ (1,3]", "α_f ∈ (3,5]", "α_f ∈ (5,7]"]
    rows = _rows(t)
    assert [r.split(":")[0] for r in rows][::3] == ["successful overtaking", "min dist. with veh_f (m)",
                                                    "min dist. with veh_o (m)", "safe episodes"]
    c = summ["cells"][1]
    k = c["rates"]["overtook"]["k"]
    lo, hi = c["rates"]["overtook"]["low"], c["rates"]["overtook"]["high"]
    assert rows["successful overtaking: ours"][1] == f"{k}/30 [{lo:.3f}, {hi:.3f}]"
    assert rows["successful overtaking: paper"] == ["29/30", "11/30", "0/30"]
    d = stats.compare_unpaired(k, 30, 11, 30)
    assert rows["successful overtaking: ours − paper"][1] == f"{d['diff']:+.3f} [{d['low']:+.3f}, {d['high']:+.3f}]"
    assert rows["safe episodes: ours"][0] == "30/30 (≥ 0.905)"
    assert rows["min dist. with veh_o (m): ours"][1] == f"{c['values']['min_gap_opp_m']['min']:.2f}"
    assert rows["min dist. with veh_o (m): paper"] == ["18.31", "5.52", "72.41"]


def test_table3_without_opposing_columns_says_not_measured():
    summ, manifest = _summary(synthetic.TABLE3, opposing=False)
    t = paper_tables.paper_table(summ, manifest["campaign"]["reference"])
    rows = _rows(t)
    assert rows["min dist. with veh_o (m): ours"] == ["–", "–", "–"]
    assert rows["min dist. with veh_o (m): ours − paper"] == ["–", "–", "–"]
    assert any("Not measured in this run: min_gap_opp_m" in n for n in t.notes)


def test_table4_blocks_per_scenario_and_methods_as_columns():
    summ, manifest = _summary(synthetic.TABLE4, opposing=True)
    t = paper_tables.paper_table(summ, manifest["campaign"]["reference"])
    assert t.columns == ["", "MPC-DC", "VL-CBF eps=0.3", "VL-CBF eps=0.5"]
    sections = [r.title for r in t.rows if isinstance(r, Section)]
    assert sections == ["Scenario A", "Scenario B"]
    first_block = t.rows[1:t.rows.index(next(r for r in t.rows[1:] if isinstance(r, Section)))]
    assert [r[0] for r in first_block][:3] == ["min dist. with veh_f (m): ours", "min dist. with veh_f (m): paper",
                                               "min dist. with veh_f (m): ours − paper"]
    assert first_block[1][1:] == ["-0.15", "0.76", "0.99"]
    assert first_block[7][1:] == ["0/30", "30/30", "30/30"]
    tex = to_latex(t)
    assert tex.count(r"\multicolumn{4}{l}{\emph{Scenario") == 2
    md = to_markdown(t)
    assert "| **Scenario B** |" in md


def test_reference_cell_missing_from_the_run_is_named():
    raw = {"campaign": {"name": "t", "seed": 1, "episodes": 3}, "grid": {"scenario.front_speed_kmh": [25]},
           "reference": {"table": "II", "cells": {"front_speed_kmh=25": {"overtake_time_s.min": 4.13},
                                                  "front_speed_kmh=36": {"overtake_time_s.min": 5.29}}}}
    summ, manifest = _summary(raw)
    t = paper_tables.paper_table(summ, manifest["campaign"]["reference"])
    assert t.columns[1:] == ["v_f = 25 km/h", "v_f = 36 km/h"]
    assert _rows(t)["min (s): ours"][1] == "–"
    assert any(n == "Not in this run: front_speed_kmh=36." for n in t.notes)


def test_unknown_layout_and_lookup():
    summ, _ = _summary({"campaign": {"name": "t", "seed": 1, "episodes": 3}})
    assert paper_tables.paper_table(summ, {"table": "IX"}) is None
    cell = summ["cells"][0]
    assert paper_tables.lookup(cell, "safe.k") == cell["rates"]["safe"]["k"]
    assert paper_tables.lookup(cell, "min_dist_front_m.q50") == cell["values"]["min_dist_front_m"]["quantiles"]["q50"]
    assert paper_tables.lookup(cell, "min_gap_opp_m.min") is None  # a known metric this run lacks
    with pytest.raises(KeyError, match="unknown reference quantity"):
        paper_tables.lookup(cell, "warp_speed.max")
    assert math.isnan(paper_tables.lookup(cell, "overtake_time_s.q99"))


def test_parse_cell_name_and_pretty_labels():
    assert paper_tables.parse_cell_name("front_accel_range_mps2=[1,3],method=VL-CBF eps=0.3") == {
        "front_accel_range_mps2": "[1,3]", "method": "VL-CBF eps=0.3"}
    assert paper_tables.pretty_label("front_accel_range_mps2", "[3,5]") == "α_f ∈ (3,5]"
    assert paper_tables.pretty_label("epsilon", "0.3") == "ε = 0.3"
    assert paper_tables.pretty_label("lambda0", "-0.3135") == "λ₀ = -0.3135"
    assert paper_tables.pretty_label("scale", "2") == "scale = 2"


def test_table4_shows_both_meanings_of_safe_and_the_eps_variant_beside_mpcdc():
    import copy

    raw = copy.deepcopy(synthetic.TABLE4)
    raw["axes"]["method"]["MPC-DC eps=0.3"] = {"mpc.controller": "mpcdc_eps", "barrier.epsilon": 0.3}
    raw["reference"]["cells"]["scenario=B,method=MPC-DC eps=0.3"] = {"safe.k": 19}
    summ, manifest = _summary(raw, opposing=True)
    t = paper_tables.paper_table(summ, manifest["campaign"]["reference"])
    assert t.columns == ["", "MPC-DC", "MPC-DC eps=0.3", "VL-CBF eps=0.3", "VL-CBF eps=0.5"]
    rows = _rows(t)  # the last block (Scenario B) wins for repeated labels
    by_name = {c["cell"]: c for c in summ["cells"]}
    for col, method in enumerate(["MPC-DC", "MPC-DC eps=0.3", "VL-CBF eps=0.3", "VL-CBF eps=0.5"]):
        c = by_name[f"scenario=B,method={method}"]
        safe, outside = c["rates"]["safe"], c["rates"]["outside_margin"]
        assert rows["safe cases (h_ef ≥ 0): ours"][col].startswith(f"{safe['k']}/{safe['n']}")
        assert rows["outside the ε margin (h_ef ≥ ε): ours"][col].startswith(f"{outside['k']}/{outside['n']}")
    assert rows["safe cases (h_ef ≥ 0): paper"][:2] == ["19/30", "19/30"]
    assert "outside the ε margin (h_ef ≥ ε): paper" not in rows  # the paper gives one count only
    assert any("Two meanings of safe" in n for n in t.notes)


def test_outside_margin_is_derived_from_the_margin_and_collisions():
    rows = [{"cell": "c", "cell_index": 0, "outcome": "overtook", "invariance_margin": m, "collision_front": cf,
             "collision_opp": False, "safe": True}
            for m, cf in ((0.1, False), (0.0, False), (-0.01, False), (0.2, True), (math.nan, False))]
    cell = summary.summarise(pa.Table.from_pylist(rows), bootstrap_resamples=10)["cells"][0]
    assert cell["rates"]["outside_margin"]["k"] == 2 and cell["rates"]["outside_margin"]["n"] == 5


def test_table2_shows_the_start_to_goal_lower_bounds():
    raw = {"campaign": {"name": "t2", "seed": 1, "episodes": 3}, "grid": {"scenario.front_speed_kmh": [25, 36]},
           "reference": {"table": "II", "cells": {"front_speed_kmh=25": {"overtake_time_s.mean": 4.64},
                                                  "front_speed_kmh=36": {"overtake_time_s.mean": 5.90}}}}
    summ, manifest = _summary(raw)
    t = paper_tables.paper_table(summ, manifest["campaign"]["reference"])
    rows = _rows(t)
    assert rows["start-to-goal lower bound, at the speed limit from t = 0 (s)"] == ["5.34", "7.66"]
    assert rows["start-to-goal lower bound, with the acceleration limit (s)"] == ["6.52", "9.23"]
    assert summ["cells"][0]["goal_time_bound_s"]["speed_limit"] == pytest.approx(5.339, abs=1e-3)
    assert any("Start-to-goal lower bound" in n for n in t.notes)
