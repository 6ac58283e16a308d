"""The registry of requirements, targets and scores (mcverify.requirements): complete and used by every layer."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mcverify import model, requirements
from mcverify.analysis import estimates
from mcverify.analysis import robustness as rb
from mcverify.requirements import REQUIREMENTS, SCORES, STEPWISE, TARGETS, StopInputs
from mcverify.schema import COLUMN_NAMES


def test_every_requirement_has_one_robustness_and_every_per_step_one_a_signal():
    assert list(rb.ROBUSTNESS) == list(REQUIREMENTS)
    assert list(rb.SIGNALS) == list(STEPWISE)
    assert STEPWISE == tuple(name for name, r in REQUIREMENTS.items() if r.stepwise)


def test_the_model_and_the_analysis_read_the_registry():
    assert model.REQUIREMENT_NAMES == requirements.REQUIREMENT_NAMES == tuple(rb.REQUIREMENTS)
    assert model.GUIDE_NAMES == requirements.GUIDE_NAMES == rb.GUIDES
    assert list(estimates.TARGETS) == list(TARGETS)
    assert all(estimates.TARGETS[n] == t.definition for n, t in TARGETS.items())


def test_what_the_registry_says_it_reads_is_stored():
    for r in REQUIREMENTS.values():
        assert set(r.columns) <= set(COLUMN_NAMES), r.name
        assert not r.target or r.name in TARGETS[r.target].requirements, r.name
    for t in TARGETS.values():
        assert set(t.flags) <= set(COLUMN_NAMES), t.name
        assert set(t.requirements) <= set(REQUIREMENTS), t.name
        assert not t.negated or len(t.flags) == 1
    assert set(SCORES.values()) <= set(TARGETS)
    assert requirements.SCORED_TARGETS == ("collision", "ellipse")  # in TARGETS order
    assert requirements.default_score("collision") == "gap" and requirements.default_score("ellipse") == "h_ef"


def test_a_per_step_signal_reads_only_its_step_columns():
    """Each per-step requirement's signal works on a trajectory holding exactly its step columns."""
    for name in STEPWISE:
        traj = {c: np.array([0.5, -0.2, 0.3]) for c in REQUIREMENTS[name].step_columns}
        assert rb.SIGNALS[name](traj, 0.3, 0.9).shape == (3,), name


def _episode(*, gap_front=1.0, hit_front=False, gap_opp=5.0, hit_opp=False, min_h=0.5, h0=0.9, eps=0.3,
             min_h_opp=2.0, unsolved=0, certified=0, opp="human"):
    """One episode as the rollout's stop test sees it and as its stored row reads."""
    inputs = StopInputs(np.array([hit_front]), np.array([hit_opp]), np.array([min_h]), np.array([min_h_opp]),
                        np.array([unsolved]), np.array([certified]), np.array([h0]), eps, opp != "none")
    row = {"min_gap_front_m": 0.0 if hit_front else gap_front, "collision_front": hit_front,
           "min_gap_opp_any_m": 0.0 if hit_opp else gap_opp, "collision_opp": hit_opp, "opposing_kind": opp,
           "min_h_front": min_h, "h0_front": h0, "epsilon": eps, "min_h_opp": min_h_opp,
           "both_infeasible_steps": unsolved, "both_certified_infeasible_steps": certified, "outcome": "overtook"}
    return inputs, row


@pytest.mark.parametrize("case", [
    {}, {"hit_front": True}, {"hit_opp": True}, {"hit_opp": True, "opp": "none"}, {"min_h": -0.1},
    {"min_h": 0.2}, {"min_h": 0.2, "h0": 0.1}, {"min_h_opp": -0.5}, {"min_h_opp": -0.5, "opp": "none"},
    {"unsolved": 3}, {"unsolved": 3, "certified": 1},
])
def test_every_stop_mask_agrees_with_the_sign_of_its_robustness(case):
    inputs, row = _episode(**case)
    if row["opposing_kind"] == "none":
        row["min_h_opp"] = math.nan  # what the rollout stores without veh_o
    for name, req in REQUIREMENTS.items():
        assert bool(req.stop(inputs)[0]) == (rb.robustness(row, name) < 0.0), (name, case)


def test_an_unknown_name_is_refused_with_the_known_ones():
    with pytest.raises(ValueError, match="unknown requirement 'nope'; known: collision_front, "):
        requirements.requirement("nope")
    assert requirements.requirement_help().endswith(
        "theorem5_certified, safe or stl:<formula> (STL over the stored signals)")
    assert all(f"{name} (target {target})" in requirements.score_help() for name, target in SCORES.items())


@pytest.mark.parametrize(("value", "margin", "expected"), [
    (0.3, 0.2, 0.3), (0.3, -0.1, 0.15), (-0.06, -0.5, -0.01), (0.3, float("nan"), 0.3), (0.0, -1.0, 0.0),
])
def test_the_margin_ladder_keeps_the_sign_and_divides_by_the_depth_below_0(value, margin, expected):
    assert requirements.margin_ladder(value, margin) == pytest.approx(expected, abs=1e-15)
