"""mcverify.analysis.bounds: the start-to-goal lower bound beside the paper's Table II."""

from __future__ import annotations

import dataclasses
import math

import pytest

from mcverify.analysis.bounds import goal_time_bounds, goal_time_lower_bound
from mcverify.model import ModelParams

TABLE_II = {"ego_x_m": 10.0, "ego_speed_mps": 10.0, "front_x_m": 64.0, "phi_s": 1.8, "speed_limit_mps": 19.4}


def test_paper_table_ii_start_cannot_reach_the_goal_in_the_papers_time():
    t25 = goal_time_lower_bound(front_speed_mps=25 / 3.6, **TABLE_II)
    assert t25 == pytest.approx(5.34, abs=0.01)
    assert t25 > 4.64  # the paper's mean at 25 km/h
    assert t25 == pytest.approx((54 + 1.8 * 25 / 3.6) / (19.4 - 25 / 3.6), rel=1e-12)


def test_bound_grows_with_the_front_speed_and_with_the_acceleration_limit():
    speeds = [25, 28, 32, 36]
    inf_acc = [goal_time_lower_bound(front_speed_mps=v / 3.6, **TABLE_II) for v in speeds]
    acc = [goal_time_lower_bound(front_speed_mps=v / 3.6, accel_max_mps2=3.0, **TABLE_II) for v in speeds]
    assert inf_acc == sorted(inf_acc) and len(set(inf_acc)) == 4
    assert acc == sorted(acc) and all(a > b for a, b in zip(acc, inf_acc, strict=True))
    # a huge acceleration limit tends to the speed-limit bound; the bound is a real crossing time
    assert goal_time_lower_bound(front_speed_mps=25 / 3.6, accel_max_mps2=1e9, **TABLE_II) == pytest.approx(inf_acc[0])
    t, a, v0, vf = acc[0], 3.0, 10.0, 25 / 3.6
    t1 = (19.4 - v0) / a
    x_e = 10.0 + v0 * t1 + 0.5 * a * t1**2 + 19.4 * (t - t1)
    assert x_e == pytest.approx(64.0 + vf * t + 1.8 * vf, abs=1e-9)


def test_edge_cases_and_params():
    assert goal_time_lower_bound(front_speed_mps=20.0, **TABLE_II) == math.inf  # limit below v_f
    assert goal_time_lower_bound(10.0, 10.0, 5.0, 1.0, 1.8, 19.4) == 0.0  # already past the goal
    p = dataclasses.asdict(ModelParams())
    b = goal_time_bounds(p)
    assert b["speed_limit"] == pytest.approx(5.339, abs=1e-3) and b["accel_limit"] > b["speed_limit"]
    p["scenario"]["front_accel_mps2"] = 1.0
    assert goal_time_bounds(p) is None and goal_time_bounds(None) is None
