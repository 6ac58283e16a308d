"""Vehicle dynamics against closed forms and scipy's solve_ivp; vmap against single episodes."""

from __future__ import annotations

import functools
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from mcverify.sim import vehicles

L_R = 1.4
REPO = Path(__file__).resolve().parents[2]






def ego_rhs_np(state: np.ndarray, u: np.ndarray) -> np.ndarray:
    """eq.kinematic_bicycle written out independently in numpy."""
    _, _, psi, v = state
    alpha, beta = u
    return np.array(
        [
            v * np.cos(psi) - v * np.sin(psi) * beta,
            v * np.sin(psi) + v * np.cos(psi) * beta,
            v / L_R * beta,
            alpha,
        ]
    )


def random_ego(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    states = np.column_stack(
        [rng.uniform(0, 100, n), rng.uniform(-1, 4.5, n), rng.uniform(-0.35, 0.35, n), rng.uniform(0, 20, n)]
    )
    inputs = np.column_stack([rng.uniform(-6, 3, n), rng.uniform(-0.15, 0.15, n)])
    return states, inputs


ego_deriv = functools.partial(vehicles.ego_derivative, l_r_m=L_R)


@functools.cache
def zoh_ego(period_s: float, substeps: int):
    return jax.jit(lambda s, u: vehicles.integrate_zoh(ego_deriv, s, u, period_s, substeps))


def test_ego_derivative_matches_paper_formula() -> None:
    states, inputs = random_ego(np.random.default_rng(0), 50)
    got = np.asarray(jax.vmap(ego_deriv)(states, inputs))
    want = np.stack([ego_rhs_np(s, u) for s, u in zip(states, inputs, strict=True)])
    np.testing.assert_allclose(got, want, rtol=1e-14, atol=1e-14)


def test_double_integrator_derivative() -> None:
    np.testing.assert_array_equal(vehicles.double_integrator_derivative(jnp.array([3.0, 7.5]), -2.0), [7.5, -2.0])
    np.testing.assert_array_equal(
        vehicles.double_integrator_derivative(jnp.array([3.0, 7.5]), jnp.array([1.5])), [7.5, 1.5]
    )


def test_rk4_exact_for_double_integrator() -> None:
    # x(t) is quadratic in t under constant acceleration: RK4 is exact up to rounding.
    state, accel, dt = jnp.array([12.0, 6.94]), 1.3, 0.37
    got = vehicles.rk4_step(vehicles.double_integrator_derivative, state, accel, dt)
    np.testing.assert_allclose(got, [12.0 + 6.94 * dt + 0.5 * accel * dt**2, 6.94 + accel * dt], rtol=1e-15)


def test_integrate_zoh_shapes_and_last_row() -> None:
    final, subs = zoh_ego(0.02, 10)(jnp.array([10.0, 0.0, 0.0, 10.0]), jnp.array([1.0, 0.05]))
    assert final.shape == (4,) and subs.shape == (10, 4)
    np.testing.assert_array_equal(final, subs[-1])
    with pytest.raises(ValueError, match="substeps"):
        vehicles.integrate_zoh(ego_deriv, jnp.zeros(4), jnp.zeros(2), 0.02, 0)


def test_integrate_zoh_one_period_vs_solve_ivp() -> None:
    period, substeps = 0.02, 10
    states, inputs = random_ego(np.random.default_rng(1), 8)
    t_sub = period * np.arange(1, substeps + 1) / substeps
    for s0, u in zip(states, inputs, strict=True):
        _, subs = zoh_ego(period, substeps)(s0, u)
        ref = solve_ivp(lambda t, s, u=u: ego_rhs_np(s, u), (0.0, period), s0, t_eval=t_sub, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(np.asarray(subs), ref.y.T, rtol=0, atol=1e-10)


def test_integrate_zoh_piecewise_constant_seconds_vs_solve_ivp() -> None:
    # 3 s of piecewise-constant inputs, integrated period by period under lax.scan.
    period, substeps, n_periods = 0.02, 10, 150
    rng = np.random.default_rng(2)
    s0 = np.array([10.0, 0.0, 0.0, 10.0])
    inputs = np.column_stack([rng.uniform(-2, 2, n_periods), rng.uniform(-0.1, 0.1, n_periods)])

    @jax.jit
    def run(state, us):
        def body(s, u):
            final, _ = vehicles.integrate_zoh(ego_deriv, s, u, period, substeps)
            return final, final

        return jax.lax.scan(body, state, us)[1]

    got = np.asarray(run(s0, inputs))
    state, want = s0, []
    for u in inputs:
        sol = solve_ivp(
            lambda t, s, u=u: ego_rhs_np(s, u), (0.0, period), state, method="DOP853", rtol=1e-12, atol=1e-12
        )
        state = sol.y[:, -1]
        want.append(state)
    np.testing.assert_allclose(got, np.array(want), rtol=0, atol=1e-8)


def test_double_integrator_zoh_vs_closed_form_and_solve_ivp() -> None:
    period, substeps = 0.02, 10
    accels = np.random.default_rng(3).uniform(-3, 3, 100)  # 2 s, piecewise constant

    @jax.jit
    def run(state, us):
        def body(s, a):
            final, _ = vehicles.integrate_zoh(vehicles.double_integrator_derivative, s, a, period, substeps)
            return final, final

        return jax.lax.scan(body, state, us)[1]

    got = np.asarray(run(jnp.array([64.0, 25.0 / 3.6]), accels))
    x, v, closed = 64.0, 25.0 / 3.6, []
    for a in accels:
        x, v = x + v * period + 0.5 * a * period**2, v + a * period
        closed.append((x, v))
    np.testing.assert_allclose(got, np.array(closed), rtol=0, atol=1e-10)
    state, stepped = np.array([64.0, 25.0 / 3.6]), []
    for a in accels:  # restart at every input switch: solve_ivp needs a smooth right-hand side
        state = solve_ivp(lambda t, s, a=a: [s[1], a], (0.0, period), state, rtol=1e-12, atol=1e-12).y[:, -1]
        stepped.append(state)
    np.testing.assert_allclose(got, np.array(stepped), rtol=0, atol=1e-8)


def test_vmap_matches_loop(assert_batch_equals_loop) -> None:
    states, inputs = random_ego(np.random.default_rng(4), 64)
    singles = {
        "ego_derivative": jax.jit(ego_deriv),
        "rk4_step": jax.jit(lambda s, u: vehicles.rk4_step(ego_deriv, s, u, 0.002)),
        "integrate_zoh": jax.jit(
            lambda s, u: jnp.concatenate([a.ravel() for a in vehicles.integrate_zoh(ego_deriv, s, u, 0.02, 10)])
        ),
        "double_integrator": jax.jit(
            lambda s, u: vehicles.integrate_zoh(vehicles.double_integrator_derivative, s[2:], u[0], 0.02, 10)[1]
        ),
    }
    for name, fn in singles.items():
        batched = np.asarray(jax.jit(jax.vmap(fn))(states, inputs))
        looped = np.stack([np.asarray(fn(s, u)) for s, u in zip(states, inputs, strict=True)])
        assert batched.shape == looped.shape, name
        assert_batch_equals_loop(batched, looped)


# Runs in a fresh interpreter so that XLA_FLAGS is set before the XLA backend starts.
BIT_IDENTITY_SCRIPT = textwrap.dedent(
    """
    import functools, sys
    import jax, jax.numpy as jnp, numpy as np
    import cbf_reference
    from mcverify.model import Noise
    from mcverify.sim import barriers, geometry, noise, vehicles

    rng = np.random.default_rng(7)
    n = 28
    ego = np.column_stack([rng.uniform(0, 100, n), rng.uniform(-1, 4.5, n), rng.uniform(-0.35, 0.35, n),
                           rng.uniform(0, 20, n)])
    u = np.column_stack([rng.uniform(-6, 3, n), rng.uniform(-0.15, 0.15, n)])
    front = np.column_stack([ego[:, 0] + rng.uniform(-15, 15, n), rng.uniform(0, 20, n)])
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.PRNGKey(11), i))(jnp.arange(n))
    steps = rng.integers(0, 1000, n)
    deriv = functools.partial(vehicles.ego_derivative, l_r_m=1.4)
    a, b = 6.9, 2.6

    def episode(e, uu, f, key, step):
        # One control period of the closed loop: plant, every sub-step check, noise, barrier.
        final, subs = vehicles.integrate_zoh(deriv, e, uu, 0.02, 10)
        def checks(s):
            ego_box = geometry.footprint_corners(s[0], s[1], s[2], 4.885, 1.84)
            front_box = geometry.footprint_corners(f[0], 0.0, 0.0, 4.885, 1.84)
            gap = geometry.rectangle_gap_m(ego_box, front_box)
            return jnp.stack([
                barriers.h_ellipse(s[0], s[1], f[0], 0.0, a, b),
                geometry.ellipse_signed_distance_m(s[0] - f[0], s[1], a, b),
                gap, geometry.rectangles_overlap(ego_box, front_box).astype(float),
                cbf_reference.h_ellipse_dot(s, uu, jnp.stack([f[0], 0.0, f[1]]), 0.0, a, b, 1.4),
                cbf_reference.kappa_tilde_inverse(jnp.array([1.0, 0.5]), s[1]),
                *noise.measure_vehicle(noise.step_key(key, step, 0), f[0], 0.0, f[1], gap, Noise()),
            ])
        return jnp.concatenate([final, jax.vmap(checks)(subs).ravel()])

    args = (ego, u, front, keys, steps)
    single = jax.jit(episode)
    looped = np.stack([np.asarray(single(*(x[i] for x in args))) for i in range(n)])
    bad = 0
    for size in (1, 7, n):
        batched = jax.jit(jax.vmap(episode))
        for start in range(0, n - size + 1, size):
            got = np.asarray(batched(*(x[start:start + size] for x in args)))
            bad += int(np.sum(np.any(got != looped[start:start + size], axis=1)))
    print("rows differing:", bad)
    sys.exit(1 if bad else 0)
    """
)


def test_vmap_bit_identical_to_single_episode_without_fma() -> None:
    env = dict(os.environ, XLA_FLAGS=(os.environ.get("XLA_FLAGS", "") + " --xla_cpu_max_isa=AVX").strip())
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), str(REPO / "tests"), env.get("PYTHONPATH", "")]))
    proc = subprocess.run(
        [sys.executable, "-c", BIT_IDENTITY_SCRIPT], cwd=REPO, env=env, capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
