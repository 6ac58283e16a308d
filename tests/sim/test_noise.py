"""Perception noise: bounds, uniformity (Kolmogorov-Smirnov), the exact "none" kind, and keys that
do not depend on the batch."""

from __future__ import annotations

from dataclasses import replace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from mcverify.model import Noise
from mcverify.sim import noise

PAPER = Noise()
ROOT = jax.random.PRNGKey(2024)
N_DRAWS = 4000






def draw(model: Noise, x: float, y: float, v: float, gap: float, n: int = N_DRAWS) -> np.ndarray:
    """(n, 3) measurement errors [dx, dy, dv] for n independent steps of one episode."""

    @jax.jit
    def one(step):
        m = noise.measure_vehicle(noise.step_key(ROOT, step, 0), x, y, v, gap, model)
        return jnp.stack(m) - jnp.array([x, y, v])

    return np.asarray(jax.vmap(one)(jnp.arange(n)))


def assert_uniform(sample: np.ndarray, half_width: float) -> None:
    assert np.all(np.abs(sample) <= half_width * (1 + 1e-12))
    assert np.max(np.abs(sample)) > 0.99 * half_width  # the whole range is used
    assert stats.kstest(sample, "uniform", args=(-half_width, 2 * half_width)).pvalue > 1e-3


@pytest.mark.parametrize(
    ("gap", "pos_half"),
    [(5.0, 0.5), (2.0001, 0.5), (2.0, 0.1), (0.3, 0.1), (0.0, 0.1)],  # gap == threshold: near
)
def test_paper_regimes_bounds_and_uniformity(gap: float, pos_half: float) -> None:
    errors = draw(PAPER, 70.0, 0.2, 6.94, gap)
    assert_uniform(errors[:, 0], pos_half)
    assert_uniform(errors[:, 1], pos_half)
    assert_uniform(errors[:, 2], 0.1 * 6.94)
    # x, y and v noise are independent draws
    assert abs(np.corrcoef(errors.T)[0, 1]) < 0.06 and abs(np.corrcoef(errors.T)[0, 2]) < 0.06


def test_scale_and_negative_speed() -> None:
    errors = draw(replace(PAPER, scale=3.0), -12.0, 3.5, -15.0, 10.0)
    assert_uniform(errors[:, 0], 1.5)
    assert_uniform(errors[:, 2], 3.0 * 0.1 * 15.0)  # relative to |speed|


def test_zero_speed_has_no_speed_noise() -> None:
    assert np.all(draw(PAPER, 1.0, 0.0, 0.0, 5.0, n=50)[:, 2] == 0.0)


def test_none_kind_is_exact() -> None:
    values = (64.123456789, -0.000123, 6.944444444444445)
    got = jax.jit(lambda k: noise.measure_vehicle(k, *values, 0.5, Noise(kind="none")))(ROOT)
    assert tuple(float(v) for v in got) == values
    assert draw(Noise(kind="none"), *values, 0.5, n=20).max() == 0.0


def test_unknown_kind_raises_naming_valid_kinds() -> None:
    with pytest.raises(ValueError, match="paper, none"):
        noise.measure_vehicle(ROOT, 0.0, 0.0, 1.0, 5.0, Noise(kind="gaussian"))


def test_step_key_is_fold_in_of_stream_then_step() -> None:
    want = jax.random.fold_in(jax.random.fold_in(ROOT, 3), 17)
    np.testing.assert_array_equal(noise.step_key(ROOT, 17, 3), want)
    np.testing.assert_array_equal(jax.jit(noise.step_key)(ROOT, jnp.int32(17), 3), want)
    keys = {tuple(np.asarray(noise.step_key(ROOT, s, c)).tolist()) for s in range(5) for c in range(3)}
    assert len(keys) == 15  # all distinct


def test_deterministic() -> None:
    a = draw(PAPER, 70.0, 0.2, 6.94, 5.0, n=100)
    b = draw(PAPER, 70.0, 0.2, 6.94, 5.0, n=100)
    np.testing.assert_array_equal(a, b)


def test_vmap_batch_does_not_change_episode_draws(assert_batch_equals_loop) -> None:
    """Episode i's measurements are the same computed alone or inside a vmapped batch of 7."""
    episode_keys = jax.vmap(lambda i: jax.random.fold_in(ROOT, i))(jnp.arange(7))
    rng = np.random.default_rng(5)
    truth = rng.uniform([0, -1, 0, 0], [100, 4, 20, 4], (7, 4))  # x, y, v, gap
    steps = jnp.arange(7) * 13

    def measure(key, step, t):
        return jnp.stack(noise.measure_vehicle(noise.step_key(key, step, 0), t[0], t[1], t[2], t[3], PAPER))

    def unit_draws(key, step):
        return jax.random.uniform(noise.step_key(key, step, 0), (3,), minval=-1.0, maxval=1.0)

    batched = np.asarray(jax.jit(jax.vmap(measure))(episode_keys, steps, truth))
    batched_keys = np.asarray(jax.vmap(noise.step_key, in_axes=(0, 0, None))(episode_keys, steps, 0))
    batched_units = np.asarray(jax.jit(jax.vmap(unit_draws))(episode_keys, steps))
    single = jax.jit(measure)
    for i in range(7):
        key_i = jax.random.fold_in(ROOT, i)
        # The random bits are integer arithmetic: identical regardless of the batch.
        np.testing.assert_array_equal(batched_keys[i], noise.step_key(key_i, steps[i], 0))
        np.testing.assert_array_equal(batched_units[i], jax.jit(unit_draws)(key_i, steps[i]))
        alone = np.asarray(single(key_i, steps[i], truth[i]))
        assert_batch_equals_loop(batched[i], alone)
        eager = np.asarray(measure(key_i, steps[i], truth[i]))
        np.testing.assert_allclose(eager, alone, rtol=1e-15, atol=1e-15)


# --- structured, bounded disturbances (mcverify falsify) --------------------------------------


def _measure_args():
    from mcverify.sim.noise import NoiseBounds  # noqa: PLC0415

    return {"bounds": NoiseBounds(pos_far_m=0.5, pos_near_m=0.1, near_threshold_m=2.0, speed_rel=0.1, scale=1.0)}


def test_no_disturbance_is_bit_identical_to_the_plain_draw():
    import jax  # noqa: PLC0415

    from mcverify.sim import noise as nz  # noqa: PLC0415

    for i in range(20):
        key = jax.random.PRNGKey(i)
        plain = nz.measure(key, 30.0 + i, 0.1, 7.0, 5.0, **_measure_args())
        with_zero = nz.measure(key, 30.0 + i, 0.1, 7.0, 5.0, **_measure_args(), share=0.0,
                               x_offset=0.0, v_offset=0.0)
        unit = jax.random.uniform(key, (3,), dtype=float, minval=-1.0, maxval=1.0)
        expected = (30.0 + i + 0.5 * unit[0], 0.1 + 0.5 * unit[1], 7.0 + (1.0 * 0.1 * 7.0) * unit[2])
        for a, b, c in zip(plain, with_zero, expected, strict=True):
            assert float(a) == float(b) == float(c)


def test_structured_errors_stay_inside_the_declared_bounds():
    import jax  # noqa: PLC0415
    import numpy as np  # noqa: PLC0415

    from mcverify.sim import noise as nz  # noqa: PLC0415

    rng = np.random.default_rng(0)
    for i in range(50):
        d = [rng.uniform(-1, 1), rng.uniform(-0.5, 0.5), rng.uniform(-1, 1), rng.uniform(-0.5, 0.5)]
        t = rng.uniform(0, 20)
        sx, sv = nz.structured_offsets(d, t)
        share = rng.uniform(0, 1)
        x, _, v = nz.measure(jax.random.PRNGKey(i), 30.0, 0.0, 7.0, 5.0, **_measure_args(), share=share,
                             x_offset=sx, v_offset=sv)
        assert abs(float(x) - 30.0) <= 0.5 + 1e-12 and abs(float(v) - 7.0) <= 0.7 + 1e-12
    # the whole budget as a bias: the error sits on the bound
    sx, sv = nz.structured_offsets([1.0, 0.0, -1.0, 0.0], 3.0)
    x, _, v = nz.measure(jax.random.PRNGKey(0), 30.0, 0.0, 7.0, 5.0, **_measure_args(), share=1.0,
                         x_offset=sx, v_offset=sv)
    assert float(x) == 30.5 and float(v) == 6.3
    # a drift grows with time until it reaches the bound
    assert float(nz.structured_offsets([0.0, 0.1, 0.0, 0.0], 5.0)[0]) == 0.5
    assert float(nz.structured_offsets([0.0, 0.1, 0.0, 0.0], 50.0)[0]) == 1.0


def test_disturbance_fields_are_validated_with_one_line():
    import pytest  # noqa: PLC0415

    from mcverify.campaign.spec import campaign_from_dict  # noqa: PLC0415
    from mcverify.errors import CampaignError  # noqa: PLC0415

    for field, value in (("structured_share", 1.5), ("front_x_bias", -2.0)):
        raw = {"campaign": {"name": "x", "seed": 1, "episodes": 1}, "model": {"noise": {field: value}}}
        with pytest.raises(CampaignError, match=f"noise.{field}") as err:
            campaign_from_dict(raw)
        assert "\n" not in str(err.value)


# --- piecewise-constant offsets over equal segments of the episode --------------------------------


def test_segment_offsets_pick_the_segment_of_the_time_and_none_is_the_old_value():
    import jax.numpy as jnp  # noqa: PLC0415
    import numpy as np  # noqa: PLC0415

    from mcverify.model import MAX_SEGMENTS  # noqa: PLC0415
    from mcverify.sim import noise as nz  # noqa: PLC0415

    values = jnp.asarray([0.5, -0.25, 1.0, -1.0, *([0.0] * (MAX_SEGMENTS - 4))])
    # 4 segments of a 20 s episode: [0, 5), [5, 10), [10, 15), [15, 20]
    for t, want in ((0.0, 0.5), (4.999, 0.5), (5.0, -0.25), (12.0, 1.0), (19.9, -1.0), (20.0, -1.0)):
        assert float(nz.segment_offset(values, 4.0, t, 20.0)) == want, t
    assert float(nz.segment_offset(values, 0.0, 7.0, 20.0)) == 0.0
    # bias + drift + offset, clipped to the bound
    seg = jnp.stack([values, values])
    sx, sv = nz.structured_offsets([0.2, 0.01, -0.9, 0.0], 12.0, seg, [4.0, 4.0], 20.0)
    assert float(sx) == 1.0 and float(sv) == float(np.float64(-0.9) + np.float64(1.0))
    # no segments: bit for bit the offsets without them, at any time and disturbance
    rng = np.random.default_rng(1)
    zero = jnp.zeros((2, MAX_SEGMENTS))
    for _ in range(50):
        d, t = rng.uniform(-1, 1, 4), rng.uniform(0, 25)
        old = nz.structured_offsets(d, t)
        new = nz.structured_offsets(d, t, zero, [0.0, 0.0], 25.0)
        assert [float(a) for a in old] == [float(b) for b in new]


def test_segment_fields_are_validated_and_padded():
    import pytest  # noqa: PLC0415

    from mcverify.campaign.spec import campaign_from_dict  # noqa: PLC0415
    from mcverify.errors import CampaignError  # noqa: PLC0415
    from mcverify.sim import noise as nz  # noqa: PLC0415

    def camp(value):
        return campaign_from_dict({"campaign": {"name": "x", "seed": 1, "episodes": 1},
                                   "model": {"noise": {"opp_x_segments": value}}})

    noise_params = camp([0.5, -1.0, 0.0]).cells[0].params.noise
    assert noise_params.opp_x_segments == (0.5, -1.0, 0.0)
    opp = nz.NoiseParams.of(noise_params, 25.0).opp
    values, counts = opp.segments.tolist(), opp.segment_counts.tolist()
    assert counts == [3.0, 0.0] and values[0][:4] == [0.5, -1.0, 0.0, 0.0] and len(values[1]) == 8
    for bad in ([1.5], [0.0] * 9):
        with pytest.raises(CampaignError, match="noise.opp_x_segments") as err:
            camp(bad)
        assert "\n" not in str(err.value)


def test_the_plant_measures_veh_f_with_the_offset_of_the_current_segment():
    """Through the plant: share 1, no bias, three segments of a 24 s episode; the x error is
    half-width * the segment's value, the speed (no segments) is exact."""
    import jax  # noqa: PLC0415
    import jax.numpy as jnp  # noqa: PLC0415

    from mcverify.campaign.spec import campaign_from_dict  # noqa: PLC0415
    from mcverify.sim import plant as pl  # noqa: PLC0415

    model = {"noise": {"structured_share": 1.0, "front_x_segments": [0.5, -1.0, 0.25]}, "sim": {"max_time_s": 24.0}}
    p = campaign_from_dict({"campaign": {"name": "x", "seed": 1, "episodes": 1}, "model": model}).cells[0].params
    pp = pl.plant_params(p)
    lane = jax.tree_util.tree_map(lambda a: a[0], pl.initial_plant(p, [0.0]))
    for t_s, value in ((1.0, 0.5), (9.0, -1.0), (17.0, 0.25)):
        front, _ = pl.observe(lane._replace(t_s=jnp.asarray(t_s)), jax.random.PRNGKey(3), jnp.int32(4), pp)
        assert float(front[0]) - float(lane.front[0]) == p.noise.pos_far_m * value, t_s  # far regime: 0.5 m
        assert float(front[2]) == float(lane.front[1])


# --- veh_f's lateral disturbance: bias, drift, time and footprint-gap offsets -----------------------


def test_gap_offsets_pick_the_band_of_the_gap_and_nothing_beyond_the_window():
    import jax.numpy as jnp  # noqa: PLC0415

    from mcverify.model import MAX_SEGMENTS  # noqa: PLC0415
    from mcverify.sim import noise as nz  # noqa: PLC0415

    values = jnp.asarray([1.0, -0.5, 0.25, *([0.0] * (MAX_SEGMENTS - 3))])
    # 3 bands of a 6 m window: [0, 2), [2, 4), [4, 6]; an overlap (gap < 0) counts as the nearest band
    for gap, want in ((-0.3, 1.0), (0.0, 1.0), (1.99, 1.0), (2.0, -0.5), (3.5, -0.5), (4.0, 0.25), (6.0, 0.25),
                      (6.01, 0.0), (40.0, 0.0)):
        assert float(nz.gap_segment_offset(values, 3.0, gap, 6.0)) == want, gap
    assert float(nz.gap_segment_offset(values, 0.0, 1.0, 6.0)) == 0.0
    # bias + drift t + time offset + gap offset, clipped to the bound
    zero = jnp.zeros(MAX_SEGMENTS)
    assert float(nz.lateral_offset([0.2, 0.0], 3.0, 2.5, zero, 0.0, values, 3.0, 6.0, 20.0)) == float(
        jnp.asarray(0.2) + jnp.asarray(-0.5))
    assert float(nz.lateral_offset([0.5, 0.0], 3.0, 1.0, zero, 0.0, values, 3.0, 6.0, 20.0)) == 1.0
    assert float(nz.lateral_offset([0.0, 0.1], 5.0, 30.0, zero, 0.0, values, 3.0, 6.0, 20.0)) == 0.5


def test_lateral_share_zero_leaves_y_bit_for_bit_and_share_one_puts_y_on_its_offset():
    import jax  # noqa: PLC0415
    import numpy as np  # noqa: PLC0415

    from mcverify.sim import noise as nz  # noqa: PLC0415

    rng = np.random.default_rng(3)
    for i in range(30):
        key = jax.random.PRNGKey(100 + i)
        offset = float(rng.uniform(-1, 1))
        plain = nz.measure(key, 30.0, 0.1 * i, 7.0, 5.0, **_measure_args())
        zero_share = nz.measure(key, 30.0, 0.1 * i, 7.0, 5.0, **_measure_args(), y_share=0.0, y_offset=offset)
        assert [float(a) for a in plain] == [float(b) for b in zero_share]
        _, y, _ = nz.measure(key, 30.0, 0.1 * i, 7.0, 5.0, **_measure_args(), y_share=1.0, y_offset=offset)
        assert abs(float(y) - (0.1 * i + 0.5 * offset)) < 1e-15
        share = float(rng.uniform(0, 1))
        _, y, _ = nz.measure(key, 30.0, 0.0, 7.0, 5.0, **_measure_args(), y_share=share, y_offset=offset)
        assert abs(float(y)) <= 0.5 + 1e-12  # inside the declared bound whatever the share


def test_lateral_fields_are_validated_with_one_line():
    import pytest  # noqa: PLC0415

    from mcverify.campaign.spec import campaign_from_dict  # noqa: PLC0415
    from mcverify.errors import CampaignError  # noqa: PLC0415

    for field, value in (("lateral_share", -0.1), ("front_y_bias", 1.5), ("front_y_gap_segments", [2.0]),
                         ("front_y_segments", [0.0] * 9), ("front_y_gap_window_m", 0.0)):
        raw = {"campaign": {"name": "x", "seed": 1, "episodes": 1}, "model": {"noise": {field: value}}}
        with pytest.raises(CampaignError, match=f"noise.{field}") as err:
            campaign_from_dict(raw)
        assert "\n" not in str(err.value)


def test_the_plant_moves_measured_veh_f_sideways_by_the_band_of_its_gap():
    """Through the plant: lateral share 1, gap offsets [+1 within 2 m, -1 in 2-4 m] of a 4 m window; the
    measured y is the true y plus the regime's half-width times the band's value, x and speed as
    without the lateral disturbance."""
    import jax  # noqa: PLC0415
    import jax.numpy as jnp  # noqa: PLC0415

    from mcverify.campaign.spec import campaign_from_dict  # noqa: PLC0415
    from mcverify.sim import plant as pl  # noqa: PLC0415

    def params(noise):
        return campaign_from_dict({"campaign": {"name": "x", "seed": 1, "episodes": 1},
                                   "model": {"noise": noise}}).cells[0].params

    p = params({"lateral_share": 1.0, "front_y_gap_segments": [1.0, -1.0], "front_y_gap_window_m": 4.0})
    plain = params({})
    lane = jax.tree_util.tree_map(lambda a: a[0], pl.initial_plant(p, [0.0]))
    length = p.geometry.length_m
    key = jax.random.PRNGKey(5)
    for gap, value, half in ((1.0, 1.0, p.noise.pos_near_m), (3.0, -1.0, p.noise.pos_far_m), (10.0, None, None)):
        ego = lane.ego.at[0].set(lane.front[0] - length - gap)
        state = lane._replace(ego=ego)
        front, opp = pl.observe(state, key, jnp.int32(9), pl.plant_params(p))
        front0, opp0 = pl.observe(state, key, jnp.int32(9), pl.plant_params(plain))
        assert float(front[0]) == float(front0[0]) and float(front[2]) == float(front0[2])
        assert [float(v) for v in opp] == [float(v) for v in opp0]
        if value is None:  # beyond the window: no offset, and share 1 leaves no random part either
            assert float(front[1]) == 0.0
        else:
            assert abs(float(front[1]) - half * value) < 1e-12, gap
