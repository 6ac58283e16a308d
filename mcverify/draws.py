"""The per-episode scenario draws: one registry.

A draw is a scenario value each episode draws once, from its own stream of the episode key, within a
range of the model (e.g. veh_f's acceleration within ``scenario.front_accel_range_mps2``). Every layer
that handles draws reads them from here: the rollout draws them (:func:`mcverify.episode.draws.sample_scenario`),
importance sampling reads their ranges and nominal distributions (:mod:`mcverify.estimate.importance_run`),
the schema declares their ``sample_<name>`` columns (:mod:`mcverify.schema`) and validation names
their fields.

A new draw is one :class:`Draw` here and the code that uses its value (the plant's initial state or
the spawn rule).

This module is a low layer: it reads the model parameters by field path, imports neither the model
nor JAX.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

#: fold_in stream of the per-episode scenario draws, apart from the per-step noise streams: draw
#: ``stream`` k comes from ``fold_in(episode key, SCENARIO_STREAM + k)``.
SCENARIO_STREAM = 1_000_000


def field_value(params: Any, path: str) -> Any:
    """The model field at ``path`` ("section.field") of ``params`` (a :class:`mcverify.model.ModelParams`)."""
    section, name = path.split(".")
    return getattr(getattr(params, section), name)


@dataclass(frozen=True)
class Draw:
    """One per-episode scenario draw.

    name: its key in the episode's draws and its column ``sample_<name>``; stream: its stream k
    (:data:`SCENARIO_STREAM` + k); unit, definition: its column's; range_field: the model field
    (lo, hi) it is drawn from, uniformly in (lo, hi] (empty: the fixed value); fixed_field: the value
    without a range (and the mean of a normal draw); sd_field: a model field that, when > 0, makes the
    draw a normal of that standard deviation truncated to the range ("" never); applies: whether the
    cell draws it at all (NaN otherwise); lowest, highest: the bounds a valid range lies within
    (lowest <= lo < hi <= highest), for validation."""

    name: str
    stream: int
    unit: str
    definition: str
    range_field: str
    fixed_field: str
    applies: Callable[[Any], bool]
    lowest: Callable[[Any], float]
    highest: Callable[[Any], float] = lambda p: math.inf
    sd_field: str = ""

    @property
    def column(self) -> str:
        return f"sample_{self.name}"

    def range_of(self, params: Any) -> tuple[float, ...]:
        """The range it is drawn from in this cell: (lo, hi), or () (fixed, or not drawn at all)."""
        return tuple(field_value(params, self.range_field)) if self.applies(params) else ()

    def fixed(self, params: Any) -> float:
        return float(field_value(params, self.fixed_field))

    def sd(self, params: Any) -> float:
        """The standard deviation of a normal draw (0: uniform)."""
        return float(field_value(params, self.sd_field)) if self.sd_field else 0.0


def _has_opp(p: Any) -> bool:
    return p.opposing.kind != "none"


def _at_lane_entry(p: Any) -> bool:
    return bool(p.opposing.appears_at_lane_entry)


#: Every draw, in the order of their streams and of the schema's columns.
DRAWS: tuple[Draw, ...] = (
    Draw("front_accel_mps2", 0, "m/s^2", "the front vehicle's acceleration drawn for the episode",
         "scenario.front_accel_range_mps2", "scenario.front_accel_mps2", lambda p: True, lambda p: 0.0),
    Draw("opp_speed_mps", 1, "m/s", "veh_o's speed drawn for the episode (NaN without veh_o)",
         "opposing.speed_range_mps", "opposing.speed_mps", _has_opp, lambda p: 0.0,
         lambda p: p.opposing.speed_limit_mps),
    Draw("opp_spawn_gap_m", 2, "m", "x_o - x_e at which veh_o appears when the ego enters the opposing lane "
         "(opposing.spawn = lane_entry; NaN otherwise)", "opposing.spawn_gap_range_m", "opposing.spawn_gap_m",
         _at_lane_entry, lambda p: p.geometry.length_m),
    Draw("opp_spawn_delay_s", 3, "s", "how long after the ego's lane entry veh_o appears "
         "(opposing.spawn = lane_entry; NaN otherwise)", "opposing.spawn_delay_range_s", "opposing.spawn_delay_s",
         _at_lane_entry, lambda p: 0.0, sd_field="opposing.spawn_delay_sd_s"),
    Draw("front_accel_onset_s", 4, "s", "when the front vehicle's acceleration starts, drawn for the episode",
         "scenario.front_accel_onset_range_s", "scenario.front_accel_onset_s", lambda p: True, lambda p: 0.0),
    Draw("front_accel_duration_s", 5, "s", "how long the front vehicle's acceleration lasts, drawn for the episode "
         "(inf: until scenario.front_speed_max_mps)", "scenario.front_accel_duration_range_s",
         "scenario.front_accel_duration_s", lambda p: True, lambda p: 0.0),
)

#: Every draw by name.
DRAW_REGISTRY: dict[str, Draw] = {d.name: d for d in DRAWS}
#: Their names, the keys of an episode's draws.
DRAW_NAMES: tuple[str, ...] = tuple(DRAW_REGISTRY)
