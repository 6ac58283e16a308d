"""Vehicle dynamics: the ego kinematic bicycle and the double integrator of the other vehicles.

Pure plant models, nothing else: input and state bounds are the controller's business and the
speed caps of the front/opposing vehicles are the caller's. States are plain float arrays so the
integrators stay generic; every function handles a single episode and is jit- and vmap-able.

Units: metres, seconds, radians; speeds in m/s, accelerations in m/s^2.

Bit-for-bit reproducibility: on CPUs with FMA3, XLA contracts a*b + c into fused multiply-adds
differently for a vmapped batch and for a single episode (it depends on the batch size and on the
row's position), so results agree only to the last bit or two. Running with
``XLA_FLAGS=--xla_cpu_max_isa=AVX`` (set before JAX's backend starts) removes the contraction and
makes a batched row bit-identical to the same episode run alone under jit
(tests/sim/test_vehicles.py::test_vmap_bit_identical_to_single_episode_without_fma).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeAlias

import jax
import jax.numpy as jnp

Array: TypeAlias = jax.Array
ArrayLike: TypeAlias = jax.typing.ArrayLike

#: ``deriv_fn(state, u) -> dstate/dt``, same shape as ``state``.
DerivFn: TypeAlias = Callable[[Array, ArrayLike], Array]


def ego_derivative(state: ArrayLike, u: ArrayLike, l_r_m: ArrayLike) -> Array:
    """Time derivative of the ego kinematic bicycle (paper eq.kinematic_bicycle).

    Args:
        state: (4,) [x_m, y_m, psi_rad, speed_mps] of the c.g. in the road frame.
        u: (2,) [alpha_mps2 (c.g. acceleration), beta_rad (slip angle)].
        l_r_m: rear axle to c.g. distance (m), scalar.

    Returns:
        (4,) [xdot (m/s), ydot (m/s), psidot (rad/s), vdot (m/s^2)]. The model is the paper's
        control-affine one (small slip angle: cos beta ~ 1, sin beta ~ beta), not the exact bicycle.
    """
    state = jnp.asarray(state)
    u = jnp.asarray(u)
    psi, v = state[2], state[3]
    alpha, beta = u[0], u[1]
    cos_psi, sin_psi = jnp.cos(psi), jnp.sin(psi)
    return jnp.stack(
        [
            v * cos_psi - v * sin_psi * beta,
            v * sin_psi + v * cos_psi * beta,
            v / l_r_m * beta,
            alpha,
        ]
    )


def double_integrator_derivative(state: ArrayLike, accel: ArrayLike) -> Array:
    """Time derivative of the along-road double integrator (paper eq.double_integrator).

    Args:
        state: (2,) [x_m, speed_mps].
        accel: longitudinal acceleration (m/s^2), scalar (a (1,) array is accepted too).

    Returns:
        (2,) [xdot (m/s), vdot (m/s^2)].
    """
    state = jnp.asarray(state)
    accel = jnp.reshape(jnp.asarray(accel, dtype=state.dtype), ())
    return jnp.stack([state[1], accel])


def rk4_step(deriv_fn: DerivFn, state: ArrayLike, u: ArrayLike, dt_s: ArrayLike) -> Array:
    """One classical Runge-Kutta 4 step of ``deriv_fn`` with the input ``u`` held constant.

    Args:
        deriv_fn: ``deriv_fn(state, u) -> dstate/dt`` (shape of ``state``).
        state: (n,) state at the start of the step.
        u: input held over the step (any shape ``deriv_fn`` accepts).
        dt_s: step length (s), scalar.

    Returns:
        (n,) state after ``dt_s``.
    """
    state = jnp.asarray(state)
    k1 = deriv_fn(state, u)
    k2 = deriv_fn(state + 0.5 * dt_s * k1, u)
    k3 = deriv_fn(state + 0.5 * dt_s * k2, u)
    k4 = deriv_fn(state + dt_s * k3, u)
    return state + (dt_s / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def integrate_zoh(
    deriv_fn: DerivFn, state: ArrayLike, u: ArrayLike, period_s: ArrayLike, substeps: int
) -> tuple[Array, Array]:
    """Integrate one control period under zero-order hold with ``substeps`` RK4 steps.

    Args:
        deriv_fn: ``deriv_fn(state, u) -> dstate/dt``.
        state: (n,) state at the start of the period.
        u: input held over the whole period.
        period_s: control period (s), scalar; each sub-step lasts ``period_s / substeps``.
        substeps: number of RK4 sub-steps (static Python int >= 1).

    Returns:
        ``(final_state (n,), states (substeps, n))`` where ``states[k]`` is the state after sub-step
        k + 1 (so ``states[-1] == final_state``); callers evaluate their safety checks on every row.
    """
    if substeps < 1:
        raise ValueError(f"substeps must be >= 1, got {substeps}")
    dt_s = period_s / substeps

    def body(x: Array, _: None) -> tuple[Array, Array]:
        x_next = rk4_step(deriv_fn, x, u, dt_s)
        return x_next, x_next

    return jax.lax.scan(body, jnp.asarray(state), None, length=substeps)
