"""Signed robustness on constructed episode rows: negative iff the requirement is violated."""

from __future__ import annotations

import math

import numpy as np
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
    assert rb.robustness(row, "safe") == pytest.approx(0.8 / rb.SAFE_GAP_SCALE_M)  # the gap, in h_ef units


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



# ----------------------------------------------------------------- when a violation begins

def _trajectory(h, gap=None, q1=None, q2=None, dt=0.01):
    """Sub-step columns at t = dt, 2 dt, ... (one sub-step per control step of ``dt``)."""
    n = len(h)
    nan = [math.nan] * n
    return {"t_s": np.arange(1, n + 1) * dt, "h_front": np.array(h, float),
            "gap_front_m": np.array(gap if gap is not None else [1.0] * n, float),
            "collision_front": np.array([0.0 if g is None or g > 0 else 1.0 for g in (gap or [1.0] * n)]),
            "gap_opp_m": np.array(nan), "collision_opp": np.zeros(n),
            "q1_solved": np.array(q1 if q1 is not None else [1.0] * n, float),
            "q2_solved": np.array(q2 if q2 is not None else [1.0] * n, float)}


def test_first_violation_is_the_first_substep_below_zero():
    traj = _trajectory([0.5, 0.2, -0.1, -0.3, 0.1])
    row = _row(min_h_front=-0.3)
    assert rb.first_violation_s(row, traj, "ellipse", control_period_s=0.01) == pytest.approx(0.03)
    assert rb.first_violation_s(row, traj, "safe", control_period_s=0.01) == pytest.approx(0.03)
    # invariance at eps 0.3: h < 0.3 first at the second sub-step
    assert rb.first_violation_s(_row(min_h_front=-0.3, epsilon=0.3), traj, "invariance",
                                control_period_s=0.01) == pytest.approx(0.02)
    # a requirement the episode keeps: NaN
    assert math.isnan(rb.first_violation_s(row, traj, "collision_front", control_period_s=0.01))


def test_first_violation_of_a_collision_is_the_first_contact():
    traj = _trajectory([0.5, 0.4, 0.3, 0.3], gap=[0.8, 0.2, 0.0, 0.0])
    row = _row(min_gap_front_m=0.0, collision_front=True)
    assert rb.first_violation_s(row, traj, "collision_front", control_period_s=0.01) == pytest.approx(0.03)


def test_first_violation_of_theorem5_is_the_first_step_with_neither_solved():
    # step 2: Q1 failed, Q2 solved (fine); step 3: Q1 not attempted (NaN, going back) and Q2 failed
    traj = _trajectory([1.0] * 5, q1=[1, 0, math.nan, 0, 1], q2=[1, 1, 0, 0, 1])
    row = _row(both_infeasible_steps=2, both_certified_infeasible_steps=1)
    assert rb.first_violation_s(row, traj, "theorem5", control_period_s=0.01) == pytest.approx(0.03)
    # a trajectory recorded before `both_certified` existed: located only through a stop at that requirement
    assert math.isnan(rb.first_violation_s(row, traj, "theorem5_certified", control_period_s=0.01))
    # with the per-step certificate column: the first step at which both failures were certificates
    certified = dict(traj, both_certified=np.array([0.0, 0.0, 0.0, 1.0, 0.0]))
    assert rb.first_violation_s(row, certified, "theorem5_certified", control_period_s=0.01) == pytest.approx(0.04)
    stopped = _row(both_infeasible_steps=1, both_certified_infeasible_steps=1, stopped_at_violation=True)
    two_substeps = {k: np.repeat(v, 2) for k, v in _trajectory([1.0] * 3).items()}
    two_substeps["t_s"] = np.arange(1, 7) * 0.005  # control period 0.01 s, 2 sub-steps
    assert rb.first_violation_s(stopped, two_substeps, "theorem5_certified", control_period_s=0.01,
                                stopped_at="theorem5_certified") == pytest.approx(0.025)
    assert math.isnan(rb.first_violation_s(stopped, two_substeps, "theorem5_certified", control_period_s=0.01,
                                           stopped_at="ellipse"))


def test_first_violation_without_a_trajectory():
    row = _row(min_h_front=-0.2, safe=False, first_unsafe_s=4.2)
    assert rb.first_violation_s(row, None, "safe", control_period_s=0.02) == 4.2
    assert math.isnan(rb.first_violation_s(row, None, "ellipse", control_period_s=0.02))
    # a trajectory without the columns a requirement reads counts as none
    bare = {"t_s": np.array([0.01, 0.02])}
    assert math.isnan(rb.first_violation_s(row, bare, "ellipse", control_period_s=0.02))
    assert rb.first_violation_s(row, bare, "safe", control_period_s=0.02) == 4.2


def test_safe_is_the_same_event_in_one_unit():
    """``safe`` = min(gaps / SAFE_GAP_SCALE_M, h_ef): the sign of the unscaled minimum (the same event),
    and the scale is half the default ellipse semi-axis a."""
    from mcverify.model import ModelParams  # noqa: PLC0415 - the analysis layer does not import the model

    assert rb.SAFE_GAP_SCALE_M == 0.5 * ModelParams().barrier.ellipse_a_m
    rng = np.random.default_rng(0)
    for gap_f, gap_o, h in rng.uniform(-0.5, 3.0, size=(200, 3)):
        row = _row(min_gap_front_m=max(gap_f, 0.0), collision_front=gap_f < 0, min_gap_opp_any_m=max(gap_o, 0.0),
                   collision_opp=gap_o < 0, min_h_front=h)
        unscaled = min(rb.robustness(row, n) for n in rb.SAFE_SET)
        assert (rb.robustness(row, "safe") < 0.0) == (unscaled < 0.0)
    # a 0.5 m gap is closer to touching than h_ef = 0.3 is to the ellipse, once both are in h_ef's unit
    assert rb.robustness(_row(min_gap_front_m=0.5, min_h_front=0.3), "safe") == pytest.approx(0.5 / rb.SAFE_GAP_SCALE_M)
    assert rb.robustness(_row(min_gap_front_m=2.0, min_h_front=0.3), "safe") == 0.3


def test_theorem5_reads_the_graded_margin_and_falls_back_to_the_count():
    assert rb.robustness(_row(theorem5_margin=0.02), "theorem5") == 0.02
    assert rb.robustness(_row(theorem5_margin=-0.4, both_infeasible_steps=2), "theorem5") == -0.4
    assert rb.robustness(_row(theorem5_margin=math.nan, both_infeasible_steps=3), "theorem5") == -3.0
    assert rb.robustness(_row(theorem5_margin=math.nan), "theorem5") == rb.THEOREM5_SATISFIED
    # near-violations rank: the lower margin is the nearer miss
    assert rb.robustness(_row(theorem5_margin=0.001), "theorem5") < rb.robustness(_row(theorem5_margin=3.0), "theorem5")
