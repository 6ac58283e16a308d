"""Theorem 5 ("Q1 or Q2 is solvable at every control step") as a signed margin per recorded sub-step.

The planner's margin of one step is :func:`mcverify.control.margins.theorem5_margin`: the larger
signed room of the step's Q1 and Q2 solves (:func:`mcverify.control.margins.problem_margin`, >= 0
solved, < 0 failed), recorded per problem as ``q1_margin`` and ``q2_margin``. This module recomputes
the step's margin from those two stored columns, for the analysis layer (which does not import the
controller; tests/analysis check the two agree).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np


def theorem5_step_margin(trajectory: Mapping[str, np.ndarray]) -> np.ndarray:
    """Theorem 5's margin per sub-step, shape (sub-steps,), from the recorded ``q1_margin`` and
    ``q2_margin`` (each control step's value repeated over its sub-steps): the larger of the two
    problems' margins, +inf where Q2 was not solved and Q1 has no solution (no claim: MPC-DC) or
    where no decision was recorded. Negative exactly at the sub-steps of the control steps that
    solved neither problem (``q1_solved`` not 1 and ``q2_solved`` 0); its minimum over an episode
    is the row's ``theorem5_margin``."""
    q1, q2 = (np.asarray(trajectory[k], dtype=np.float64) for k in ("q1_margin", "q2_margin"))
    no_claim = np.isnan(q2) & ~(q1 >= 0.0)
    return np.where(no_claim, math.inf, np.fmax(q1, q2))
