"""Replay's row comparison: bit for bit on the stored columns, never on columns the run predates."""

from __future__ import annotations

import math

from mcverify.campaign.replay import compare_rows


def test_equal_rows_and_nan_equal_nan():
    row = {"safe": True, "min_h_front": 0.25, "min_gap_opp_m": math.nan, "outcome": "went_back"}
    assert compare_rows(dict(row), dict(row)) == {}


def test_a_difference_in_the_last_bit_is_reported():
    stored = {"min_h_front": 0.25}
    replayed = {"min_h_front": math.nextafter(0.25, 1.0)}
    assert set(compare_rows(stored, replayed)) == {"min_h_front"}


def test_a_column_the_stored_run_does_not_have_is_not_compared():
    stored = {"safe": False, "min_h_front": 0.1}
    replayed = {"safe": False, "min_h_front": 0.1, "infeasibility_audits": 0}
    assert compare_rows(stored, replayed) == {}


def test_a_stored_null_is_still_a_difference():
    stored = {"safe": False, "min_h_front": None}
    replayed = {"safe": False, "min_h_front": 0.1}
    assert set(compare_rows(stored, replayed)) == {"min_h_front"}
