"""Geometry against independent numpy references: exact polygon intersection, brute-force boundary
sampling, and a refined boundary search for the ellipse."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import minimize_scalar
from scipy.spatial import cKDTree

from mcverify.sim import barriers, geometry

LENGTH, WIDTH = 4.885, 1.840

corners_jit = jax.jit(geometry.footprint_corners)
overlap_jit = jax.jit(geometry.rectangles_overlap)
gap_jit = jax.jit(geometry.rectangle_gap_m)
ellipse_jit = jax.jit(geometry.ellipse_signed_distance_m)
pair_jit = jax.jit(
    jax.vmap(
        lambda pa, pb: (
            geometry.rectangles_overlap(geometry.footprint_corners(*pa), geometry.footprint_corners(*pb)),
            geometry.rectangle_gap_m(geometry.footprint_corners(*pa), geometry.footprint_corners(*pb)),
        )
    )
)






# ------------------------------------------------------------------------ numpy references


def corners_np(x: float, y: float, psi: float, length: float, width: float) -> np.ndarray:
    local = np.array([[1, -1], [1, 1], [-1, 1], [-1, -1]]) * [length / 2, width / 2]
    rot = np.array([[math.cos(psi), -math.sin(psi)], [math.sin(psi), math.cos(psi)]])
    return local @ rot.T + [x, y]


def _cross(o: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    return float((a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]))


def _inside_convex(p: np.ndarray, poly: np.ndarray) -> bool:
    return all(_cross(poly[k], poly[(k + 1) % 4], p) >= 0 for k in range(4))  # CCW polygon


def _segments_intersect(p1, p2, q1, q2) -> bool:
    d1, d2 = _cross(q1, q2, p1), _cross(q1, q2, p2)
    d3, d4 = _cross(p1, p2, q1), _cross(p1, p2, q2)
    return d1 * d2 <= 0 and d3 * d4 <= 0  # general position assumed (random configurations)


def polygons_intersect_np(a: np.ndarray, b: np.ndarray) -> bool:
    """Vertex containment or an edge crossing: a different method from the separating axes."""
    if any(_inside_convex(p, b) for p in a) or any(_inside_convex(p, a) for p in b):
        return True
    return any(_segments_intersect(a[i], a[(i + 1) % 4], b[j], b[(j + 1) % 4]) for i in range(4) for j in range(4))


def sampled_boundary(corners: np.ndarray, per_edge: int) -> np.ndarray:
    t = np.linspace(0.0, 1.0, per_edge, endpoint=False)[:, None]
    return np.concatenate([c + t * (np.roll(corners, -1, axis=0)[k] - c) for k, c in enumerate(corners)])


def sampled_gap_np(a: np.ndarray, b: np.ndarray, per_edge: int) -> tuple[float, float]:
    """(brute-force boundary-to-boundary minimum, its worst-case excess over the true gap)."""
    pa, pb = sampled_boundary(a, per_edge), sampled_boundary(b, per_edge)
    dist, _ = cKDTree(pb).query(pa)
    spacing = max(np.max(np.linalg.norm(np.diff(a, axis=0, append=a[:1]), axis=1)), LENGTH * 2) / per_edge
    return float(np.min(dist)), spacing


def ellipse_distance_np(px: float, py: float, a: float, b: float) -> float:
    t = np.linspace(0.0, 2 * np.pi, 4001)
    d = np.hypot(a * np.cos(t) - px, b * np.sin(t) - py)
    k, step = int(np.argmin(d)), t[1] - t[0]
    res = minimize_scalar(
        lambda s: math.hypot(a * math.cos(s) - px, b * math.sin(s) - py),
        bounds=(t[k] - step, t[k] + step),
        method="bounded",
        options={"xatol": 1e-13},
    )
    dist = min(res.fun, d[k])
    return dist if (px / a) ** 2 + (py / b) ** 2 >= 1.0 else -dist


def random_pairs(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Footprint parameters (n, 5) [x, y, psi, length, width] for pairs that are often near."""
    size = np.column_stack([rng.uniform(0.5, 6.0, (n, 2))])
    pa = np.column_stack([np.zeros(n), np.zeros(n), rng.uniform(-np.pi, np.pi, n), size])
    pb = np.column_stack(
        [rng.uniform(-8, 8, n), rng.uniform(-5, 5, n), rng.uniform(-np.pi, np.pi, n), rng.uniform(0.5, 6.0, (n, 2))]
    )
    return pa, pb


# -------------------------------------------------------------------------------- footprints


def test_footprint_corners_hand_cases() -> None:
    np.testing.assert_allclose(
        corners_jit(10.0, 1.0, 0.0, 4.0, 2.0), [[12.0, 0.0], [12.0, 2.0], [8.0, 2.0], [8.0, 0.0]], atol=1e-15
    )
    np.testing.assert_allclose(
        corners_jit(0.0, 0.0, np.pi / 2, 4.0, 2.0), [[1.0, 2.0], [-1.0, 2.0], [-1.0, -2.0], [1.0, -2.0]], atol=1e-15
    )


@settings(max_examples=30, deadline=None)
@given(
    st.floats(-100, 100),
    st.floats(-10, 10),
    st.floats(-math.pi, math.pi),
    st.floats(0.1, 10),
    st.floats(0.1, 10),
)
def test_footprint_corners_vs_numpy_and_ccw(x: float, y: float, psi: float, length: float, width: float) -> None:
    c = np.asarray(corners_jit(x, y, psi, length, width))
    np.testing.assert_allclose(c, corners_np(x, y, psi, length, width), atol=1e-12)
    shoelace = 0.5 * np.sum(c[:, 0] * np.roll(c[:, 1], -1) - np.roll(c[:, 0], -1) * c[:, 1])
    assert shoelace == pytest.approx(length * width, rel=1e-9)  # positive: counter-clockwise


# ------------------------------------------------------------------------------ overlap, gap


def aligned(x: float, y: float, psi: float = 0.0) -> jax.Array:
    return corners_jit(x, y, psi, LENGTH, WIDTH)


@pytest.mark.parametrize(
    ("other", "overlap", "gap"),
    [
        ((0.0, 0.0), True, 0.0),  # identical
        ((LENGTH, 0.0), True, 0.0),  # touching bumper to bumper counts as overlap
        ((0.0, WIDTH), True, 0.0),  # touching side by side
        ((LENGTH, WIDTH), True, 0.0),  # touching corner to corner
        ((LENGTH + 1.0, 0.0), False, 1.0),
        ((-LENGTH - 2.5, 0.3), False, 2.5),
        ((0.7, WIDTH + 0.4), False, 0.4),
        ((LENGTH + 3.0, WIDTH + 4.0), False, 5.0),  # corner to corner: 3-4-5
    ],
)
def test_aligned_hand_cases(other: tuple[float, float], overlap: bool, gap: float) -> None:
    a, b = aligned(0.0, 0.0), aligned(*other)
    assert bool(overlap_jit(a, b)) is overlap and bool(overlap_jit(b, a)) is overlap
    assert float(gap_jit(a, b)) == pytest.approx(gap, abs=1e-12)
    assert float(gap_jit(b, a)) == pytest.approx(gap, abs=1e-12)


def test_rotated_90_degrees() -> None:
    upright = aligned(0.0, 0.0, np.pi / 2)  # x in [-W/2, W/2], y in [-L/2, L/2]
    # A cross: no corner of either lies inside the other, yet they overlap.
    assert bool(overlap_jit(upright, aligned(0.0, 0.0)))
    assert float(gap_jit(upright, aligned(0.0, 0.0))) == 0.0
    beside = aligned(WIDTH / 2 + LENGTH / 2 + 0.3, 0.0)
    assert not bool(overlap_jit(upright, beside))
    assert float(gap_jit(upright, beside)) == pytest.approx(0.3, abs=1e-12)
    above = aligned(0.0, LENGTH / 2 + WIDTH / 2 + 0.2)
    assert float(gap_jit(upright, above)) == pytest.approx(0.2, abs=1e-12)


def test_random_pairs_vs_polygon_intersection_and_sampling() -> None:
    pa, pb = random_pairs(np.random.default_rng(10), 200)
    hit, gap = (np.asarray(v) for v in pair_jit(pa, pb))
    per_edge = 400
    for k in range(len(pa)):
        a, b = corners_np(*pa[k]), corners_np(*pb[k])
        assert hit[k] == polygons_intersect_np(a, b), k
        sampled, spacing = sampled_gap_np(a, b, per_edge)
        if hit[k]:
            assert gap[k] == 0.0
        else:
            # Sampled points lie on the boundaries: never closer than the true gap, and at most
            # half a sampling step farther (the closest pair has a vertex, which is sampled).
            assert gap[k] > 0.0
            assert gap[k] <= sampled + 1e-12, k
            assert sampled - gap[k] <= spacing / 2 + 1e-12, k
    assert 40 < hit.sum() < 160  # both outcomes well represented


def test_random_containment_implies_overlap() -> None:
    rng = np.random.default_rng(11)
    pa, pb = random_pairs(rng, 200)
    hit = np.asarray(pair_jit(pa, pb)[0])
    for k in range(len(pa)):
        a, b = corners_np(*pa[k]), corners_np(*pb[k])
        w = rng.uniform(0, 1, (400, 4))
        points = (w / w.sum(axis=1, keepdims=True)) @ a  # random convex combinations: inside a
        if any(_inside_convex(p, b) for p in points):
            assert hit[k], k


def test_near_touching_is_consistent() -> None:
    # Gaps of 1e-9 m must register as separate; overlap of 1e-9 m as overlapping.
    for psi in (0.0, 0.3, 1.2):
        a = corners_jit(0.0, 0.0, psi, LENGTH, WIDTH)
        normal = np.array([-np.sin(psi), np.cos(psi)])  # left side of a
        for delta, overlap in ((1e-9, False), (-1e-9, True)):
            offset = normal * (WIDTH + delta)
            b = corners_jit(offset[0], offset[1], psi, LENGTH, WIDTH)
            assert bool(overlap_jit(a, b)) is overlap
            assert float(gap_jit(a, b)) == pytest.approx(max(delta, 0.0), abs=1e-13)


# ------------------------------------------------------------------------------------ ellipse


def test_ellipse_hand_cases() -> None:
    a, b = 7.0, 2.0
    cases = [
        ((0.0, 0.0), -2.0),  # centre: nearest point is a co-vertex
        ((0.0, 1.5), -0.5),
        ((0.0, -5.0), 3.0),
        ((9.0, 0.0), 2.0),
        ((-7.0, 0.0), 0.0),
        ((6.6, 0.0), -0.4),  # on the major axis beyond the evolute cusp (x > a - b^2/a): the vertex
        ((3.0, 0.0), -math.hypot(3.0 - 7 * 21 / 45, 2 * math.sqrt(1 - (21 / 45) ** 2))),  # inside the cusp
    ]
    for (px, py), want in cases:
        assert float(ellipse_jit(px, py, a, b)) == pytest.approx(want, abs=1e-12), (px, py)
        assert float(ellipse_jit(py, px, b, a)) == pytest.approx(want, abs=1e-12), (px, py)  # swapped axes
    assert float(ellipse_jit(3.0, 4.0, 2.0, 2.0)) == pytest.approx(3.0, abs=1e-12)  # circle
    assert float(ellipse_jit(0.0, 0.0, 2.0, 2.0)) == pytest.approx(-2.0, abs=1e-12)
    assert float(ellipse_jit(1000.0, -300.0, a, b)) == pytest.approx(
        ellipse_distance_np(1000.0, -300.0, a, b), abs=1e-9
    )


@pytest.mark.parametrize("offset", [1e-300, 1e-30, 1e-15, 1e-12, 1e-11, 1e-9, 1e-6, 1e-3])
def test_ellipse_near_the_axes(offset: float) -> None:
    # Near the major axis inside the evolute cusp the root of Eberly's equation nearly cancels;
    # check points just off both axes, inside and outside, against the reference.
    a, b = 7.0, 2.0
    for px, py in [(3.0, offset), (-6.6, -offset), (0.5, offset), (9.0, offset), (offset, 1.0), (-offset, 4.0)]:
        want = ellipse_distance_np(px, py, a, b)
        assert float(ellipse_jit(px, py, a, b)) == pytest.approx(want, abs=1e-12), (px, py)
        assert float(ellipse_jit(py, px, b, a)) == pytest.approx(want, abs=1e-12), (px, py)


def test_ellipse_points_on_boundary_are_zero() -> None:
    t = np.linspace(0.0, 2 * np.pi, 97)
    a, b = 6.9, 2.6
    got = np.asarray(jax.vmap(ellipse_jit, in_axes=(0, 0, None, None))(a * np.cos(t), b * np.sin(t), a, b))
    np.testing.assert_allclose(got, 0.0, atol=1e-13)


def test_ellipse_random_vs_refined_sampling() -> None:
    rng = np.random.default_rng(12)
    n = 300
    a, b = rng.uniform(0.5, 8.0, n), rng.uniform(0.5, 8.0, n)
    scale = np.where(rng.uniform(size=n) < 0.5, 1.2, 4.0)  # half near the ellipse, half far
    px, py = rng.uniform(-1, 1, n) * scale * a, rng.uniform(-1, 1, n) * scale * b
    got = np.asarray(jax.vmap(ellipse_jit)(px, py, a, b))
    want = np.array([ellipse_distance_np(*v) for v in zip(px, py, a, b, strict=True)])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    h = np.asarray(jax.vmap(barriers.h_ellipse, in_axes=(0, 0, None, None, 0, 0))(px, py, 0.0, 0.0, a, b))
    assert np.all(np.sign(got) == np.sign(h))  # the same inside/outside as the barrier


# ----------------------------------------------------------------------------- vmap vs loop


def test_vmap_matches_loop(assert_batch_equals_loop) -> None:
    pa, pb = random_pairs(np.random.default_rng(13), 40)
    ca = np.asarray(jax.vmap(corners_jit)(*pa.T))
    cb = np.asarray(jax.vmap(corners_jit)(*pb.T))
    assert_batch_equals_loop(ca, np.stack([np.asarray(corners_jit(*p)) for p in pa]))
    for fn in (overlap_jit, gap_jit):
        batched = np.asarray(jax.jit(jax.vmap(fn))(ca, cb))
        assert_batch_equals_loop(batched, np.array([fn(x, y) for x, y in zip(ca, cb, strict=True)]))
    px, py = pb[:, 0], pb[:, 1]
    batched = np.asarray(jax.jit(jax.vmap(geometry.ellipse_signed_distance_m))(px, py, pa[:, 3], pa[:, 4]))
    looped = np.array([ellipse_jit(*v) for v in zip(px, py, pa[:, 3], pa[:, 4], strict=True)])
    assert_batch_equals_loop(batched, looped)
    assert jnp.asarray(batched).dtype == jnp.float64
