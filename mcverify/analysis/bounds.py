"""Lower bounds on what any controller can achieve from a scenario's start (pure, no simulation).

:func:`goal_time_lower_bound`: the earliest time at which the ego can reach the paper's goal
x_e >= x_f(t) + phi v_f (eq.tompc_goal with the goal moving with veh_f) from its start, when veh_f
drives at a constant speed. The ego's x-speed is at most its speed v (|psi + beta| only lowers it),
v is at most the speed limit and grows at most at the acceleration limit, so no plan, noise or
lane change can be faster. Used beside the paper's Table II: its start-to-goal means are below
this bound (issue 15, item 8).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any


def goal_time_lower_bound(
    ego_x_m: float,
    ego_speed_mps: float,
    front_x_m: float,
    front_speed_mps: float,
    phi_s: float,
    speed_limit_mps: float,
    accel_max_mps2: float = math.inf,
) -> float:
    """Earliest t (s) with x_e(t) >= x_f + v_f t + phi v_f, the ego at full acceleration
    ``accel_max_mps2`` (m/s^2; inf: it jumps to the limit at t = 0) up to ``speed_limit_mps``.

    Positions in metres, speeds in m/s. 0 if the ego starts at or past the goal; inf if it can
    never reach it (the limit not above v_f).
    """
    gap = front_x_m + phi_s * front_speed_mps - ego_x_m  # the goal's lead over the ego at t = 0 (m)
    if gap <= 0.0:
        return 0.0
    v_max = speed_limit_mps
    if v_max <= front_speed_mps:
        return math.inf
    v0 = min(ego_speed_mps, v_max)
    if not math.isfinite(accel_max_mps2):
        return gap / (v_max - front_speed_mps)
    a = accel_max_mps2
    if a <= 0.0:
        return gap / (v0 - front_speed_mps) if v0 > front_speed_mps else math.inf
    t_limit = (v_max - v0) / a  # when the ego reaches the limit
    rel = v0 - front_speed_mps
    t = (-rel + math.sqrt(rel * rel + 2.0 * a * gap)) / a  # a t^2 / 2 + rel t = gap, while accelerating
    if t <= t_limit:
        return t
    gap_left = gap - (rel * t_limit + 0.5 * a * t_limit**2)
    return t_limit + gap_left / (v_max - front_speed_mps)


def goal_time_bounds(params: Mapping[str, Any] | None) -> dict[str, float] | None:
    """Both bounds for a cell's parameters (``dataclasses.asdict`` of the model, as in the manifest):
    ``{"speed_limit": at the speed limit from t = 0, "accel_limit": with the ego's acceleration
    limit too}`` in seconds; None when the parameters are missing or veh_f does not drive at a
    constant speed (then this bound does not apply)."""
    try:
        sc, ego, mpc = params["scenario"], params["ego"], params["mpc"]
        if float(sc.get("front_accel_mps2", 0.0)) != 0.0 or sc.get("front_accel_range_mps2"):
            return None
        args = (float(sc["ego_x_m"]), float(sc["ego_speed_mps"]), float(sc["front_x_m"]),
                float(sc["front_speed_mps"]), float(mpc["phi_s"]), float(ego["speed_max_mps"]))
        accel = float(ego["accel_max_mps2"])
    except (KeyError, TypeError, ValueError):
        return None
    return {"speed_limit": goal_time_lower_bound(*args), "accel_limit": goal_time_lower_bound(*args, accel)}
