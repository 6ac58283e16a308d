"""Exact planar geometry for the safety checks: vehicle footprints, their overlap and gap, and the
signed distance to the barrier ellipse.

Every function handles one configuration (unbatched) and is jit- and vmap-able: no Python control
flow on traced values and fixed iteration counts. Dot products are written out element-wise rather
than with ``@``/``jnp.dot`` so that XLA emits the same element-wise code for a single episode and
for a vmapped batch (a batched ``dot_general`` may accumulate in a different order).

Units: metres and radians. Corner arrays are (4, 2) [[x, y], ...] in counter-clockwise order.
"""

from __future__ import annotations

from typing import TypeAlias

import jax
import jax.numpy as jnp

Array: TypeAlias = jax.Array
ArrayLike: TypeAlias = jax.typing.ArrayLike

#: Bisection steps in :func:`ellipse_signed_distance_m`. 96 halvings shrink the root bracket by
#: 2^-96 ~ 1.3e-29; the root is >= AXIS_SNAP_REL = 1e-12, so for brackets up to 1e3 wide (points
#: within about a hundred semi-axes of the centre) it is resolved to 1e-14 relative. Extra steps
#: leave a collapsed bracket unchanged.
ELLIPSE_BISECTION_STEPS: int = 96

#: Points closer than this times the minor semi-axis to the major axis are treated as on it (an
#: error of at most 1e-12 * b; see :func:`_ellipse_distance_first_quadrant`).
AXIS_SNAP_REL: float = 1e-12


def footprint_corners(
    x_m: ArrayLike, y_m: ArrayLike, psi_rad: ArrayLike, length_m: ArrayLike, width_m: ArrayLike
) -> Array:
    """Corners of a vehicle's rectangular footprint.

    (x_m, y_m) is taken as the centre of the footprint (the paper's c.g.; the model does not
    separate the two), psi_rad the heading from the road x axis, length along the heading.

    Returns:
        (4, 2) corners, counter-clockwise: front-right, front-left, rear-left, rear-right.
    """
    half_l = 0.5 * jnp.asarray(length_m, dtype=float)
    half_w = 0.5 * jnp.asarray(width_m, dtype=float)
    local_x = jnp.stack([half_l, half_l, -half_l, -half_l])
    local_y = jnp.stack([-half_w, half_w, half_w, -half_w])
    cos_psi, sin_psi = jnp.cos(psi_rad), jnp.sin(psi_rad)
    world_x = x_m + (local_x * cos_psi - local_y * sin_psi)
    world_y = y_m + (local_x * sin_psi + local_y * cos_psi)
    return jnp.stack([world_x, world_y], axis=-1)


def _edge_axes(corners: Array) -> Array:
    """(2, 2) directions of two adjacent edges; for a rectangle they are also its edge normals."""
    return jnp.stack([corners[1] - corners[0], corners[2] - corners[1]])


def rectangles_overlap(corners_a: ArrayLike, corners_b: ArrayLike) -> Array:
    """Exact separating-axis test for two rectangles given by (4, 2) corners (any orientation).

    Touching counts as overlap: the footprints are closed sets, and a contact is a collision (the
    conservative reading for a safety check). Consistently, :func:`rectangle_gap_m` is 0 then.

    Returns:
        bool scalar: True when the rectangles share at least one point.
    """
    corners_a = jnp.asarray(corners_a, dtype=float)
    corners_b = jnp.asarray(corners_b, dtype=float)
    axes = jnp.concatenate([_edge_axes(corners_a), _edge_axes(corners_b)])  # (4, 2)
    proj_a = corners_a[None, :, 0] * axes[:, None, 0] + corners_a[None, :, 1] * axes[:, None, 1]
    proj_b = corners_b[None, :, 0] * axes[:, None, 0] + corners_b[None, :, 1] * axes[:, None, 1]
    separated = (jnp.max(proj_a, axis=1) < jnp.min(proj_b, axis=1)) | (
        jnp.max(proj_b, axis=1) < jnp.min(proj_a, axis=1)
    )
    return ~jnp.any(separated)


def _points_to_polygon_edges_m(points: Array, corners: Array) -> Array:
    """(P, 4) Euclidean distances from each of ``points`` (P, 2) to each edge of the closed
    polygon ``corners`` (4, 2)."""
    start = corners
    edge = jnp.roll(corners, -1, axis=0) - corners  # edge k runs from corner k to corner k + 1
    dx = points[:, None, 0] - start[None, :, 0]
    dy = points[:, None, 1] - start[None, :, 1]
    edge_sq = edge[:, 0] ** 2 + edge[:, 1] ** 2
    # A degenerate (zero-length) edge is its start point: t = 0 there instead of 0/0.
    nonzero = edge_sq > 0.0
    along = dx * edge[None, :, 0] + dy * edge[None, :, 1]
    t = jnp.where(nonzero, along / jnp.where(nonzero, edge_sq, 1.0), 0.0)
    t = jnp.clip(t, 0.0, 1.0)
    rx = dx - t * edge[None, :, 0]
    ry = dy - t * edge[None, :, 1]
    return jnp.sqrt(rx * rx + ry * ry)


def rectangle_gap_m(corners_a: ArrayLike, corners_b: ArrayLike) -> Array:
    """Minimum Euclidean distance (m) between two rectangles given by (4, 2) corners.

    Exact: for two disjoint convex polygons the closest pair always includes a vertex of one of
    them, so the minimum over all vertex-to-edge distances in both directions is the gap. Returns
    0 when :func:`rectangles_overlap` is True (touching included).

    Returns:
        float scalar >= 0.
    """
    corners_a = jnp.asarray(corners_a, dtype=float)
    corners_b = jnp.asarray(corners_b, dtype=float)
    gap = jnp.minimum(
        jnp.min(_points_to_polygon_edges_m(corners_a, corners_b)),
        jnp.min(_points_to_polygon_edges_m(corners_b, corners_a)),
    )
    return jnp.where(rectangles_overlap(corners_a, corners_b), 0.0, gap)


def _ellipse_root(r0: Array, r0_minus_1: Array, z0: Array, z1: Array, g: Array) -> Array:
    """Root t > 0 of F(t) = (r0 z0 / (t + r0 - 1))^2 + (z1 / t)^2 - 1 by bisection.

    Eberly's robust bisection ("Distance from a point to an ellipse", 2013) in the shifted
    variable t = s + 1: near the major axis the root is close to his s = -1, where s + 1 would
    lose all its digits to cancellation. F decreases strictly on t > 0 and
    [z1, max(1, |(r0 z0, z1)|)] brackets the root (1 when the point is inside). Scalars, z0, z1 > 0.
    """
    n0 = r0 * z0
    lo = z1
    hi = jnp.where(g < 0.0, 1.0, jnp.sqrt(n0 * n0 + z1 * z1))

    def bisect(_: int, bracket: tuple[Array, Array]) -> tuple[Array, Array]:
        lo, hi = bracket
        t = 0.5 * (lo + hi)
        ratio0 = n0 / (t + r0_minus_1)
        ratio1 = z1 / t
        f = ratio0 * ratio0 + ratio1 * ratio1 - 1.0
        # F(t) == 0 collapses the bracket onto t; a collapsed bracket stays put.
        return jnp.where(f >= 0.0, t, lo), jnp.where(f <= 0.0, t, hi)

    lo, hi = jax.lax.fori_loop(0, ELLIPSE_BISECTION_STEPS, bisect, (lo, hi))
    return 0.5 * (lo + hi)


def _ellipse_distance_first_quadrant(e0: Array, e1: Array, y0: Array, y1: Array) -> Array:
    """Unsigned distance from (y0, y1), both >= 0, to the ellipse with semi-axes e0 >= e1 > 0."""
    # Within AXIS_SNAP_REL * e1 of the major axis the root t ~ y1/e1 is too small for a bisection
    # of fixed length to resolve; the distance is 1-Lipschitz in the point, so treating the point
    # as on the axis costs at most y1 <= AXIS_SNAP_REL * e1.
    y1 = jnp.where(y1 > AXIS_SNAP_REL * e1, y1, 0.0)

    # General case y0 > 0, y1 > 0. Divisions are guarded so the unused branches stay finite.
    safe_y0 = jnp.where(y0 > 0.0, y0, 1.0)
    safe_y1 = jnp.where(y1 > 0.0, y1, 1.0)
    z0, z1 = safe_y0 / e0, safe_y1 / e1
    g = z0 * z0 + z1 * z1 - 1.0
    r0 = (e0 / e1) ** 2
    r0_minus_1 = (e0 - e1) * (e0 + e1) / (e1 * e1)  # without cancellation for e0 close to e1
    t = _ellipse_root(r0, r0_minus_1, z0, z1, g)
    x0 = r0 * safe_y0 / (t + r0_minus_1)
    x1 = safe_y1 / t
    d_general = jnp.where(g == 0.0, 0.0, jnp.sqrt((x0 - safe_y0) ** 2 + (x1 - safe_y1) ** 2))

    # On the minor axis (y0 == 0, y1 > 0): the closest point is the co-vertex (0, e1).
    d_minor_axis = jnp.abs(y1 - e1)

    # On the major axis (y1 == 0): inside the evolute cusp the closest point leaves the axis.
    numer0 = e0 * y0
    denom0 = e0 * e0 - e1 * e1
    xde0 = numer0 / jnp.where(denom0 > 0.0, denom0, 1.0)
    inside_cusp = numer0 < denom0
    xde0 = jnp.where(inside_cusp, xde0, 0.0)
    x0_cusp = e0 * xde0
    x1_cusp = e1 * jnp.sqrt(1.0 - xde0 * xde0)
    d_major_axis = jnp.where(inside_cusp, jnp.sqrt((x0_cusp - y0) ** 2 + x1_cusp * x1_cusp), jnp.abs(y0 - e0))

    return jnp.where(y1 > 0.0, jnp.where(y0 > 0.0, d_general, d_minor_axis), d_major_axis)


def ellipse_signed_distance_m(px_m: ArrayLike, py_m: ArrayLike, a_m: ArrayLike, b_m: ArrayLike) -> Array:
    """Signed Euclidean distance (m) from a point to the ellipse (x/a)^2 + (y/b)^2 = 1.

    Args:
        px_m, py_m: the point relative to the ellipse centre, in the ellipse's (axis-aligned)
            frame, scalars.
        a_m, b_m: semi-axes along x and y (> 0), scalars; either may be the larger.

    Returns:
        float scalar: positive outside, negative inside, 0 on the ellipse. Exact to rounding
        (about 1e-15 relative to the point's distance from the centre), by Eberly's robust
        bisection with a fixed number of steps; the centre and the axes are handled in closed
        form, and a point within AXIS_SNAP_REL * min(a, b) of the major axis is treated as on it
        (an error of at most 1e-12 * min(a, b)).
    """
    px, py = jnp.asarray(px_m, dtype=float), jnp.asarray(py_m, dtype=float)
    a, b = jnp.asarray(a_m, dtype=float), jnp.asarray(b_m, dtype=float)
    # Eberly's algorithm wants the major axis first; by symmetry only |px|, |py| matter.
    swap = a < b
    e0, e1 = jnp.where(swap, b, a), jnp.where(swap, a, b)
    y0, y1 = jnp.abs(jnp.where(swap, py, px)), jnp.abs(jnp.where(swap, px, py))
    dist = _ellipse_distance_first_quadrant(e0, e1, y0, y1)
    inside = (y0 / e0) ** 2 + (y1 / e1) ** 2 < 1.0
    return jnp.where(inside, -dist, dist)
