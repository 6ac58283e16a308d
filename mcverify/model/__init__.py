"""The model's numbers: every value the paper states, and a named default for every value it leaves open.

All lengths in metres, speeds in m/s, accelerations in m/s^2, angles in radians, times in seconds.
Road frame: x along the road (direction of ego travel), y to the left; the ego lane centre is y = 0
and the opposing lane centre is y = +lane_width_m.

Each dataclass is frozen: a campaign builds new instances with :func:`dataclasses.replace`, and the
resolved values are written to every run's ``manifest.json``.

One module per concept: :mod:`~mcverify.model.vehicle` (footprint, road, ego limits),
:mod:`~mcverify.model.barrier`, :mod:`~mcverify.model.mpc`, :mod:`~mcverify.model.noise`,
:mod:`~mcverify.model.scenario` (timing, initial conditions), :mod:`~mcverify.model.opposing` and
:mod:`~mcverify.model.params` (:class:`ModelParams`, all of them); this package re-exports the names
the rest of the code imports from :mod:`mcverify.model`.
"""

from __future__ import annotations

from mcverify.model.barrier import Barrier
from mcverify.model.mpc import (
    ABANDON_RULES,
    BACKEND_NAMES,
    CONTROLLERS_WITHOUT_LEVEL,
    Q2_SOLVE_POLICIES,
    Mpc,
    kept_level,
)
from mcverify.model.noise import MAX_BRANCHES, MAX_SEGMENTS, Noise
from mcverify.model.opposing import normal_masses
from mcverify.model.params import ModelParams
from mcverify.model.scenario import GUIDE_NAMES, REQUIREMENT_NAMES, Simulation

__all__ = [
    "ABANDON_RULES", "BACKEND_NAMES", "CONTROLLERS_WITHOUT_LEVEL", "GUIDE_NAMES", "MAX_BRANCHES", "MAX_SEGMENTS",
    "Q2_SOLVE_POLICIES", "REQUIREMENT_NAMES", "Barrier", "ModelParams", "Mpc", "Noise", "Simulation", "kept_level",
    "normal_masses",
]
