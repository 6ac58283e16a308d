"""First guesses of the TO-CBF-MPC decision vector ``w`` for a cold start.

A heuristic plan in the layout of :class:`~mcverify.ocp.layout.NlpLayout`: a speed profile towards
the goal, a lateral path through the opposing lane while alongside veh_f, and the finite-difference
inputs of that path (see :func:`initial_guess`). Warm starts from a previous solve live with the
solver (:mod:`mcverify.solver.mpc`).
"""

from __future__ import annotations

import math

import numpy as np

from mcverify.model import ModelParams
from mcverify.ocp.layout import N_FRONT, N_OPP, N_X, NlpLayout, OcpStructure

_GUESS_STEP_S = 0.02  # resolution of the guess profiles (s)


def _speed_profile(params: ModelParams, v0: float, v_front: float, direction: int, t: np.ndarray) -> np.ndarray:
    """Guessed ego speed (m/s) at times t (s).

    Q1: towards the speed limit at 3/4 of the acceleration limit. Q2: down to 0.3 v_f (never up)
    at 3/4 of the braking limit, so the ego falls behind veh_f at a few m/s.
    """
    e = params.ego
    if direction > 0:
        rate, target = 0.75 * e.accel_max_mps2, e.speed_max_mps
    else:
        rate, target = 0.75 * abs(e.accel_min_mps2), min(max(0.3 * v_front, e.speed_min_mps), v0)
    return np.where(v0 < target, np.minimum(v0 + rate * t, target), np.maximum(v0 - rate * t, target))


def _lateral_path(params: ModelParams, t: np.ndarray, x_rel: np.ndarray, y0: float, v: np.ndarray) -> np.ndarray:
    """Guessed y (m) at times t: in the opposing lane while alongside veh_f, else in the ego lane.

    "Alongside" is |x - x_f| < 1.2 a. The lane changes are spread at half the largest lateral speed
    before and after (a max-plus dilation), and the path starts at y0.
    """
    e, road = params.ego, params.road
    v_lat = 0.5 * max(float(np.min(v)), 2.0) * (math.sin(e.heading_max_rad) + e.slip_max_rad)
    t_along = t[np.abs(x_rel) < 1.2 * params.barrier.ellipse_a_m]
    if t_along.size:
        # y_up(t) = max_s y_req(s) - v_lat |t - s| for y_req in {ego lane, opposing lane} (opposing above)
        idx = np.searchsorted(t_along, t)
        right = t_along[np.minimum(idx, t_along.size - 1)]
        left = t_along[np.maximum(idx - 1, 0)]
        dist = np.minimum(np.abs(t - right), np.abs(t - left))  # to the nearest time alongside
        y_up = np.maximum(road.ego_lane_y_m, road.opp_lane_y_m - v_lat * dist)
    else:
        y_up = np.full(t.size, road.ego_lane_y_m)
    return np.clip(y_up, y0 - v_lat * t, y0 + v_lat * t)


def _guess_profiles(
    params: ModelParams, ego: np.ndarray, front: np.ndarray, direction: int
) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(T, t, x, y, v) on a fine grid: guessed time to goal and the guessed path over [0, N dt_max]."""
    m = params.mpc
    horizon_s = m.horizon * m.dt_max_s
    t = np.arange(0.0, horizon_s + _GUESS_STEP_S, _GUESS_STEP_S)
    v = _speed_profile(params, max(ego[3], 0.0), front[2], direction, t)
    x = ego[0] + np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * _GUESS_STEP_S)])
    x_rel = x - (front[0] + front[2] * t)
    y = _lateral_path(params, t, x_rel, ego[1], v)
    margin = m.phi_s * front[2] + 1.0
    long_ok = x_rel >= margin if direction > 0 else x_rel <= -margin
    lat_ok = np.abs(y - params.road.ego_lane_y_m) <= 0.5 * m.eps_y_m
    done = np.flatnonzero(long_ok & lat_ok)
    total = t[done[0]] if done.size else horizon_s
    total = float(np.clip(total, 10 * m.dt_min_s * m.horizon, 0.95 * horizon_s))
    return total, t, x, y, v


def initial_guess(
    params: ModelParams,
    structure: OcpStructure,
    ego_state: np.ndarray,
    front_xyv: np.ndarray,
    direction: int,
    opp_xv: np.ndarray | None = None,
) -> np.ndarray:
    """A first guess for w, (n_w,).

    Speed: Q1 accelerates towards the speed limit, Q2 brakes to 0.3 v_f (both at 3/4 of the limit).
    Path: x integrates the speed; y moves to the opposing lane centre while the ego is alongside
    veh_f (|x - x_f| < 1.2 a) and to the ego lane otherwise, at half the largest lateral speed. T is
    the first time both the goal (with 1 m margin) and the lateral band are met, clipped to
    [10 N dt_min, 0.95 N dt_max]; DT = T/N. psi follows the path, and alpha, beta are the
    finite-difference inputs of the guess (clipped to their bounds). veh_o (with ``opp_xv``, (2,)
    [x_o m, v_o m/s]) is guessed at its measured speed.
    """
    n, e = structure.horizon, params.ego
    ego = np.asarray(ego_state, dtype=float).reshape(N_X)
    front = np.asarray(front_xyv, dtype=float).reshape(N_FRONT)
    total, t_fine, x_fine, y_fine, v_fine = _guess_profiles(params, ego, front, direction)
    dt = total / n
    t = dt * np.arange(n + 1)
    x, y, v = (np.interp(t, t_fine, f) for f in (x_fine, y_fine, v_fine))
    psi = np.clip(np.arctan2(np.diff(y), np.maximum(np.diff(x), 1e-3)), -e.heading_max_rad, e.heading_max_rad)
    psi = np.concatenate([[ego[2]], psi])
    X = np.column_stack([x, y, psi, v])
    X[0] = ego
    alpha = np.clip(np.diff(v) / dt, e.accel_min_mps2, e.accel_max_mps2)
    beta = np.diff(psi) * e.l_r_m / (np.maximum(v[:-1], 1.0) * dt)
    U = np.column_stack([alpha, np.clip(beta, -e.slip_max_rad, e.slip_max_rad)])
    xo = None
    if structure.with_opposing:
        if opp_xv is None:
            raise ValueError("this problem has an opposing vehicle: opp_xv (2,) [x_o, v_o] is required")
        x_o, v_o = np.asarray(opp_xv, dtype=float).reshape(N_OPP)
        xo = np.column_stack([x_o + v_o * t, np.full(n + 1, v_o)])  # at its measured speed
    return NlpLayout.of(structure).pack(X, U, np.full(n, dt), xo)
