"""JAX references of the paper's VL-CBF theory, used by the tests to check the plant and the levels.

The plant needs only the barrier values (:mod:`mcverify.sim.barriers`); these derivatives, the
inverse of kappa~ in JAX and the invariance test are what the theorems are stated in, so the tests
check the simulation against them (Theorem 2, thm.VL-CBF_levelset; eq.VL-CBF).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from mcverify.levels import KAPPA_INVERSE_STEPS
from mcverify.sim.barriers import Array, ArrayLike, kappa_tilde, lambda_H
from mcverify.sim.vehicles import ego_derivative


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


def h_longitudinal_dot(
    v_e_mps: ArrayLike, v_o_mps: ArrayLike, accel_e_mps2: ArrayLike, accel_o_mps2: ArrayLike, a_l_mps2: ArrayLike
) -> Array:
    """Time derivative (m/s) of :func:`h_longitudinal`: v_o - v_e - (v_e - v_o)(alpha_e - alpha_o)/a_l.

    accel_e_mps2 is the ego's x-acceleration xddot_e (the paper's alpha_e^x), accel_o_mps2 the
    opposing vehicle's (signed, road frame).
    """
    return v_o_mps - v_e_mps - (v_e_mps - v_o_mps) * (accel_e_mps2 - accel_o_mps2) / a_l_mps2


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
