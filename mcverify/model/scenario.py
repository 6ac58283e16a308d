"""An episode's timing (:class:`Simulation`) and initial conditions (:class:`Scenario`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from mcverify import requirements as _requirements

#: The requirements (each also a valid :attr:`Simulation.stop_at`) and what a falsification search may
#: minimise instead (``[falsify] guide``): the registry's, :mod:`mcverify.requirements`.
REQUIREMENT_NAMES: tuple[str, ...] = _requirements.REQUIREMENT_NAMES
GUIDE_NAMES: tuple[str, ...] = _requirements.GUIDE_NAMES


@dataclass(frozen=True)
class Simulation:
    """Closed-loop timing: the planner's period, the plant's RK4 sub-steps under zero-order hold (every safety check
    runs at every sub-step), the episode's time limit, and how long the plant keeps running under the lane-keeping
    law of :mod:`mcverify.control.lane_keeping` after the goal test ("overtook" / "went_back"; the outcome and its
    time stay the goal test's). ``stop_at`` is set by ``mcverify falsify`` only (:data:`REQUIREMENT_NAMES`)."""

    control_period_s: float = 0.02
    """Planner sampling period. Valid: > 0. Paper: 0.02 (50 Hz)."""
    substeps: int = 10
    """RK4 sub-steps per control period; every safety check runs at every sub-step. Valid: 1-1000."""
    max_time_s: float = 25.0
    """Time limit of an episode; then it ends as a timeout. Valid: > 0."""
    settle_s: float = 3.0
    """After the goal test, how long the plant keeps running under the lane-keeping law (0: stop at once). Valid: >=
    0."""
    stop_at: str = ""
    """Falsify mode only: end the episode at its first violation of this requirement ("": never). Set by
    `mcverify falsify` ([falsify] stop_episodes); refused in campaign files."""


@dataclass(frozen=True)
class Scenario:
    """Initial conditions (paper Sec. VI-B: ego at x = 10 m, 10 m/s; front vehicle at x = 64 m) and veh_f's
    acceleration, which never switches sign (the paper's assumption); a range draws it per episode from the
    episode's key (the paper's Table III ranges (1,3], (3,5], (5,7]), and so do the ranges of the burst's onset
    and duration (values the paper leaves open)."""

    ego_x_m: float = 10.0
    """Ego's initial c.g. position. Paper: 10."""
    ego_speed_mps: float = 10.0
    """Ego's initial speed (also as scenario.ego_speed_kmh). Valid: within the ego speed range. Paper: 10."""
    front_x_m: float = 64.0
    """veh_f's initial c.g. position. Paper: 64."""
    front_speed_mps: float = 25.0 / 3.6
    """veh_f's initial speed (also as scenario.front_speed_kmh). Valid: >= 0. Paper: Table II 25-36 km/h."""
    front_accel_mps2: float = 0.0
    """veh_f's acceleration from front_accel_onset_s on (it never decelerates). Valid: >= 0."""
    front_accel_range_mps2: tuple[float, ...] = ()
    """(lo, hi): each episode draws veh_f's acceleration uniformly in (lo, hi]; replaces front_accel_mps2. Paper:
    Table III (1,3], (3,5], (5,7]."""
    front_accel_onset_s: float = 0.0
    """When veh_f starts accelerating. Valid: >= 0."""
    front_accel_onset_range_s: tuple[float, ...] = ()
    """(lo, hi): each episode draws when veh_f starts accelerating uniformly in (lo, hi]; replaces front_accel_onset_s
    (ignored while a range is set). Valid: 0 <= lo < hi. The paper gives no onset for Table III."""
    front_accel_duration_s: float = math.inf
    """How long veh_f's acceleration lasts (inf: until front_speed_max_mps, so no overtake once it is faster than the
    ego can go). Valid: >= 0."""
    front_accel_duration_range_s: tuple[float, ...] = ()
    """(lo, hi): each episode draws how long veh_f's acceleration lasts uniformly in (lo, hi] (always > 0); replaces
    front_accel_duration_s (ignored while a range is set). Valid: 0 <= lo < hi. The paper gives no duration for
    Table III."""
    front_speed_max_mps: float = 30.0
    """veh_f's speed cap while it accelerates. Valid: >= 0."""
