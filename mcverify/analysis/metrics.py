"""The episode metrics as the reports show them: column, short label, one-sentence definition, unit.

:data:`RATE_METRICS` are summarised as rates with confidence intervals, :data:`VALUE_METRICS` by
count, quantiles and mean (:mod:`mcverify.analysis.summary`); the reports take their table headers
and definitions from here.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Metric:
    """An episode column as the reports show it: ``name`` (column), ``label`` (short, for table
    headers) and ``definition`` (one sentence for the report's definitions)."""

    name: str
    label: str
    definition: str
    unit: str = ""


#: Boolean metrics summarised as rates with confidence intervals, in report order. ``collision`` is
#: derived: a collision with either vehicle (the columns present are OR-ed); so is
#: ``outside_margin``: safe with the cell's margin, no collision and min h_ef >= epsilon
#: (``invariance_margin`` >= 0), the second meaning of "safe" beside ``safe`` (h_ef >= 0).
RATE_METRICS: tuple[Metric, ...] = (
    Metric("safe", "safe", "no collision with either vehicle and h_ef ≥ 0 (outside the safety ellipse) at every "
           "integration sub-step"),
    Metric("outside_margin", "outside ε margin", "no collision with either vehicle and h_ef ≥ ε (the cell's level; "
           "min h_ef − ε ≥ 0) at every integration sub-step: safe with the margin"),
    Metric("collision", "collision", "the ego footprint overlapped the front or the opposing vehicle's at some "
           "sub-step"),
    Metric("collision_front", "collision veh_f", "the oriented footprints of ego and front vehicle overlapped"),
    Metric("collision_opp", "collision veh_o", "the oriented footprints of ego and opposing vehicle overlapped"),
    Metric("ellipse_violation", "ellipse violated", "h_ef < 0 at some sub-step: the ego c.g. entered the safety "
           "ellipse around the front vehicle"),
    Metric("invariance_breach", "invariance breach", "h_ef started at or above the level ε and fell below it "
           "(Theorem 2 says it cannot)"),
    Metric("opp_invariance_breach", "h_eo breach", "h_eo fell below its level while the ego borrowed the opposing "
           "lane"),
    Metric("overtook", "overtook", "the episode ended with the paper's convergence test met ahead of the front vehicle "
           "(a successful overtake)"),
    Metric("went_back", "went back", "the episode ended behind the front vehicle in the ego lane (Q2's goal: the "
           "overtake was abandoned)"),
    Metric("timeout", "timeout", "neither goal was reached within the episode time limit"),
    Metric("settled_in_lane", "settled in lane", "the goal test fired and, after the settling period of lane "
           "keeping, the ego footprint lay inside its lane"),
    Metric("unsafe_in_settling", "unsafe in settling", "the ego first left the safe set after the goal test, while "
           "settling"),
    Metric("speed_limit_exceeded", "over the speed limit", "the ego's true speed exceeded ego.speed_max_mps at some "
           "integration sub-step (the MPC keeps the limit at its nodes only)"),
    Metric("input_limit_exceeded", "input beyond its bounds", "the applied acceleration or slip lay beyond the ego's "
           "bounds (ego.accel_min/max_mps2, ego.slip_max_rad) in some control period"),
)

#: Continuous metrics summarised by count, min, max, quantiles and mean with a bootstrap interval.
VALUE_METRICS: tuple[Metric, ...] = (
    Metric("min_dist_front_m", "min dist. veh_f", "the paper's \"min dist. with veh_f\": smallest signed Euclidean "
           "distance from the ego c.g. to the safety ellipse h_ef = 0, negative inside", "m"),
    Metric("min_gap_front_m", "min gap veh_f", "smallest gap between the ego and front vehicle footprints", "m"),
    Metric("min_gap_opp_m", "min dist. veh_o", "the paper's \"min dist. with veh_o\": smallest bumper gap to the "
           "opposing vehicle while the ego footprint reaches into the opposing lane (no value if it never did)", "m"),
    Metric("min_h_front", "min h_ef", "minimum of the barrier h_ef along the true trajectory"),
    Metric("min_gap_opp_any_m", "min gap veh_o (any time)", "smallest footprint gap to the opposing vehicle at any "
           "time", "m"),
    Metric("min_h_opp", "min h_eo", "minimum of h_eo while borrowing the opposing lane", "m"),
    Metric("invariance_margin", "min h_ef − ε", "min h_ef minus the level ε; negative means the level set was left"),
    Metric("overtake_time_s", "overtake time", "time from the episode start to the paper's convergence test "
           "(x_e ≥ x_f + φ v_f and |y_e| ≤ ε_y on measured values); overtaking episodes only", "s"),
    Metric("lane_borrow_time_s", "lane-borrow time", "from the first to the last sub-step at which the ego footprint "
           "reaches into the opposing lane", "s"),
    Metric("end_time_s", "episode length", "simulated time until the episode ended", "s"),
    Metric("first_unsafe_s", "first unsafe time", "when the ego first left the safe set (unsafe episodes only)", "s"),
    Metric("sample_front_accel_mps2", "α_f drawn", "the front vehicle's acceleration drawn for the episode", "m/s²"),
    # end state: at the goal test (conv_) and after the settling period (end_, settle_)
    Metric("conv_heading_rad", "heading at goal", "ego heading ψ when the goal test fired", "rad"),
    Metric("conv_lateral_speed_mps", "lateral speed at goal", "ego lateral speed y' when the goal test fired", "m/s"),
    Metric("conv_line_excess_m", "past lane line at goal", "how far the ego footprint reached past the lane line "
           "when the goal test fired (0 inside)", "m"),
    Metric("end_heading_rad", "heading at end", "ego heading ψ when the simulation stopped (after settling)", "rad"),
    Metric("end_lateral_speed_mps", "lateral speed at end", "ego lateral speed y' when the simulation stopped",
           "m/s"),
    Metric("settle_line_excess_max_m", "past lane line while settling", "largest reach of the ego footprint past "
           "the lane line from the goal test to the end of settling (0 inside)", "m"),
    # limits of the ego on the true trajectory (<= 0: held)
    Metric("speed_excess_mps", "speed excess", "largest ego speed above ego.speed_max_mps at any sub-step", "m/s"),
    Metric("accel_excess_mps2", "acceleration excess", "largest excess of the applied acceleration over its bounds",
           "m/s²"),
    Metric("slip_excess_rad", "slip excess", "largest excess of the applied slip angle over ego.slip_max_rad", "rad"),
)

RATE_NAMES = tuple(m.name for m in RATE_METRICS)
VALUE_NAMES = tuple(m.name for m in VALUE_METRICS)
METRICS: dict[str, Metric] = {m.name: m for m in RATE_METRICS + VALUE_METRICS}
