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

from mcverify.control.planner import EpisodeState
from mcverify.schema import STOPPED_OUTCOME  # noqa: F401 - re-exported; declared once, in the schema
from mcverify.sim.plant import SafetyTrace


def violated(name: str, trace: SafetyTrace, states: Sequence[EpisodeState], h0: np.ndarray, epsilon: float,
             has_opp: bool) -> np.ndarray:
    """Boolean mask, shape (episodes,): requirement ``name`` is violated by the episode so far.

    trace: the chunk's running safety trace (arrays of shape (episodes,)); states: the host-side
    counters (Theorem 5's steps); h0: h_ef at the start, shape (episodes,); epsilon: the cell's level.
    """
    collision_front = np.asarray(trace.collision_front, dtype=bool)
    collision_opp = np.asarray(trace.collision_opp, dtype=bool) & has_opp
    min_h = np.asarray(trace.min_h_front, dtype=float)
    if name == "collision_front":
        return collision_front
    if name == "collision_opp":
        return collision_opp
    if name == "ellipse":
        return min_h < 0.0
    if name == "safe":
        return collision_front | collision_opp | (min_h < 0.0)
    if name == "invariance":
        return (np.asarray(h0) >= epsilon) & (min_h - epsilon < 0.0)
    if name == "h_eo":
        return (np.asarray(trace.min_h_opp, dtype=float) < 0.0) & has_opp
    if name == "theorem5":
        return np.array([st.both_infeasible_steps > 0 for st in states], dtype=bool)
    if name == "theorem5_certified":
        return np.array([st.both_certified_infeasible_steps > 0 for st in states], dtype=bool)
    raise ValueError(f"unknown requirement {name!r} for sim.stop_at")
