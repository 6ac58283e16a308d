"""What one candidate's episode scored, read from its generation's run folder.

The values a falsification search tells its method and stores per evaluation: the requirement's
robustness, the value of a ``[falsify] guide``, the running robustness per control step (what
splitting branches on) and the control steps the episode simulated (its cost). An STL requirement and
the ``@go_back`` / ``@run`` guides read the candidate's stored trajectory; the others read its row.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from mcverify import requirements as reqs
from mcverify import store
from mcverify.analysis import robustness as rb
from mcverify.errors import RunError


def simulated_steps(row: dict[str, Any], control_period_s: float) -> int:
    """Control steps an episode simulated, settling included (its end time over the control period); 0 for an
    episode that could not be simulated."""
    ends = [float(row.get(k, math.nan)) for k in ("settle_end_s", "end_time_s")]
    ends = [t for t in ends if math.isfinite(t)]
    return int(round(max(ends) / control_period_s)) if ends and not rb.is_error_row(row) else 0


def running_robustness(gen_dir: Path, row: dict[str, Any], name: str, control_period_s: float) -> np.ndarray:
    """A candidate's running robustness (of a requirement or an ``@run`` guide) per control step, from
    its stored trajectory (empty for an episode that could not be simulated: it is never a survivor)."""
    if rb.is_error_row(row):
        return np.zeros(0)
    trajectory = stored_trajectory(gen_dir, row, "--method splitting branches on each candidate's stored trajectory")
    return rb.running_robustness(trajectory, name, control_period_s, epsilon=float(row["epsilon"]),
                                 h0=float(row["h0_front"]))


def stored_trajectory(gen_dir: Path, row: dict[str, Any], why: str) -> dict[str, np.ndarray]:
    """The stored trajectory of a candidate's episode; RunError naming ``why`` it is needed if missing."""
    trajectory = store.read_trajectory(gen_dir, int(row["episode_id"]))
    if trajectory is None:
        raise RunError(f"{store.trajectory_path(gen_dir, int(row['episode_id']))} is missing: {why}")
    return trajectory


def robustness(gen_dir: Path, row: dict[str, Any], requirement: str) -> float:
    """The requirement's robustness for one candidate (an STL requirement reads its stored trajectory)."""
    if not rb.needs_trajectory(requirement) or rb.is_error_row(row):
        return rb.robustness(row, requirement)
    return rb.robustness(row, requirement, stored_trajectory(gen_dir, row, f"requirement {requirement!r} is "
                                                                           "evaluated on each candidate's stored "
                                                                           "trajectory"))


def guide_value(gen_dir: Path, row: dict[str, Any], guide: str, control_period_s: float) -> float:
    """The guide's value for one candidate (``@go_back`` and ``@run`` guides read its stored trajectory)."""
    if not guide.endswith((reqs.GO_BACK_SUFFIX, reqs.RUN_SUFFIX)) or rb.is_error_row(row):
        return rb.guide_value(row, None, guide)
    return rb.guide_value(row, stored_trajectory(gen_dir, row, f"[falsify] guide = {guide!r} reads each "
                                                               "candidate's stored trajectory"), guide,
                          control_period_s=control_period_s)


def lowest(values: np.ndarray) -> float:
    """The smallest value that is not NaN (NaN if there is none)."""
    finite = values[~np.isnan(values)]
    return float(finite.min()) if finite.size else math.nan
