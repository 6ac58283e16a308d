"""Varying-level control barrier function (VL-CBF) primitives (paper def.VL-CBF,
thm.VL-CBF_levelset, eq.two_way_value_function_e/_o).

Notation: ``lambdas`` = (lambda_0, lambda_1, ..., lambda_m), shape (m + 1,); ``lambdas_m`` =
(lambda_1, ..., lambda_m), shape (m,). The order m is static (read from the array shape).
kappa~(h) = sum_i lambda_i h^(2i-1) is strictly increasing and odd when every lambda_i >= 0 and
one is > 0 (the paper's class K_e function); Lambda H(h) = lambda_0 + kappa~(h).

The JAX functions handle one episode, are jit- and vmap-able and also accept Python floats and
tuples. The ``*_np`` functions do the same in plain Python floats (no JAX) for campaign
validation; they use the same algorithm and agree with the JAX ones to rounding.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TypeAlias

import jax
import jax.numpy as jnp

from mcverify.sim.vehicles import ego_derivative

Array: TypeAlias = jax.Array
ArrayLike: TypeAlias = jax.typing.ArrayLike

#: Bisection steps of :func:`kappa_tilde_inverse`. The starting bracket [0, B] has B <= m |root|
#: (see :func:`_root_upper_bound`), so 64 halvings leave a relative width below 2m * 5.4e-20.
KAPPA_INVERSE_STEPS: int = 64


# ---------------------------------------------------------------------------- value functions


def h_ellipse(
    ego_x_m: ArrayLike, ego_y_m: ArrayLike, front_x_m: ArrayLike, front_y_m: ArrayLike, a_m: ArrayLike, b_m: ArrayLike
) -> Array:
    """Ellipse barrier to the front vehicle: ((x_e - x_f)/a)^2 + ((y_e - y_f)/b)^2 - 1.

    Dimensionless scalar: >= 0 outside the ellipse of semi-axes a_m (along x), b_m (along y)
    centred on the front vehicle.
    """
    return ((ego_x_m - front_x_m) / a_m) ** 2 + ((ego_y_m - front_y_m) / b_m) ** 2 - 1.0


def h_ellipse_dot(
    ego_state: ArrayLike,
    u: ArrayLike,
    front_xyv: ArrayLike,
    front_accel_mps2: ArrayLike,
    a_m: ArrayLike,
    b_m: ArrayLike,
    l_r_m: ArrayLike,
) -> Array:
    """Total time derivative (1/s) of :func:`h_ellipse` along the ego kinematic bicycle and the
    front double integrator (front vehicle moving along x at constant y).

    Args:
        ego_state: (4,) [x_m, y_m, psi_rad, speed_mps]; u: (2,) [alpha_mps2, beta_rad].
        front_xyv: (3,) front [x_m, y_m, speed_mps].
        front_accel_mps2: the front vehicle's acceleration. h depends on positions only (relative
            degree 1), so it does not enter hdot; it is accepted to keep one signature for the
            barrier derivatives.
        a_m, b_m, l_r_m: ellipse semi-axes and the ego's rear-axle-to-c.g. distance (m).
    """
    del front_accel_mps2  # relative degree 1: positions only
    ego_state = jnp.asarray(ego_state, dtype=float)
    front_xyv = jnp.asarray(front_xyv, dtype=float)
    ego_rate = ego_derivative(ego_state, u, l_r_m)
    dx = ego_state[0] - front_xyv[0]
    dy = ego_state[1] - front_xyv[1]
    return 2.0 * dx * (ego_rate[0] - front_xyv[2]) / a_m**2 + 2.0 * dy * ego_rate[1] / b_m**2


def h_longitudinal(
    x_e_m: ArrayLike, v_e_mps: ArrayLike, x_o_m: ArrayLike, v_o_mps: ArrayLike, a_l_mps2: ArrayLike
) -> Array:
    """Two-way value function x_o - x_e - (v_e - v_o)^2 / (2 a_l) (m), eq.two_way_value_function_e
    (eq.two_way_value_function_o is the same expression).

    Speeds are signed road-frame x-velocities (an opposing vehicle driving towards the ego has
    v_o < 0); v_e is the ego's x-velocity xdot_e, not its speed. a_l_mps2 > 0: maximum deceleration.
    """
    return x_o_m - x_e_m - (v_e_mps - v_o_mps) ** 2 / (2.0 * a_l_mps2)


def h_longitudinal_dot(
    v_e_mps: ArrayLike, v_o_mps: ArrayLike, accel_e_mps2: ArrayLike, accel_o_mps2: ArrayLike, a_l_mps2: ArrayLike
) -> Array:
    """Time derivative (m/s) of :func:`h_longitudinal`: v_o - v_e - (v_e - v_o)(alpha_e - alpha_o)/a_l.

    accel_e_mps2 is the ego's x-acceleration xddot_e (the paper's alpha_e^x), accel_o_mps2 the
    opposing vehicle's (signed, road frame).
    """
    return v_o_mps - v_e_mps - (v_e_mps - v_o_mps) * (accel_e_mps2 - accel_o_mps2) / a_l_mps2


# ------------------------------------------------------------------------- VL-CBF polynomial


def _odd_polynomial(coeffs: Array, h: Array) -> Array:
    """sum_k coeffs[k] h^(2k+1) by Horner's rule in h^2 (no pow: exact signs for h < 0)."""
    h_sq = h * h
    acc = coeffs[-1] * jnp.ones_like(h)
    for k in range(coeffs.shape[0] - 2, -1, -1):  # static unroll over the order m
        acc = coeffs[k] + h_sq * acc
    return h * acc


def kappa_tilde(lambdas_m: ArrayLike, h: ArrayLike) -> Array:
    """kappa~(h) = sum_{i=1..m} lambda_i h^(2i-1); lambdas_m: (m,), m >= 1; h: scalar."""
    lambdas_m = jnp.asarray(lambdas_m, dtype=float)
    if lambdas_m.ndim != 1 or lambdas_m.shape[0] < 1:
        raise ValueError(f"lambdas_m must have shape (m,) with m >= 1, got {lambdas_m.shape}")
    return _odd_polynomial(lambdas_m, jnp.asarray(h, dtype=float))


def lambda_H(lambdas: ArrayLike, h: ArrayLike) -> Array:  # noqa: N802 - the paper's Lambda H
    """Lambda H(h) = lambda_0 + sum_{i=1..m} lambda_i h^(2i-1); lambdas: (m + 1,), m >= 1."""
    lambdas = jnp.asarray(lambdas, dtype=float)
    return lambdas[0] + kappa_tilde(lambdas[1:], h)


def _root_upper_bound(lambdas_m: Array, target: Array) -> Array:
    """B >= 0 with kappa~(B) >= target >= 0, and B <= 2 m * root.

    Each term alone satisfies lambda_i r^(2i-1) <= kappa~(r) = target, so the root r is at most
    (target/lambda_i)^(1/(2i-1)) for every i with lambda_i > 0; the smallest of these bounds is
    within a factor m of r because the largest term is at least target/m. The factor 2 keeps the
    root inside the bracket despite the rounding of the fractional power.
    """
    exponents = 1.0 / (2.0 * jnp.arange(lambdas_m.shape[0]) + 1.0)
    positive = lambdas_m > 0.0
    ratios = target / jnp.where(positive, lambdas_m, 1.0)
    bounds = jnp.where(positive, ratios**exponents, jnp.inf)
    return 2.0 * jnp.min(bounds)


def kappa_tilde_inverse(lambdas_m: ArrayLike, value: ArrayLike) -> Array:
    """The unique real h with kappa~(h) = value.

    Requires lambda_i >= 0 with at least one > 0 (then kappa~ is odd and strictly increasing);
    gives NaN when all are zero. Bisection on [0, B] for |value| with a fixed number of steps
    (jittable), relative accuracy about 1e-16 for any magnitude; the sign is restored by oddness.

    Args:
        lambdas_m: (m,) [lambda_1, ..., lambda_m]; value: scalar.
    """
    lambdas_m = jnp.asarray(lambdas_m, dtype=float)
    value = jnp.asarray(value, dtype=float)
    target = jnp.abs(value)

    def bisect(_: int, bracket: tuple[Array, Array]) -> tuple[Array, Array]:
        lo, hi = bracket
        mid = 0.5 * (lo + hi)
        below = kappa_tilde(lambdas_m, mid) < target
        return jnp.where(below, mid, lo), jnp.where(below, hi, mid)

    hi = _root_upper_bound(lambdas_m, target)
    lo, hi = jax.lax.fori_loop(0, KAPPA_INVERSE_STEPS, bisect, (jnp.zeros_like(hi), hi))
    return jnp.sign(value) * 0.5 * (lo + hi)


def lambda0_from_epsilon(lambdas_m: ArrayLike, epsilon: ArrayLike) -> Array:
    """Level parameter lambda_0 = -kappa~(epsilon) that makes {h >= epsilon} forward invariant
    (proof of thm.VL-CBF_levelset)."""
    return -kappa_tilde(lambdas_m, epsilon)


def epsilon_from_lambda0(lambdas_m: ArrayLike, lambda0: ArrayLike) -> Array:
    """The level epsilon = kappa~^-1(-lambda_0) enforced by a given lambda_0."""
    return kappa_tilde_inverse(lambdas_m, -jnp.asarray(lambda0, dtype=float))


def cbf_residual(hdot: ArrayLike, lambdas: ArrayLike, h: ArrayLike) -> Array:
    """hdot + Lambda H(h); >= 0 means the VL-CBF condition (eq.VL-CBF / K_vlcbf) holds."""
    return hdot + lambda_H(lambdas, h)


def invariance_breach(h_series: ArrayLike, epsilon: ArrayLike, tol: ArrayLike = 0.0) -> Array:
    """Whether a trajectory breaks the forward invariance of C_eps = {h >= epsilon}.

    True when h_series[0] >= epsilon and some later sample falls below epsilon - tol. A series
    that starts below epsilon is never a breach: thm.VL-CBF_levelset only speaks of x(0) in
    C_eps (from below, h is only required to rise). NaN samples never count as below.

    Args:
        h_series: (T,) barrier values along one trajectory, T >= 1.
        epsilon: the level; tol >= 0: slack for integration/rounding error.

    Returns:
        bool scalar.
    """
    h_series = jnp.asarray(h_series, dtype=float)
    return (h_series[0] >= epsilon) & jnp.any(h_series < epsilon - tol)


# --------------------------------------------------------------- plain-Python (no JAX) versions


def _check_lambdas_np(lambdas_m: Sequence[float]) -> list[float]:
    lams = [float(v) for v in lambdas_m]
    if not lams:
        raise ValueError("lambdas_m must hold at least lambda_1 (m >= 1)")
    if any(not math.isfinite(v) or v < 0.0 for v in lams) or max(lams) <= 0.0:
        raise ValueError(f"lambdas_m must be finite, >= 0 and not all zero, got {tuple(lams)}")
    return lams


def kappa_tilde_np(lambdas_m: Sequence[float], h: float) -> float:
    """:func:`kappa_tilde` in plain Python floats."""
    lams = [float(v) for v in lambdas_m]
    h_sq = h * h
    acc = lams[-1]
    for lam in reversed(lams[:-1]):
        acc = lam + h_sq * acc
    return h * acc


def kappa_tilde_inverse_np(lambdas_m: Sequence[float], value: float) -> float:
    """:func:`kappa_tilde_inverse` in plain Python floats.

    Raises:
        ValueError: when a lambda_i is negative or non-finite, or all are zero.
    """
    lams = _check_lambdas_np(lambdas_m)
    target = abs(float(value))
    lo = 0.0
    hi = 2.0 * min((target / lam) ** (1.0 / (2 * i + 1)) for i, lam in enumerate(lams) if lam > 0.0)
    for _ in range(KAPPA_INVERSE_STEPS):
        mid = 0.5 * (lo + hi)
        if kappa_tilde_np(lams, mid) < target:
            lo = mid
        else:
            hi = mid
    return math.copysign(0.5 * (lo + hi), value) if value != 0.0 else 0.0


def lambda0_from_epsilon_np(lambdas_m: Sequence[float], epsilon: float) -> float:
    """:func:`lambda0_from_epsilon` in plain Python floats (validates lambdas_m)."""
    return -kappa_tilde_np(_check_lambdas_np(lambdas_m), float(epsilon))


def epsilon_from_lambda0_np(lambdas_m: Sequence[float], lambda0: float) -> float:
    """:func:`epsilon_from_lambda0` in plain Python floats (validates lambdas_m)."""
    return kappa_tilde_inverse_np(lambdas_m, -float(lambda0))
