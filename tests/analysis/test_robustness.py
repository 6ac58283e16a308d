"""Signed robustness on constructed episode rows: negative iff the requirement is violated."""

from __future__ import annotations

import math

import pytest

from mcverify.analysis import robustness as rb


def _row(**over):
    row = {
        "outcome": "overtook", "error_message": None, "opposing_kind": "human",
        "collision_front": False, "collision_opp": False,
        "min_gap_front_m": 0.8, "min_gap_opp_any_m": 40.0, "min_h_front": 0.35, "h0_front": 2.0,
        "epsilon": 0.3, "min_h_opp": 12.0, "both_infeasible_steps": 0, "both_certified_infeasible_steps": 0,
    }
    row.update(over)
    return row


def test_a_clean_episode_satisfies_every_requirement():
    row = _row()
    for name in rb.REQUIREMENTS:
        assert rb.robustness(row, name) >= 0.0, name
    assert rb.robustness(row, "collision_front") == pytest.approx(0.8)
    assert rb.robustness(row, "invariance") == pytest.approx(0.05)
    assert rb.robustness(row, "safe") == pytest.approx(0.35)


@pytest.mark.parametrize(
    ("name", "over"),
    [
        ("collision_front", {"collision_front": True, "min_gap_front_m": 0.0}),
        ("collision_opp", {"collision_opp": True, "min_gap_opp_any_m": 0.0}),
        ("ellipse", {"min_h_front": -0.01}),
        ("invariance", {"min_h_front": 0.29}),
        ("h_eo", {"min_h_opp": -3.0}),
        ("theorem5", {"both_infeasible_steps": 4}),
        ("theorem5_certified", {"both_certified_infeasible_steps": 1, "both_infeasible_steps": 1}),
    ],
)
def test_each_violation_is_negative_and_only_its_own(name, over):
    row = _row(**over)
    assert rb.robustness(row, name) < 0.0
    assert bool(rb.violated([row], name)[0])
    # The composite "safe" is violated exactly when one of its members is.
    assert (rb.robustness(row, "safe") < 0.0) == (name in rb.SAFE_SET)
    # Implied violations: h_ef < 0 is below the level too; a certified step is a step with neither solved.
    implied = {"ellipse": {"invariance"}, "theorem5_certified": {"theorem5"}}.get(name, set())
    others = [n for n in rb.REQUIREMENTS if n not in {name, "safe", *implied}]
    assert all(rb.robustness(row, n) >= 0.0 for n in others), others


def test_theorem5_counts_steps_and_certified_apart():
    row = _row(both_infeasible_steps=7, both_certified_infeasible_steps=0)
    assert rb.robustness(row, "theorem5") == -7.0
    assert rb.robustness(row, "theorem5_certified") == rb.THEOREM5_SATISFIED


def test_not_applicable_requirements_are_plus_infinity():
    no_opp = _row(opposing_kind="none", min_gap_opp_any_m=math.nan, min_h_opp=math.nan)
    assert rb.robustness(no_opp, "collision_opp") == math.inf
    assert rb.robustness(no_opp, "h_eo") == math.inf
    below_level_at_start = _row(h0_front=0.1, min_h_front=0.05)
    assert rb.robustness(below_level_at_start, "invariance") == math.inf


def test_min_over_a_set_and_error_rows():
    row = _row(min_h_front=0.2, min_h_opp=-1.5)
    assert rb.min_robustness(row, ["ellipse", "h_eo"]) == -1.5
    err = _row(outcome="error", error_message="boom")
    assert math.isnan(rb.robustness(err, "safe"))
    assert not rb.violated([err], "safe")[0]
    with pytest.raises(ValueError, match="unknown requirement"):
        rb.robustness(row, "nope")

