"""The vehicles' footprint, the road and the ego's input and state bounds (units and road frame:
:mod:`mcverify.model`)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class VehicleGeometry:
    """Footprint of every vehicle (paper Sec. VI-A: Toyota Camry)."""

    length_m: float = 4.885
    """Footprint length of every vehicle. Valid: > 0. Paper: 4.885 (Toyota Camry)."""
    width_m: float = 1.840
    """Footprint width of every vehicle. Valid: > 0. Paper: 1.840."""


@dataclass(frozen=True)
class Road:
    """Two-lane, two-way road (paper Sec. VI-A: lane width 3.5 m)."""

    lane_width_m: float = 3.5
    """Width of each of the two lanes. Valid: > 0. Paper: 3.5."""

    @property
    def ego_lane_y_m(self) -> float:
        return 0.0

    @property
    def opp_lane_y_m(self) -> float:
        return self.lane_width_m


@dataclass(frozen=True)
class EgoLimits:
    """Input and state bounds of the ego kinematic bicycle (eq.kinematic_bicycle). The paper states only the
    speed limit (19.4 m/s = 70 km/h); the others are named defaults: a Camry's acceleration (0-100 km/h in about
    8 s), firm braking on dry asphalt, the c.g. kept on the road, and l_r about half the Camry's 2.825 m wheelbase.
    """

    accel_min_mps2: float = -6.0
    """Ego's strongest braking (a negative acceleration). Valid: < 0. Paper: not given."""
    accel_max_mps2: float = 3.0
    """Ego's largest acceleration. Valid: > 0. Paper: not given."""
    slip_max_rad: float = 0.15
    """Bound on the bicycle's slip angle beta. Valid: > 0. Paper: not given."""
    speed_min_mps: float = 0.0
    """Lowest ego speed. Valid: >= 0, below speed_max_mps."""
    speed_max_mps: float = 19.4
    """Ego speed limit (also set as ego.speed_max_kmh). Valid: > 0. Paper: 19.4 (70 km/h)."""
    heading_max_rad: float = 0.35
    """Bound on the ego heading psi. Valid: > 0. Paper: not given."""
    y_min_m: float = -0.83
    """Lowest lateral position of the ego c.g. (road edge minus half a width). Paper: not given."""
    y_max_m: float = 4.33
    """Highest lateral position of the ego c.g. Valid: > y_min_m. Paper: not given."""
    l_r_m: float = 1.4
    """Rear axle to c.g. distance of the bicycle model. Valid: > 0. Paper: not given."""

