"""All the model's parameters of one campaign cell, one section per record (:class:`ModelParams`)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

from mcverify.model.barrier import Barrier
from mcverify.model.mpc import Mpc
from mcverify.model.noise import Noise
from mcverify.model.opposing import Opposing
from mcverify.model.scenario import Scenario, Simulation
from mcverify.model.vehicle import EgoLimits, Road, VehicleGeometry


@dataclass(frozen=True)
class ModelParams:
    """Everything that defines one cell of a campaign, except the episode count and seed."""

    geometry: VehicleGeometry = field(default_factory=VehicleGeometry)
    road: Road = field(default_factory=Road)
    ego: EgoLimits = field(default_factory=EgoLimits)
    barrier: Barrier = field(default_factory=Barrier)
    mpc: Mpc = field(default_factory=Mpc)
    noise: Noise = field(default_factory=Noise)
    sim: Simulation = field(default_factory=Simulation)
    scenario: Scenario = field(default_factory=Scenario)
    opposing: Opposing = field(default_factory=Opposing)

    def to_dict(self) -> dict:
        return asdict(self)
