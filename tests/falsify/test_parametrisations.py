"""The low-dimensional parametrisations of the perception error and the random baselines."""

from __future__ import annotations

import numpy as np
import pytest

from mcverify.falsify.parametrisations import (
    BangBang,
    FullSequence,
    GapBands,
    Windows,
    random_bang_bang,
    random_uniform,
)
from mcverify.sim.schedule import CHANNELS, ErrorSchedule, GapBandSchedule


def test_gap_bands_put_theta_on_the_chosen_channels_per_band():
    p = GapBands(channels=("front_y", "opp_x"), opp_share=0.0)
    assert p.dimension == 6
    s = p.schedule([0.1, 0.2, 0.3, 0.4, 2.0, -0.6])
    assert isinstance(s, GapBandSchedule) and s.opp_share == 0.0
    expected = np.zeros((3, 5))
    expected[:, [1, 3]] = [[0.1, 0.2], [0.3, 0.4], [1.0, -0.6]]  # 2.0 clipped to the box
    np.testing.assert_array_equal(s.units, expected)


def test_windows_place_constant_units_within_their_start_ranges():
    p = Windows(steps=50, start_ranges=((10, 20), (30, 40)), max_steps=5, channels=("front_y",))
    assert p.dimension == 6
    s = p.schedule([-1.0, -1.0, 0.7, 1.0, 1.0, -0.3])
    col = s.units[:, CHANNELS.index("front_y")]
    assert col[10] == 0.7 and col[11] == 0.0  # start 10, one step
    np.testing.assert_array_equal(col[40:45], -0.3)  # start 40, five steps
    assert np.count_nonzero(s.units) == 6
    w = Windows.around(50, centres_s=[1.0, 3.0], half_width_s=0.3, control_period_s=0.1)
    assert w.start_ranges == ((7, 13), (27, 33))


def test_bang_bang_is_the_sign_per_segment():
    s = BangBang(steps=10, segments=3, channels=("front_x",)).schedule([0.0, -2.0, 5.0])
    np.testing.assert_array_equal(s.units[:, 0], [1, 1, 1, 1, -1, -1, -1, 1, 1, 1])
    assert not s.units[:, 1:].any()


def test_full_sequence_and_the_baselines_are_valid_and_deterministic():
    s = FullSequence(steps=4).schedule(np.linspace(-1, 1, 20))
    assert isinstance(s, ErrorSchedule) and s.units.shape == (4, 5)
    a, b = random_uniform(30, seed=5), random_uniform(30, seed=5)
    np.testing.assert_array_equal(a.units, b.units)
    assert not np.array_equal(a.units, random_uniform(30, seed=6).units)
    bb = random_bang_bang(30, 6, seed=2, channels=("front_y", "opp_v"))
    assert set(np.unique(bb.units[:, [1, 4]])) <= {-1.0, 1.0} and not bb.units[:, [0, 2, 3]].any()
    np.testing.assert_array_equal(bb.units, random_bang_bang(30, 6, seed=2, channels=("front_y", "opp_v")).units)


def test_bad_theta_and_channels_are_rejected():
    with pytest.raises(ValueError, match="15 numbers"):
        GapBands().schedule(np.zeros(3))
    with pytest.raises(ValueError, match="no NaN"):
        BangBang(steps=4, segments=1, channels=("front_x",)).schedule([np.nan])
    with pytest.raises(ValueError, match="channels"):
        GapBands(channels=("front_z",)).schedule(np.zeros(3))
