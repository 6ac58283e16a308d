"""The other road users' behaviour laws (JAX, one episode, jit- and vmap-able).

Road frame as in :mod:`mcverify.model`: x along the ego's direction of travel. The front vehicle
veh_f drives along the ego lane centre (y = 0) in +x; the opposing vehicle veh_o along the opposing
lane centre in -x, so its road-frame velocity ``v_o`` is <= 0 and a positive road-frame
acceleration ``alpha_o`` brakes it.

Laws (all return a road-frame acceleration in m/s^2, held over one control period):

* :func:`front_accel`: veh_f accelerates at its episode's alpha_f from an onset time on, up to its
  speed cap, never switching sign (the paper's assumption on veh_f);
* :func:`human_accel`: a human driver in veh_o accelerating towards its speed limit at a fixed
  rate (0: constant speed);
* :func:`autonomous_accel`: an autonomous veh_o, its cruise law filtered by its own VL-CBF on
  h_oe (eq.tompcAdd_cbf_oe), solved exactly (a one-dimensional QP has a closed form).
"""

from __future__ import annotations

from typing import TypeAlias

import jax
import jax.numpy as jnp

from mcverify.sim.barriers import h_longitudinal, lambda_H
from mcverify.sim.vehicles import ego_derivative

Array: TypeAlias = jax.Array
ArrayLike: TypeAlias = jax.typing.ArrayLike


def front_accel(t_s: ArrayLike, accel_mps2: ArrayLike, onset_s: ArrayLike, duration_s: ArrayLike,
                speed_mps: ArrayLike, speed_max_mps: ArrayLike, dt_s: ArrayLike) -> Array:
    """veh_f's acceleration over [t_s, t_s + dt_s]: ``accel_mps2`` (>= 0) while
    onset_s <= t_s < onset_s + duration_s, cut so that its speed does not pass ``speed_max_mps``."""
    on = jnp.where((t_s >= onset_s) & (t_s < onset_s + duration_s), accel_mps2, 0.0)
    return jnp.minimum(on, jnp.maximum(speed_max_mps - speed_mps, 0.0) / dt_s)


def human_accel(v_o_mps: ArrayLike, accel_mps2: ArrayLike, speed_limit_mps: ArrayLike, dt_s: ArrayLike) -> Array:
    """A human-driven veh_o accelerating towards the ego (alpha_o = -accel) until its speed reaches
    ``speed_limit_mps``; cut so the limit is not passed within ``dt_s``. accel 0: constant speed."""
    speed = -v_o_mps
    return -jnp.minimum(accel_mps2, jnp.maximum(speed_limit_mps - speed, 0.0) / dt_s)


def ego_x_motion(ego_state: ArrayLike, u: ArrayLike, l_r_m: ArrayLike) -> tuple[Array, Array]:
    """The ego's longitudinal velocity v_e^x = xdot (m/s) and acceleration alpha_e^x = xddot (m/s^2)
    along eq.kinematic_bicycle under the held input u (the paper's symbols in eq.value_derivative)."""
    vx_fn = lambda s: ego_derivative(s, u, l_r_m)[0]  # noqa: E731
    vx, dvx = jax.jvp(vx_fn, (jnp.asarray(ego_state, dtype=float),), (ego_derivative(ego_state, u, l_r_m),))
    return vx, dvx


def ego_top_edge_m(ego_state: ArrayLike, length_m: ArrayLike, width_m: ArrayLike) -> Array:
    """Largest y (m) of the ego footprint: y + (L/2)|sin psi| + (W/2) cos psi."""
    psi = ego_state[2]
    return ego_state[1] + 0.5 * length_m * jnp.abs(jnp.sin(psi)) + 0.5 * width_m * jnp.cos(psi)


def autonomous_accel(
    opp_xv: ArrayLike,
    ego_state: ArrayLike,
    ego_u: ArrayLike,
    *,
    cruise_speed_mps: ArrayLike,
    gain_per_s: ArrayLike,
    lambdas: ArrayLike,
    decel_max_mps2: ArrayLike,
    accel_max_mps2: ArrayLike,
    brake_max_mps2: ArrayLike,
    l_r_m: ArrayLike,
    ego_in_opposing_lane: ArrayLike,
) -> Array:
    """An autonomous veh_o: min (alpha - alpha_nom)^2 s.t. its VL-CBF on h_oe, solved exactly.

    alpha_nom = gain (-cruise_speed - v_o) holds its cruise speed. While the ego's footprint is in
    the opposing lane and ahead of veh_o, eq.tompcAdd_cbf_oe,
    hdot_oe + Lambda_o H(h_oe) >= 0 with hdot_oe = v_o - v_e - (v_e - v_o)(alpha_e - alpha_o)/a_l,
    is a lower bound on alpha_o (v_e - v_o > 0): the QP's solution is the larger of alpha_nom and
    that bound, then clipped to [-accel_max, brake_max]. veh_o perceives the ego exactly (its state
    and the input it applies: vehicle-to-vehicle communication, as the paper assumes for Lambda_o).

    Args:
        opp_xv: (2,) [x_o m, v_o m/s (<= 0)]; ego_state: (4,); ego_u: (2,) the ego's held input.
        lambdas: (m+1,) Lambda_o = [lambda_0, lambda_1, ...] of veh_o's own VL-CBF (h in metres).
        ego_in_opposing_lane: bool, the ego's footprint reaches the lane line.
    """
    x_o, v_o = opp_xv[0], opp_xv[1]
    vx_e, ax_e = ego_x_motion(ego_state, ego_u, l_r_m)
    nominal = gain_per_s * (-cruise_speed_mps - v_o)
    h = h_longitudinal(ego_state[0], vx_e, x_o, v_o, decel_max_mps2)
    closing = jnp.maximum(vx_e - v_o, 0.1)
    cbf_bound = ax_e - decel_max_mps2 * (lambda_H(lambdas, h) + v_o - vx_e) / closing
    active = ego_in_opposing_lane & (ego_state[0] < x_o)
    alpha = jnp.where(active, jnp.maximum(nominal, cbf_bound), nominal)
    return jnp.clip(alpha, -accel_max_mps2, brake_max_mps2)


def stop_at_rest(v_o_mps: ArrayLike, alpha_o_mps2: ArrayLike, dt_s: ArrayLike) -> Array:
    """Limit a braking alpha_o (> 0) so that v_o (<= 0) stops at 0 within ``dt_s`` instead of reversing."""
    return jnp.minimum(alpha_o_mps2, jnp.maximum(-v_o_mps, 0.0) / dt_s)
