"""VL-CBF primitives: derivatives against autodiff, the kappa~ inverse against scipy's brentq, and a
continuous-time check of Theorem thm.VL-CBF_levelset with solve_ivp."""

from __future__ import annotations

import functools
import math

import cbf_reference
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from mcverify import levels
from mcverify.model import Barrier
from mcverify.sim import barriers
from mcverify.sim.vehicles import ego_derivative

L_R = 1.4
A, B = Barrier().ellipse_a_m, Barrier().ellipse_b_m
LAMBDA_SETS = [(1.0,), (1.0, 0.5), (0.3, 2.0, 0.05)]






def kappa_np(lambdas_m, h: float) -> float:
    """Independent reference: explicit odd powers."""
    return sum(lam * h ** (2 * i + 1) for i, lam in enumerate(lambdas_m))


def random_scene(rng: np.random.Generator, n: int):
    ego = np.column_stack(
        [rng.uniform(0, 100, n), rng.uniform(-1, 4.5, n), rng.uniform(-0.35, 0.35, n), rng.uniform(0, 20, n)]
    )
    u = np.column_stack([rng.uniform(-6, 3, n), rng.uniform(-0.15, 0.15, n)])
    front = np.column_stack([ego[:, 0] + rng.uniform(-20, 20, n), rng.uniform(-0.5, 0.5, n), rng.uniform(0, 20, n)])
    return ego, u, front, rng.uniform(-2, 2, n)


# ---------------------------------------------------------------------------- value functions


def test_h_ellipse_values() -> None:
    assert float(barriers.h_ellipse(0.0, 0.0, 0.0, 0.0, A, B)) == -1.0
    assert float(barriers.h_ellipse(A, 0.0, 0.0, 0.0, A, B)) == pytest.approx(0.0, abs=1e-15)
    assert float(barriers.h_ellipse(10.0, 3.0, 7.0, -1.0, 3.0, 2.0)) == pytest.approx(1.0 + 4.0 - 1.0)


def test_h_ellipse_dot_vs_autodiff() -> None:
    """hdot = dh/dz . f(z) along the bicycle and the front double integrator, via jax.jvp."""
    ego, u, front, front_accel = random_scene(np.random.default_rng(20), 50)

    def by_jvp(e, uu, f, af):
        z = jnp.concatenate([e, f[jnp.array([0, 2])]])  # [x, y, psi, v, x_f, v_f]; y_f is constant
        rate = jnp.concatenate([ego_derivative(e, uu, L_R), jnp.stack([f[2], af])])
        h = lambda zz: barriers.h_ellipse(zz[0], zz[1], zz[4], f[1], A, B)  # noqa: E731
        return jax.jvp(h, (z,), (rate,))[1]

    got = jax.vmap(functools.partial(cbf_reference.h_ellipse_dot, a_m=A, b_m=B, l_r_m=L_R))(ego, u, front, front_accel)
    want = jax.vmap(by_jvp)(ego, u, front, front_accel)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)


def test_h_longitudinal_and_its_derivative_vs_autodiff() -> None:
    rng = np.random.default_rng(21)
    z = rng.uniform([0, 0, 50, -20], [50, 20, 200, 0], (40, 4))  # x_e, v_e, x_o, v_o (opposing: v_o < 0)
    acc = rng.uniform(-6, 3, (40, 2))
    a_l = 6.0
    assert float(barriers.h_longitudinal(0.0, 10.0, 100.0, -10.0, 5.0)) == pytest.approx(100.0 - 400.0 / 10.0)

    def by_jvp(zz, aa):
        h = lambda s: barriers.h_longitudinal(s[0], s[1], s[2], s[3], a_l)  # noqa: E731
        return jax.jvp(h, (zz,), (jnp.stack([zz[1], aa[0], zz[3], aa[1]]),))[1]

    got = jax.vmap(lambda zz, aa: cbf_reference.h_longitudinal_dot(zz[1], zz[3], aa[0], aa[1], a_l))(z, acc)
    np.testing.assert_allclose(got, jax.vmap(by_jvp)(z, acc), rtol=1e-12, atol=1e-12)


# ------------------------------------------------------------------------------- polynomial


@pytest.mark.parametrize("lambdas_m", [*LAMBDA_SETS, (0.4, 0.0, 1.0, 0.2)])
def test_lambda_h_and_kappa_vs_explicit_powers(lambdas_m) -> None:
    hs = np.concatenate([-np.logspace(-4, 1.5, 20), [0.0], np.logspace(-4, 1.5, 20)])
    lambdas = np.array([-0.37, *lambdas_m])
    got_k = np.asarray(jax.vmap(barriers.kappa_tilde, in_axes=(None, 0))(np.array(lambdas_m), hs))
    got_h = np.asarray(jax.vmap(barriers.lambda_H, in_axes=(None, 0))(lambdas, hs))
    want = np.array([kappa_np(lambdas_m, h) for h in hs])
    np.testing.assert_allclose(got_k, want, rtol=1e-14, atol=1e-300)
    np.testing.assert_allclose(got_h, -0.37 + want, rtol=1e-14, atol=1e-15)
    assert got_k[0] < 0 < got_k[-1]  # odd: exact signs for h < 0 (no pow of a negative base)


def test_kappa_rejects_bad_shape() -> None:
    with pytest.raises(ValueError, match="shape"):
        barriers.kappa_tilde(np.zeros((0,)), 1.0)


@pytest.mark.parametrize("lambdas_m", LAMBDA_SETS)
def test_kappa_inverse_round_trips_and_matches_brentq(lambdas_m) -> None:
    lams = jnp.array(lambdas_m)
    inverse = jax.jit(jax.vmap(cbf_reference.kappa_tilde_inverse, in_axes=(None, 0)))
    kappa = jax.jit(jax.vmap(barriers.kappa_tilde, in_axes=(None, 0)))

    values = np.concatenate([-np.logspace(-10, 10, 41), [0.0], np.logspace(-10, 10, 41)])
    roots = np.asarray(inverse(lams, values))
    np.testing.assert_allclose(np.asarray(kappa(lams, roots)), values, rtol=1e-12, atol=0)
    for v, r in zip(values[::5], roots[::5], strict=True):
        span = 1.0 + abs(v) / lambdas_m[0]
        ref = brentq(lambda h, v=v: kappa_np(lambdas_m, h) - v, -span, span, xtol=1e-300, rtol=1e-15)
        assert r == pytest.approx(ref, rel=1e-12, abs=0)

    hs = np.concatenate([-np.logspace(-8, 3, 30), np.logspace(-8, 3, 30)])
    np.testing.assert_allclose(np.asarray(inverse(lams, np.asarray(kappa(lams, hs)))), hs, rtol=1e-12, atol=0)


def test_kappa_inverse_with_zero_lambdas() -> None:
    assert float(cbf_reference.kappa_tilde_inverse(jnp.array([0.0, 1.0]), 8.0)) == pytest.approx(2.0, rel=1e-14)
    assert float(cbf_reference.kappa_tilde_inverse(jnp.array([2.0, 0.0]), -3.0)) == pytest.approx(-1.5, rel=1e-14)
    assert levels.kappa_tilde_inverse([0.0, 1.0], -27.0) == pytest.approx(-3.0, rel=1e-14)
    assert not np.isfinite(float(cbf_reference.kappa_tilde_inverse(jnp.array([0.0, 0.0]), 1.0)))


@pytest.mark.parametrize("lambdas_m", LAMBDA_SETS)
def test_lambda0_epsilon_round_trip_jax_and_python(lambdas_m) -> None:
    for eps in (0.0, 1e-6, 0.3, 1.0, 7.5):
        lam0 = cbf_reference.lambda0_from_epsilon(lambdas_m, eps)  # tuples and Python floats accepted
        assert float(lam0) <= 0.0
        assert float(cbf_reference.epsilon_from_lambda0(lambdas_m, lam0)) == pytest.approx(eps, rel=1e-12, abs=1e-300)
        lam0_np = levels.lambda0_from_epsilon(lambdas_m, eps)
        assert isinstance(lam0_np, float) and lam0_np == pytest.approx(float(lam0), rel=1e-15, abs=0)
        eps_np = levels.epsilon_from_lambda0(lambdas_m, lam0_np)
        assert isinstance(eps_np, float) and eps_np == pytest.approx(eps, rel=1e-12, abs=1e-300)


def test_default_barrier_level() -> None:
    bar = Barrier()
    assert levels.lambda0_from_epsilon(bar.lambdas_m, bar.epsilon) == pytest.approx(-(0.3 + 0.5 * 0.3**3))


@pytest.mark.parametrize("bad", [(), (-1.0, 1.0), (0.0, 0.0), (math.nan,)])
def test_python_versions_validate_lambdas(bad) -> None:
    with pytest.raises(ValueError, match="lambdas_m"):
        levels.epsilon_from_lambda0(bad, -0.3)
    with pytest.raises(ValueError, match="lambdas_m"):
        levels.lambda0_from_epsilon(bad, 0.3)


def test_cbf_residual() -> None:
    lambdas = jnp.array([-0.3135, 1.0, 0.5])
    assert float(cbf_reference.cbf_residual(-0.2, lambdas, 0.3)) == pytest.approx(-0.2, abs=1e-15)
    assert float(cbf_reference.cbf_residual(0.0, lambdas, 1.0)) == pytest.approx(1.5 - 0.3135)


# ------------------------------------------------------------------------------- invariance


@pytest.mark.parametrize(
    ("series", "tol", "breach"),
    [
        ([1.0, 0.5, 0.31, 0.3, 0.4], 0.0, False),
        ([1.0, 0.5, 0.29, 0.4], 0.0, True),
        ([1.0, 0.5, 0.29, 0.4], 0.02, False),  # within tolerance
        ([0.3, 0.3, 0.3], 0.0, False),  # starts exactly on the level
        ([0.1, -0.5, 0.2], 0.0, False),  # starts below the level: not the theorem's business
        ([1.0, math.nan, 0.5], 0.0, False),
        ([1.0], 0.0, False),
    ],
)
def test_invariance_breach(series, tol, breach) -> None:
    assert bool(jax.jit(cbf_reference.invariance_breach)(jnp.array(series), 0.3, tol)) is breach


def closed_loop_h(lambdas_m, eps: float, h0: float, u_nominal: float, t_end: float = 25.0):
    """hdot = u, u = max(u_nominal, -Lambda H(h)): the least input the VL-CBF condition allows,
    or a nominal one when it already satisfies it (a Lipschitz safety filter)."""
    lam0 = float(cbf_reference.lambda0_from_epsilon(lambdas_m, eps))

    def rhs(t, h):
        return [max(u_nominal, -(lam0 + kappa_np(lambdas_m, h[0])))]

    sol = solve_ivp(rhs, (0.0, t_end), [h0], method="DOP853", rtol=1e-10, atol=1e-12, max_step=0.1)
    return sol.y[0], np.array([rhs(0.0, [h])[0] for h in sol.y[0]]), lam0


@pytest.mark.parametrize("lambdas_m", LAMBDA_SETS)
@pytest.mark.parametrize("u_nominal", [-math.inf, -5.0])
def test_theorem_levelset_forward_invariance(lambdas_m, u_nominal: float) -> None:
    eps = 0.3
    for h0 in (eps, 1.0, 4.0):
        h, hdot, lam0 = closed_loop_h(lambdas_m, eps, h0, u_nominal)
        assert h.min() >= eps - 1e-9  # never below the level
        assert h[-1] == pytest.approx(eps, abs=1e-6)  # and converges to it from above
        assert not bool(cbf_reference.invariance_breach(jnp.asarray(h), eps, 1e-9))
        residual = np.asarray(cbf_reference.cbf_residual(hdot, jnp.array([lam0, *lambdas_m]), h))  # element-wise
        assert residual.min() >= -1e-12
    # From below the level h only has to rise; it approaches eps without crossing it.
    h, _, _ = closed_loop_h(lambdas_m, eps, -0.5, u_nominal)
    assert np.all(np.diff(h) >= -1e-12) and h.max() <= eps + 1e-9 and h[-1] == pytest.approx(eps, abs=1e-6)


def test_violating_input_is_a_breach() -> None:
    lambdas_m, eps = (1.0, 0.5), 0.3
    lam0 = float(cbf_reference.lambda0_from_epsilon(lambdas_m, eps))
    sol = solve_ivp(lambda t, h: [-(lam0 + kappa_np(lambdas_m, h[0])) - 0.1], (0.0, 20.0), [1.0], rtol=1e-10)
    assert bool(cbf_reference.invariance_breach(jnp.asarray(sol.y[0]), eps, 1e-6))


# ----------------------------------------------------------------------------- vmap vs loop


def test_vmap_matches_loop(assert_batch_equals_loop) -> None:
    ego, u, front, front_accel = random_scene(np.random.default_rng(22), 24)
    hdot = jax.jit(functools.partial(cbf_reference.h_ellipse_dot, a_m=A, b_m=B, l_r_m=L_R))
    batched = np.asarray(jax.jit(jax.vmap(hdot))(ego, u, front, front_accel))
    assert_batch_equals_loop(batched, np.array([hdot(*row) for row in zip(ego, u, front, front_accel, strict=True)]))

    lams = jnp.array([-0.3135, 1.0, 0.5])
    hs = ego[:, 1] - 1.0
    for fn in (
        jax.jit(lambda h: barriers.lambda_H(lams, h)),
        jax.jit(lambda h: cbf_reference.kappa_tilde_inverse(lams[1:], h)),
        jax.jit(lambda h: barriers.h_ellipse(h, 0.3, 1.0, -0.2, A, B)),
    ):
        assert_batch_equals_loop(np.asarray(jax.jit(jax.vmap(fn))(hs)), np.array([fn(h) for h in hs]))

    series = np.random.default_rng(23).uniform(0.0, 1.0, (24, 30))
    breach = jax.jit(lambda s: cbf_reference.invariance_breach(s, 0.3, 0.01))
    np.testing.assert_array_equal(jax.vmap(breach)(series), [breach(s) for s in series])
