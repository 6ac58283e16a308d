"""The opposing vehicle veh_o (:class:`Opposing`) and the masses of its normal spawn delay."""

from __future__ import annotations

import statistics
from dataclasses import dataclass


@dataclass(frozen=True)
class Opposing:
    """The opposing vehicle veh_o: a double integrator (eq.double_integrator) on the opposing lane
    centre, driving towards -x (its road-frame velocity is -speed).

    ``kind``:
    * "none": no opposing vehicle (Table II);
    * "autonomous": a cruise law alpha = ``cruise_gain_per_s`` (speed_mps - speed) filtered by its
      own VL-CBF on h_oe (eq.tompcAdd_cbf_oe) with Lambda_o = [-kappa~_o(``epsilon_m``),
      ``lambdas_m``...], solved exactly at every control step; its parameters are known to the
      ego (the paper's "via communications"), so the planner predicts it with the same law;
    * "human": accelerates towards ``speed_limit_mps`` at ``accel_mps2`` (the paper's Case 2 uses
      1.6 m/s^2; 0 = constant speed, Table IV). The planner does not know this law and predicts the
      worst case: ``accel_max_mps2`` towards the ego, capped at ``speed_limit_mps`` (Sec. V-C).

    When veh_o appears (``spawn``; the paper does not say, and with a fixed start the two vehicles
    rarely meet while the ego borrows the lane): "start", from ``x_m`` at t = 0 (Tables III-IV as first
    reproduced), or "lane_entry", ``spawn_gap_m`` ahead of the ego when its footprint first crosses the lane
    line (``spawn_delay_s`` later), so that every episode that starts an overtake meets it mid-overtake. The
    ``*_range_*`` fields draw the gap, the delay and veh_o's speed per episode from the episode's key.
    """

    kind: str = "none"
    """none, autonomous (cruise law filtered by its own VL-CBF, known to the ego) or human (unknown law, worst case
    predicted)."""
    x_m: float = 250.0
    """veh_o's initial c.g. position (spawn = start)."""
    speed_mps: float = 15.0
    """veh_o's initial (and cruise) speed magnitude; it drives towards -x. Valid: >= 0."""
    accel_mps2: float = 0.0
    """A human veh_o's acceleration towards speed_limit_mps (0: constant speed). Paper: 1.6 in Case 2, 0 in Table IV."""
    speed_limit_mps: float = 19.4
    """veh_o's speed limit. Paper: 19.4."""
    accel_max_mps2: float = 3.0
    """The worst-case acceleration the ego predicts for a human veh_o. Valid: >= 0."""
    brake_max_mps2: float = 6.0
    """veh_o's largest deceleration (its CBF filter is clipped to it). Valid: > 0."""
    cruise_gain_per_s: float = 1.0
    """Gain of an autonomous veh_o's cruise law alpha = k (speed_mps - speed). Valid: >= 0."""
    lambdas_m: tuple[float, ...] = (1.0,)
    """lambda_i of veh_o's own kappa~_o on h_oe. Valid: all > 0."""
    epsilon_m: float = 1.0
    """Level of veh_o's barrier h_oe (metres). Valid: >= 0."""
    detect_range_m: float = 200.0
    """The ego sees veh_o (and adds eq.tompcAdd) once x_o - x_e is below this. Valid: > 0."""
    spawn: str = "start"
    """When veh_o appears: start (at x_m at t = 0) or lane_entry (when the ego first enters the opposing lane)."""
    spawn_gap_m: float = 150.0
    """x_o - x_e at which veh_o appears with spawn = lane_entry. Valid: > 0."""
    spawn_gap_range_m: tuple[float, ...] = ()
    """(lo, hi): draws the spawn gap per episode uniformly in (lo, hi]; replaces spawn_gap_m."""
    spawn_delay_s: float = 0.0
    """With lane_entry, how long after the lane entry veh_o appears. Valid: >= 0."""
    spawn_delay_range_s: tuple[float, ...] = ()
    """(lo, hi): draws the spawn delay per episode uniformly in (lo, hi]; replaces spawn_delay_s."""
    spawn_delay_sd_s: float = 0.0
    """> 0 with spawn_delay_range_s: the delay is normal with mean spawn_delay_s and this standard deviation,
    truncated to the range, instead of uniform (the timing of veh_o's arrival as a jitter around a nominal time).
    The range may lie in a tail (e.g. [1.9, 8] around 1.5: the normal conditioned on a late arrival). Valid: >= 0;
    needs spawn_delay_range_s holding more than 1e-12 of the normal's mass."""
    speed_range_mps: tuple[float, ...] = ()
    """(lo, hi): draws veh_o's speed per episode uniformly in (lo, hi]; replaces speed_mps."""

    @property
    def appears_at_lane_entry(self) -> bool:
        """Whether there is a veh_o and it appears at the ego's lane entry (where the spawn gap and
        delay apply)."""
        return self.kind != "none" and self.spawn == "lane_entry"


def normal_masses(mean: float, sd: float, lo: float, hi: float) -> tuple[float, float, float]:
    """(below lo, inside [lo, hi], above hi): the probabilities of a normal (``mean``, ``sd``), each tail taken
    from its own side so that a range far in a tail keeps its precision (the normal spawn delay,
    ``OpposingParams.spawn_delay_sd_s``: its validation, its draws and the importance sampler's nominal)."""
    unit = statistics.NormalDist()
    a, b = (lo - mean) / sd, (hi - mean) / sd
    below, above = unit.cdf(a), unit.cdf(-b)
    inside = unit.cdf(-a) - unit.cdf(-b) if a > 0 else unit.cdf(b) - unit.cdf(a)
    return below, inside, above
