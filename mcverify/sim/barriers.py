"""Varying-level control barrier function (VL-CBF) primitives (paper def.VL-CBF,
thm.VL-CBF_levelset, eq.two_way_value_function_e/_o).

Notation: ``lambdas`` = (lambda_0, lambda_1, ..., lambda_m), shape (m + 1,); ``lambdas_m`` =
(lambda_1, ..., lambda_m), shape (m,). The order m is static (read from the array shape).
kappa~(h) = sum_i lambda_i h^(2i-1) is strictly increasing and odd when every lambda_i >= 0 and
one is > 0 (the paper's class K_e function); Lambda H(h) = lambda_0 + kappa~(h).

The functions handle one episode, are jit- and vmap-able and also accept Python floats and
tuples. The level conversions (lambda_0 <-> epsilon) in plain floats are in :mod:`mcverify.levels`.
"""

from __future__ import annotations

from typing import TypeAlias

import jax
import jax.numpy as jnp

Array: TypeAlias = jax.Array
ArrayLike: TypeAlias = jax.typing.ArrayLike

# ---------------------------------------------------------------------------- value functions


def h_ellipse(
    ego_x_m: ArrayLike, ego_y_m: ArrayLike, front_x_m: ArrayLike, front_y_m: ArrayLike, a_m: ArrayLike, b_m: ArrayLike
) -> Array:
    """Ellipse barrier to the front vehicle: ((x_e - x_f)/a)^2 + ((y_e - y_f)/b)^2 - 1.

    Dimensionless scalar: >= 0 outside the ellipse of semi-axes a_m (along x), b_m (along y)
    centred on the front vehicle.
    """
    return ((ego_x_m - front_x_m) / a_m) ** 2 + ((ego_y_m - front_y_m) / b_m) ** 2 - 1.0


def h_longitudinal(
    x_e_m: ArrayLike, v_e_mps: ArrayLike, x_o_m: ArrayLike, v_o_mps: ArrayLike, a_l_mps2: ArrayLike
) -> Array:
    """Two-way value function x_o - x_e - (v_e - v_o)^2 / (2 a_l) (m), eq.two_way_value_function_e
    (eq.two_way_value_function_o is the same expression).

    Speeds are signed road-frame x-velocities (an opposing vehicle driving towards the ego has
    v_o < 0); v_e is the ego's x-velocity xdot_e, not its speed. a_l_mps2 > 0: maximum deceleration.
    """
    return x_o_m - x_e_m - (v_e_mps - v_o_mps) ** 2 / (2.0 * a_l_mps2)


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
