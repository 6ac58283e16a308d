"""The beam search over the per-step error: deterministic, resumes to the uninterrupted result, nodes cost
only their own steps, and the best schedule re-simulated from step 0 gives the beam's row (real closed loop,
30 control steps)."""

from __future__ import annotations

import dataclasses
import hashlib
import math
import types

import numpy as np
import pyarrow.parquet as pq
import pytest

from mcverify.analysis import robustness as rb
from mcverify.campaign.replay import replay
from mcverify.campaign.spec import campaign_from_dict
from mcverify.errors import RunError
from mcverify.falsify import beam

RAW = {"campaign": {"name": "beam-test", "seed": 3, "episodes": 1},
       "model": {"sim": {"control_period_s": 0.1, "substeps": 20, "max_time_s": 3.0},
                 "scenario": {"front_x_m": 30.0}}}
SPEC = beam.BeamSpec(first_step=5, last_step=15, segment_steps=5, requirement="ellipse", seed=7,
                     shape=beam.BeamShape(branching=2, width=2, channels=("front_x", "front_y")))


@pytest.fixture(scope="module")
def campaign():
    return campaign_from_dict(RAW)


@pytest.fixture(scope="module")
def whole(campaign, tmp_path_factory):
    return beam.search(campaign, SPEC, tmp_path_factory.mktemp("beam") / "whole")


def test_interrupted_and_resumed_equals_uninterrupted(campaign, whole, tmp_path):
    with pytest.raises(RunError, match="test hook"):
        beam.search(campaign, SPEC, tmp_path / "cut", stop_after_depths=1)
    resumed = beam.search(campaign, SPEC, tmp_path / "cut")
    assert resumed.robustness == whole.robustness and resumed.search_steps == whole.search_steps
    assert all(np.array_equal(a.units, b.units) for a, b in zip(resumed.frontier, whole.frontier, strict=True))
    assert resumed.rebuild_steps == 2 * 10  # two frontier nodes re-simulated to the end of depth 1 (step 9)
    with pytest.raises(RunError, match="another specification"):
        beam.search(campaign, dataclasses.replace(SPEC, seed=8), tmp_path / "cut")


def test_nodes_cost_their_own_steps_and_memory_stays_bounded(whole):
    # the prefix (5 steps), depth 1 (2 children x 5), depth 2 (2 x 2 x 5), the two frontier episodes finished
    # after step 14 (15 steps each: both time out at step 29 here)
    assert [n.row["outcome"] for n in whole.frontier] == ["timeout", "timeout"]
    assert whole.search_steps == 5 + 10 + 20 + 30
    assert [d["control_steps"] for d in whole.depth_log] == [15, 35]
    assert whole.peak_snapshots <= 2 * SPEC.shape.width + 1
    # the adversary acted in the window only, with bang-bang units on the chosen channels
    for node in whole.frontier:
        assert not node.units[:5].any() and not node.units[15:].any() and not node.units[:, 2:].any()
        assert set(np.unique(node.units[5:15, :2])) <= {-1.0, 1.0}


def test_the_final_frontier_is_the_one_found_before(whole):
    """The frontier's schedules, pinned from the code before BeamShape: the draws and the ranking unchanged."""
    digest = hashlib.sha256(np.stack([n.units for n in whole.frontier]).tobytes()).hexdigest()
    assert digest == "6429cdbb89962418581fb792ac5646754d4296f114cfd8e99ea5329d834236e3"


def test_the_best_schedule_replays_bit_for_bit_from_step_0(campaign, whole, tmp_path):
    run = beam.write_best(campaign, whole.frontier[whole.best].units, SPEC, tmp_path / "best")
    row = pq.read_table(run / "episodes.parquet").to_pylist()[0]
    best = whole.frontier[whole.best]
    for key in ("min_h_front", "theorem5_margin", "steps", "outcome", "both_infeasible_steps"):
        assert row[key] == best.row[key] or (row[key] != row[key] and best.row[key] != best.row[key]), key
    assert replay(run, 0).row["min_h_front"] == row["min_h_front"]


def test_a_bad_window_is_one_line(campaign, tmp_path):
    with pytest.raises(RunError, match="must lie in"):
        beam.search(campaign, dataclasses.replace(SPEC, last_step=99), tmp_path / "bad")


def test_a_violation_decided_in_a_prefix_ends_the_search_at_once(campaign, tmp_path, monkeypatch):
    """A running-minimum requirement violated in a child's prefix is violated for good: that child runs to its
    episode's end and the search stops there, its cost the steps so far. The decision is faked here (the test
    episode violates nothing): every node whose prefix reaches step 9, i.e. the first child of depth 1."""
    monkeypatch.setitem(beam.DECIDED_IN_PREFIX, "ellipse", lambda snap: snap.step >= 9)
    stopped = beam.search(campaign, SPEC, tmp_path / "stop")
    assert stopped.stopped_at_depth == 1 and len(stopped.frontier) == 1
    # the prefix (5 steps), the first child of depth 1 (5), then that child run to the time limit (steps 10-29)
    assert stopped.search_steps == 5 + 5 + 20 and stopped.frontier[0].row["steps"] == 30
    assert stopped.depth_log == [{"depth": 1, "best_score": stopped.frontier[0].score, "control_steps": 30}]
    assert stopped.robustness == [stopped.frontier[0].row["min_h_front"]]
    resumed = beam.search(campaign, SPEC, tmp_path / "stop")  # no depth file was written: the same stop again
    assert resumed.search_steps == stopped.search_steps and resumed.stopped_at_depth == 1


@pytest.mark.parametrize("requirement", sorted(beam.DECIDED_IN_PREFIX))
def test_prefix_decisions_name_requirements_whose_robustness_is_a_running_minimum(requirement):
    from mcverify.analysis import robustness as rb

    assert requirement in rb.REQUIREMENTS  # a typo would silently never stop a search


@pytest.mark.parametrize(("score", "expected"), [("h_front", 0.3), ("theorem5", -0.5)])
def test_each_score_ranks_a_node_by_its_own_running_value(score, expected):
    loop = types.SimpleNamespace(spec=types.SimpleNamespace(shape=types.SimpleNamespace(score=score)))
    row = {"min_h_front": 0.3, "theorem5_margin": -0.5}
    assert beam._Loop._score(loop, None, row) == pytest.approx(expected, abs=1e-15)
    # before any dual-planner step the margin is NaN: theorem5 ranks such a node last
    fresh = beam._Loop._score(loop, None, {"min_h_front": 0.3, "theorem5_margin": float("nan")})
    assert fresh == {"h_front": 0.3, "theorem5": float("inf")}[score]


def _snapshot(gap_opp_m: float, collision_opp: bool = False) -> types.SimpleNamespace:
    trace = types.SimpleNamespace(min_h_front=0.4, min_gap_front_m=3.0, collision_front=False,
                                  min_gap_opp_any_m=gap_opp_m, collision_opp=collision_opp)
    return types.SimpleNamespace(trace=trace, state=types.SimpleNamespace(theorem5_margin=0.2))


def test_the_safe_score_ranks_by_the_nearest_of_veh_f_veh_o_and_the_ellipse():
    """``safe`` ranks a node by the requirement's robustness so far: veh_o's gap counts (in h_ef's unit) once
    veh_o exists, a contact with it is a violation decided in the prefix, and the final row scores the same way."""
    scale = rb.SAFE_GAP_SCALE_M
    assert beam.running_score("safe", beam.running_row(_snapshot(math.inf))) == pytest.approx(0.4)  # no veh_o yet
    assert beam.running_score("safe", beam.running_row(_snapshot(1.0))) == pytest.approx(1.0 / scale)
    assert beam.running_score("safe", beam.running_row(_snapshot(0.0, True))) == rb.COLLISION_ROBUSTNESS_M / scale
    assert beam.DECIDED_IN_PREFIX["collision_opp"](_snapshot(0.0, True))
    assert not beam.DECIDED_IN_PREFIX["safe"](_snapshot(0.1))
    row = {"min_h_front": 0.4, "min_gap_front_m": 3.0, "collision_front": False, "min_gap_opp_any_m": 1.0,
           "collision_opp": False, "opposing_kind": "human"}
    assert beam.running_score("safe", row) == pytest.approx(1.0 / scale)
    assert beam.running_score("safe", {**row, "opposing_kind": "none", "min_gap_opp_any_m": math.nan}) == 0.4


def test_held_units_keep_one_sign_per_channel_through_each_segment(campaign, tmp_path):
    """``units = "held"``: a child's segment holds one sign per chosen channel (a sustained error)."""
    spec = dataclasses.replace(SPEC, shape=dataclasses.replace(SPEC.shape, units="held"))
    root = beam.Node(np.zeros((30, 5)), 4, 0.0)
    for depth in (0, 1):
        for units in beam._children(spec, root, depth, 0, [0, 1]):
            seg = units[5 + 5 * depth:10 + 5 * depth, :2]
            assert set(np.unique(seg)) <= {-1.0, 1.0} and (seg == seg[0]).all()
            assert not np.delete(units, np.s_[5 + 5 * depth:10 + 5 * depth], axis=0).any()
