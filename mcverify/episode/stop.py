"""Falsify mode: which episodes of a chunk have just violated the requirement ``sim.stop_at``.

``mcverify falsify`` with ``stop_episodes = true`` sets ``sim.stop_at`` to the searched requirement;
the rollout then ends an episode at the end of the control period in which this test first holds,
so its trajectory, its row and its robustness stop there (``stopped_at_violation``). The test reads
the running safety trace and counters that the row is made of, so it agrees with the sign of
:mod:`mcverify.analysis.robustness` on the stopped row (negative iff violated; tests/episode check it).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from mcverify.control.episode_state import EpisodeState
from mcverify.requirements import REQUIREMENTS, StopInputs
from mcverify.schema import STOPPED_OUTCOME  # noqa: F401 - re-exported; declared once, in the schema
from mcverify.sim.plant import SafetyTrace


def violated(name: str, trace: SafetyTrace, states: Sequence[EpisodeState], h0: np.ndarray, epsilon: float,
             has_opp: bool) -> np.ndarray:
    """Boolean mask, shape (episodes,): requirement ``name`` is violated by the episode so far (the
    registry's :attr:`~mcverify.requirements.Requirement.stop`).

    trace: the chunk's running safety trace (arrays of shape (episodes,)); states: the host-side
    counters (Theorem 5's steps); h0: h_ef at the start, shape (episodes,); epsilon: the cell's level.
    """
    if name not in REQUIREMENTS:
        raise ValueError(f"unknown requirement {name!r} for sim.stop_at")
    inputs = StopInputs(
        collision_front=np.asarray(trace.collision_front, dtype=bool),
        collision_opp=np.asarray(trace.collision_opp, dtype=bool),
        min_h_front=np.asarray(trace.min_h_front, dtype=float),
        min_h_opp=np.asarray(trace.min_h_opp, dtype=float),
        both_infeasible_steps=np.array([st.both_infeasible_steps for st in states]),
        both_certified_infeasible_steps=np.array([st.both_certified_infeasible_steps for st in states]),
        h0_front=np.asarray(h0),
        epsilon=epsilon,
        has_opp=has_opp,
    )
    return np.asarray(REQUIREMENTS[name].stop(inputs), dtype=bool)
