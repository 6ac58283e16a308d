"""Algorithm 1 and the Conditions for Overtaking (Table I): every row of the table is a test."""

from __future__ import annotations

import math

import pytest

from mcverify.control.decision import TABLE_ONE_ROWS, Mode, Source, TableOneInput, decide, table_one


def case(**over) -> TableOneInput:
    """A situation where every column of Table I is satisfied; tests flip one column at a time.

    Columns: T1 > T2 (8 s > 3 s); x_o,Q1^N > x_e,Q1^N (veh_o ends 50 m ahead of the ego under Q1);
    x_o,Q2^N > x_g^2 (veh_o still 80 m beyond Q2's goal when Q2 ends); y_e in L_ego.
    """
    base = dict(
        q1_ok=True, q2_ok=True, t1_s=8.0, t2_s=3.0, x_e_q1_end_m=150.0, x_o_q1_end_m=200.0,
        x_o_q2_end_m=120.0, x_goal_q2_m=40.0, ego_in_own_lane=True,
    )
    base.update(over)
    return TableOneInput(**base)


# Table I, row by row (bullet = satisfies, circle = violates, blank = not care):
#   T1>T2  xoQ1>xeQ1  xoQ2>xg2  y_e in L_ego  ->  decision


def test_row_1_t1_greater_and_opposing_ends_ahead_overtakes():
    # row 1: T1 > T2 (bullet), xoQ1 > xeQ1 (bullet), rest "not care" -> overtake
    for in_lane in (True, False):
        for xo_q2 in (120.0, 10.0):  # either value of the third column
            assert table_one(case(ego_in_own_lane=in_lane, x_o_q2_end_m=xo_q2)) == (True, 1)


def test_row_2_t1_not_greater_in_own_lane_overtakes():
    # row 2: T1 > T2 (circle), xoQ1 > xeQ1 (bullet), y_e in L_ego (bullet) -> overtake,
    # the case the text describes: going back at risk, but the ego already cut in front of veh_f
    c = case(t1_s=2.0, t2_s=3.0, x_o_q2_end_m=10.0, ego_in_own_lane=True)
    assert table_one(c) == (True, 2)


def test_row_3_t1_not_greater_out_of_own_lane_goes_back():
    # row 3: T1 > T2 (circle), xoQ1 > xeQ1 (bullet), y_e in L_ego (circle) -> go back
    c = case(t1_s=2.0, t2_s=3.0, x_o_q2_end_m=10.0, ego_in_own_lane=False)
    assert table_one(c) == (False, 3)


def test_row_4_going_back_safe_overtakes_even_out_of_lane():
    # row 4: xoQ1 > xeQ1 (bullet), xoQ2 > xg2 (bullet) -> overtake; it takes precedence over row 3
    c = case(t1_s=2.0, t2_s=3.0, x_o_q2_end_m=120.0, ego_in_own_lane=False)
    assert table_one(c) == (True, 4)


def test_row_5_opposing_reaches_ego_final_position_goes_back():
    # row 5: xoQ1 > xeQ1 (circle) -> go back, whatever the other columns say
    for t1 in (8.0, 2.0):
        for in_lane in (True, False):
            c = case(t1_s=t1, x_o_q1_end_m=140.0, ego_in_own_lane=in_lane)
            assert table_one(c) == (False, 5)
    assert table_one(case(x_o_q1_end_m=150.0))[0] is False  # equal is not "greater"


def test_q1_not_solved_goes_back():
    assert table_one(case(q1_ok=False, t1_s=math.nan, x_e_q1_end_m=math.nan, x_o_q1_end_m=math.nan)) == (False, 0)


def test_q2_not_solved_keeps_the_feasible_overtake():
    # Theorem 5: with Q2 unsolved, Q1 is the feasible problem; the ego keeps overtaking while
    # veh_o stays ahead of where Q1 ends (and still goes back when it would not: row 5 first).
    c = case(q2_ok=False, t2_s=math.nan, x_o_q2_end_m=math.nan, x_goal_q2_m=math.nan, ego_in_own_lane=False)
    assert table_one(c) == (True, 6)
    assert table_one(case(q2_ok=False, x_o_q1_end_m=100.0)) == (False, 5)


def test_every_row_is_named():
    assert set(TABLE_ONE_ROWS) == {0, 1, 2, 3, 4, 5, 6}


@pytest.mark.parametrize(
    "mode, q1_ok, q2_ok, expected",
    [
        (Mode.OVERTAKE, True, True, (Mode.OVERTAKE, Source.Q1)),
        (Mode.OVERTAKE, True, False, (Mode.OVERTAKE, Source.Q1)),
        (Mode.OVERTAKE, False, True, (Mode.GO_BACK, Source.Q2)),  # Algorithm 1's break: for good
        (Mode.OVERTAKE, False, False, (Mode.OVERTAKE, Source.FALLBACK)),
        (Mode.GO_BACK, True, True, (Mode.GO_BACK, Source.Q2)),  # never back to Q1's loop
        (Mode.GO_BACK, False, True, (Mode.GO_BACK, Source.Q2)),
        (Mode.GO_BACK, True, False, (Mode.GO_BACK, Source.FALLBACK)),
    ],
)
def test_algorithm_one_transitions(mode, q1_ok, q2_ok, expected):
    assert decide(mode, q1_ok, q2_ok) == expected
