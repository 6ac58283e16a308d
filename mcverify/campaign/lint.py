"""Warnings for campaigns that cannot do what they seem to: checks on the expanded cells that the
validation (which refuses impossible values) lets through because each value alone is valid.

Each warning is one line naming the cells and what to change. ``mcverify run`` prints them before
it starts (and ``--dry-run`` lists them); they never stop a run, since a study of what happens
when no overtake is possible may be intended.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

from mcverify.campaign.spec import Campaign
from mcverify.cell import Cell


def warnings(campaign: Campaign) -> list[str]:
    """Every warning for ``campaign``, one line each (empty if none)."""
    found: list[str] = []
    slow = [c for c in campaign.cells if _front_always_too_fast(c)]
    if slow:
        p = slow[0].params
        found.append(
            f"no episode can overtake in {_cells(slow, campaign)}: veh_f ends at least as fast as the ego's speed "
            f"limit ego.speed_max_mps = {p.ego.speed_max_mps:g} m/s ({_why(slow[0])}); set "
            "scenario.front_accel_duration_s (the burst lasts until scenario.front_speed_max_mps by default) or "
            "a lower scenario.front_speed_max_mps"
        )
    slow_names = {c.name for c in slow}
    short = [c for c in campaign.cells if c.name not in slow_names and _horizon_too_short(c)]
    if short:
        found.append(
            f"every episode of {_cells(short, campaign)} ends as a timeout: sim.max_time_s = "
            f"{short[0].params.sim.max_time_s:g} s is shorter than the time the ego needs to reach veh_f "
            "at its speed limit"
        )
    for fixed, drawn in _REPLACED_BY_RANGE:
        ignored = [c for c in campaign.cells if _ignored(c, fixed, drawn)]
        if ignored:
            found.append(f"scenario.{fixed} is ignored in {_cells(ignored, campaign)}: scenario.{drawn} draws it per "
                         "episode")
    return found


#: Fixed scenario values that a range, once set, replaces (the range is drawn per episode).
_REPLACED_BY_RANGE = (("front_accel_onset_s", "front_accel_onset_range_s"),
                      ("front_accel_duration_s", "front_accel_duration_range_s"))


def _ignored(cell: Cell, fixed: str, drawn: str) -> bool:
    """The cell sets the fixed value away from its default, and a range that replaces it."""
    s = cell.params.scenario
    return bool(getattr(s, drawn)) and getattr(s, fixed) != getattr(type(s)(), fixed)


def front_final_speed_mps(cell: Cell, accel_mps2: float) -> float:
    """veh_f's speed once its acceleration burst is over (it never decelerates), m/s; with a drawn
    duration, after the shortest burst of its range."""
    s = cell.params.scenario
    if accel_mps2 <= 0.0:
        return s.front_speed_mps
    duration_s = _shortest_duration_s(cell)
    gained = accel_mps2 * duration_s if math.isfinite(duration_s) else math.inf
    return max(s.front_speed_mps, min(s.front_speed_max_mps, s.front_speed_mps + gained))


def _shortest_duration_s(cell: Cell) -> float:
    s = cell.params.scenario
    return min(s.front_accel_duration_range_s) if s.front_accel_duration_range_s else s.front_accel_duration_s


def _lowest_accel(cell: Cell) -> float:
    s = cell.params.scenario
    return min(s.front_accel_range_mps2) if s.front_accel_range_mps2 else s.front_accel_mps2


def _front_always_too_fast(cell: Cell) -> bool:
    """Even the smallest drawn acceleration leaves veh_f at or above the ego's speed limit."""
    return front_final_speed_mps(cell, _lowest_accel(cell)) >= cell.params.ego.speed_max_mps


def _why(cell: Cell) -> str:
    s = cell.params.scenario
    a = _lowest_accel(cell)
    if a <= 0.0:
        return f"it drives at scenario.front_speed_mps = {s.front_speed_mps:g} m/s"
    burst = (f"front_accel_duration_s = {s.front_accel_duration_s:g} s" if not s.front_accel_duration_range_s else
             f"front_accel_duration_range_s's {_shortest_duration_s(cell):g} s or more")
    return (f"an acceleration of {a:g} m/s^2 or more for {burst} "
            f"takes it to {front_final_speed_mps(cell, a):g} m/s")


def _horizon_too_short(cell: Cell) -> bool:
    """Even at its speed limit from the first instant the ego cannot reach veh_f's rear bumper."""
    p = cell.params
    gap_m = p.scenario.front_x_m - p.scenario.ego_x_m - p.geometry.length_m
    closing_mps = p.ego.speed_max_mps - p.scenario.front_speed_mps
    return gap_m > 0 and (closing_mps <= 0 or gap_m / closing_mps > p.sim.max_time_s)


def _cells(cells: Iterable[Cell], campaign: Campaign) -> str:
    cells = list(cells)
    if len(cells) == len(campaign.cells):
        return "every cell" if len(cells) > 1 else f"cell {cells[0].name!r}"
    names = ", ".join(repr(c.name) for c in cells[:4]) + (f" and {len(cells) - 4} more" if len(cells) > 4 else "")
    return f"cell(s) {names}"
