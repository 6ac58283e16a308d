"""A cell: one combination of a campaign's grid values, the unit every episode belongs to.

Declared below the run layer because the rollout, the executors, the reports and the benchmarks
all take one; a campaign file expands into cells (:mod:`mcverify.campaign.spec`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from mcverify.levels import Level
from mcverify.model import ModelParams


@dataclass(frozen=True)
class Cell:
    """One combination of grid values: its own parameters, episode count and deterministic keys."""

    index: int
    name: str
    overrides: dict[str, Any]  # every model override of this cell (axes' bundles and grid values)
    params: ModelParams
    episodes: int
    level: Level  # the VL-CBF level of params.barrier, resolved once (Level.of_barrier)
    episode_offset: int = 0  # global id of this cell's episode 0 (episode ids are unique in a run)
    labels: dict[str, str] = field(default_factory=dict)  # axis -> value label, e.g. {"method": "MPC-DC"}

    @property
    def epsilon(self) -> float:
        return self.level.epsilon

    @property
    def lambda0(self) -> float:
        return self.level.lambda0

    @property
    def controller(self) -> str:
        return self.params.mpc.controller
