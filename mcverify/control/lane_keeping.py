"""The settling controller: keep the ego in its lane after the episode's goal test fired (no MPC).

After the planner's convergence test ("overtook" / "went_back") the rollout keeps simulating for
``sim.settle_s`` with this law, so that the safety checks cover how the ego actually ends its
manoeuvre (at convergence it may still be swerving: |y_e| <= eps_y says nothing about psi).

The law, on the kinematic bicycle (eq.kinematic_bicycle: y' = v sin psi + v cos psi beta,
psi' = v beta / l_r, v' = alpha), with e = y - y_lane the offset from the ego lane's centre:

* reference heading  psi_ref = -atan(K_Y e / max(v, V_FLOOR)), clipped to +-heading_max / 2;
* slip angle         beta = clip(psi_ref - psi, +-slip_max).
  With this unit gain, y' ~ v (sin psi + beta) ~ v psi_ref ~ -K_Y e while beta is unsaturated: the
  offset decays at the rate K_Y, and psi follows psi_ref with the time constant l_r / v (about
  0.1 s at 14 m/s), so the heading goes to 0 with the offset;
* acceleration       alpha = clip(K_V (v_ref - v), accel_min, accel_max), v_ref the speed the ego
  converged with, except that it never closes in on veh_f: v_ref >= the measured v_f while ahead of
  it and v_ref <= v_f while behind (veh_f never decelerates), within [speed_min, speed_max].

Pure numpy on one episode's state: deterministic and independent of the chunk.
"""

from __future__ import annotations

import math

import numpy as np

from mcverify.model import ModelParams

#: Gain of the lateral offset (1/s): the offset to the lane centre decays about as exp(-K_Y t).
K_Y = 1.0
#: Speed below which the reference heading is computed as if at this speed (m/s): no division by 0.
V_FLOOR = 1.0
#: Gain of the speed loop (1/s).
K_V = 1.0


def reference_speed(v_converged: float, ego: np.ndarray, front_meas: np.ndarray, p: ModelParams) -> float:
    """The speed to hold (m/s): ``v_converged``, but never closing in on the measured veh_f."""
    v_ref = v_converged
    v_f = float(front_meas[2])
    v_ref = max(v_ref, v_f) if ego[0] >= front_meas[0] else min(v_ref, v_f)
    return float(min(max(v_ref, p.ego.speed_min_mps), p.ego.speed_max_mps))


def lane_keeping_input(ego: np.ndarray, v_ref: float, p: ModelParams) -> np.ndarray:
    """The input (2,) [alpha m/s^2, beta rad] that steers ``ego`` [x, y, psi, v] to its lane centre at
    ``v_ref``, within the input bounds of ``p.ego`` (see the module docstring for the law)."""
    lim = p.ego
    e = float(ego[1]) - p.road.ego_lane_y_m
    psi, v = float(ego[2]), float(ego[3])
    psi_max = 0.5 * lim.heading_max_rad
    psi_ref = min(max(-math.atan(K_Y * e / max(v, V_FLOOR)), -psi_max), psi_max)
    beta = min(max(psi_ref - psi, -lim.slip_max_rad), lim.slip_max_rad)
    alpha = min(max(K_V * (v_ref - v), lim.accel_min_mps2), lim.accel_max_mps2)
    return np.array([alpha, beta])


def lateral_speed_mps(ego: np.ndarray, u: np.ndarray) -> float:
    """y' of the plant (eq.kinematic_bicycle) in state ``ego`` under the input ``u``: v sin psi + v cos psi beta."""
    psi, v = float(ego[2]), float(ego[3])
    return v * math.sin(psi) + v * math.cos(psi) * float(u[1])


def line_excess_m(y: np.ndarray, psi: np.ndarray, p: ModelParams) -> np.ndarray:
    """How far (m) the ego footprint reaches past the ego lane's left edge (the lane line), 0 when
    inside: max(0, y + (L/2)|sin psi| + (W/2) cos psi - y_line). Vectorised over y, psi."""
    line = 0.5 * (p.road.ego_lane_y_m + p.road.opp_lane_y_m)
    top = y + 0.5 * p.geometry.length_m * np.abs(np.sin(psi)) + 0.5 * p.geometry.width_m * np.cos(psi)
    return np.maximum(top - line, 0.0)


def footprint_in_lane(ego: np.ndarray, p: ModelParams) -> bool:
    """The ego footprint lies entirely inside its lane (between the road's outer edge and the lane line)."""
    y, psi = float(ego[1]), float(ego[2])
    half = 0.5 * p.geometry.length_m * abs(math.sin(psi)) + 0.5 * p.geometry.width_m * math.cos(psi)
    lo = p.road.ego_lane_y_m - 0.5 * p.road.lane_width_m
    hi = 0.5 * (p.road.ego_lane_y_m + p.road.opp_lane_y_m)
    return bool(y - half >= lo and y + half <= hi)
