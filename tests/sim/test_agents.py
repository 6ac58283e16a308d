"""The other road users' laws (mcverify.sim.agents) against independent references."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mcverify.levels import lambda0_from_epsilon
from mcverify.sim import agents

LAMBDAS_O = np.array([lambda0_from_epsilon((1.0,), 1.0), 1.0])  # level 1 m, kappa~ linear
A_L = 6.0
L_R = 1.4
LAW = dict(cruise_speed_mps=15.0, gain_per_s=1.0, lambdas=LAMBDAS_O, decel_max_mps2=A_L,
           accel_max_mps2=3.0, brake_max_mps2=6.0, l_r_m=L_R)


def np_h(x_e, vx_e, x_o, v_o):
    return x_o - x_e - (vx_e - v_o) ** 2 / (2 * A_L)


def np_hdot(vx_e, ax_e, v_o, a_o):
    return v_o - vx_e - (vx_e - v_o) * (ax_e - a_o) / A_L


def np_ego_x_motion(ego, u):
    """xdot and xddot of eq.kinematic_bicycle by hand: xdot = v (cos psi - beta sin psi)."""
    _, _, psi, v = ego
    alpha, beta = u
    psidot = v * beta / L_R
    xdot = v * (np.cos(psi) - beta * np.sin(psi))
    xddot = alpha * (np.cos(psi) - beta * np.sin(psi)) - v * (np.sin(psi) + beta * np.cos(psi)) * psidot
    return xdot, xddot


def brute_force_law(opp, ego, u, in_lane):
    """argmin (a - a_nom)^2 over a fine grid of [-accel_max, brake_max] subject to the VL-CBF."""
    x_o, v_o = opp
    vx, ax = np_ego_x_motion(ego, u)
    nominal = 1.0 * (-15.0 - v_o)
    grid = np.linspace(-3.0, 6.0, 180_001)
    if in_lane and ego[0] < x_o:
        h = np_h(ego[0], vx, x_o, v_o)
        ok = np_hdot(vx, ax, v_o, grid) + LAMBDAS_O[0] + LAMBDAS_O[1] * h >= 0
        if not ok.any():
            return 6.0  # infeasible: the closest the bounds allow is full braking
        grid = grid[ok]
    return grid[np.argmin((grid - nominal) ** 2)]


def test_ego_x_motion_matches_hand_derivation():
    rng = np.random.default_rng(1)
    for _ in range(20):
        ego = rng.uniform([0, 0, -0.35, 1], [100, 4, 0.35, 19])
        u = rng.uniform([-6, -0.15], [3, 0.15])
        vx, ax = agents.ego_x_motion(ego, u, L_R)
        ref_vx, ref_ax = np_ego_x_motion(ego, u)
        assert float(vx) == pytest.approx(ref_vx, rel=1e-12)
        assert float(ax) == pytest.approx(ref_ax, rel=1e-10, abs=1e-10)


@pytest.mark.parametrize("in_lane", [True, False])
def test_autonomous_law_is_the_exact_qp_solution(in_lane):
    rng = np.random.default_rng(2 + in_lane)
    for _ in range(60):
        ego = rng.uniform([0, 3.0, -0.1, 5], [40, 3.6, 0.1, 19])
        opp = np.array([rng.uniform(45, 160), -rng.uniform(5, 19)])
        u = rng.uniform([-6, -0.1], [3, 0.1])
        got = float(agents.autonomous_accel(opp, ego, u, ego_in_opposing_lane=in_lane, **LAW))
        assert got == pytest.approx(brute_force_law(opp, ego, u, in_lane), abs=1e-4)


def test_autonomous_law_cruises_when_the_ego_is_in_its_own_lane():
    ego, opp, u = np.array([50.0, 0.0, 0.0, 19.0]), np.array([70.0, -12.0]), np.array([3.0, 0.0])
    got = float(agents.autonomous_accel(opp, ego, u, ego_in_opposing_lane=False, **LAW))
    assert got == pytest.approx(-3.0)  # towards its 15 m/s cruise speed, at most accel_max


def test_both_vlcbf_laws_keep_h_oe_at_or_above_its_level():
    """Theorem 3 (thm.safety): ego and veh_o, each filtered by its VL-CBF on the same h, meet head-on
    in the opposing lane. veh_o runs its law on the ego's applied input (as in the plant); the ego
    takes the largest acceleration up to 3 m/s^2 whose eq.VL-CBF_e holds against veh_o's response to
    it (as the planner's prediction does). Sampled at 50 Hz, integrated exactly in between: h stays
    >= its level (1 m) up to the inter-sampling error, and they never meet."""
    dt, sub = 0.02, 20
    ego = np.array([0.0, 3.5, 0.0, 15.0])
    opp = np.array([150.0, -15.0])
    law = jax.jit(lambda o, e, a: agents.stop_at_rest(
        o[1], agents.autonomous_accel(o, e, jnp.stack([a, 0.0]), ego_in_opposing_lane=True, **LAW), dt))

    def response(a_e):
        return float(law(opp, ego, a_e))

    def admissible(a_e, h):
        return np_hdot(ego[3], a_e, opp[1], response(a_e)) + LAMBDAS_O[0] + LAMBDAS_O[1] * h >= 0

    h_min = np.inf
    for _ in range(600):
        vx = ego[3]
        h = np_h(ego[0], vx, opp[0], opp[1])
        # the largest admissible acceleration in [-6, 3] by bisection: the condition is monotone
        # in a_e (veh_o's response caps the relative acceleration, it never overtakes it)
        lo, hi = max(-6.0, -ego[3] / dt), 3.0
        if admissible(hi, h):
            a_e = hi
        else:
            for _ in range(30):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if admissible(mid, h) else (lo, mid)
            a_e = lo
        a_o = response(a_e)
        for _ in range(sub):
            h_dt = dt / sub
            ego = ego + np.array([ego[3] * h_dt + 0.5 * a_e * h_dt**2, 0, 0, a_e * h_dt])
            opp = opp + np.array([opp[1] * h_dt + 0.5 * a_o * h_dt**2, a_o * h_dt])
            h_min = min(h_min, np_h(ego[0], ego[3], opp[0], opp[1]))
        assert ego[3] >= -1e-9 and opp[1] <= 1e-9
    assert h_min >= 1.0 - 0.05
    assert ego[3] == pytest.approx(0.0, abs=1e-6)  # the ego stopped; veh_o creeps on as its barrier allows
    assert opp[0] - ego[0] >= 1.0 - 0.05  # they never came closer than the level


def test_human_driver_accelerates_to_its_limit_and_holds_it():
    v = -10.0
    for _ in range(400):
        a = float(agents.human_accel(v, 1.6, 19.4, 0.02))
        assert -1.6 - 1e-12 <= a <= 0.0
        v += a * 0.02
    assert v == pytest.approx(-19.4)
    assert float(agents.human_accel(-19.4, 1.6, 19.4, 0.02)) == 0.0
    assert float(agents.human_accel(-12.0, 0.0, 19.4, 0.02)) == 0.0  # constant speed (Table IV)


def test_front_vehicle_burst_and_cap():
    f = agents.front_accel
    assert float(f(0.5, 4.0, 1.0, 1.5, 7.0, 30.0, 0.002)) == 0.0  # before the onset
    assert float(f(1.0, 4.0, 1.0, 1.5, 7.0, 30.0, 0.002)) == 4.0
    assert float(f(2.49, 4.0, 1.0, 1.5, 7.0, 30.0, 0.002)) == 4.0
    assert float(f(2.5, 4.0, 1.0, 1.5, 7.0, 30.0, 0.002)) == 0.0  # the burst is over
    assert float(f(5.0, 4.0, 1.0, np.inf, 7.0, 30.0, 0.002)) == 4.0  # no duration: until the cap
    assert float(f(5.0, 4.0, 1.0, np.inf, 29.999, 30.0, 0.002)) == pytest.approx(0.5)  # cut at the cap


def test_ego_top_edge_of_a_rotated_footprint():
    for psi in (-0.3, 0.0, 0.2):
        corners_y = [
            1.0 + sx * 2.4425 * np.sin(psi) + sy * 0.92 * np.cos(psi) for sx in (-1, 1) for sy in (-1, 1)
        ]
        assert float(agents.ego_top_edge_m(np.array([0, 1.0, psi, 10]), 4.885, 1.84)) == pytest.approx(max(corners_y))
