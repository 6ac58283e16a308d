"""The first unsafe moment of a stored trajectory: when, which constraint, which vehicle, what margin.

Read from the sub-step columns of ``trajectories/episode-NNNNNN.parquet`` (see
:mod:`mcverify.episode.recording`): a collision with veh_f (``collision_front``, else
``gap_front_m <= 0``), a collision with veh_o (``collision_opp``, else ``gap_opp_m <= 0``) and the
ego c.g. inside the safety ellipse (``h_front < 0``), the three members of the row's ``safe``. The
time is the first *sub-step* with a violation, so it lies within the control period that starts at
the row's ``first_unsafe_s`` (the row keeps the period's start, the figure the exact instant).
When several constraints fail at that sub-step the collision is named (the worse event), veh_o first.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

#: Constraint -> (vehicle, the trajectory column of its margin, the margin's name in labels).
CONSTRAINTS: dict[str, tuple[str, str, str]] = {
    "collision_opp": ("veh_o", "gap_opp_m", "gap"),
    "collision_front": ("veh_f", "gap_front_m", "gap"),
    "ellipse": ("veh_f", "h_front", "h_ef"),
}


@dataclass(frozen=True)
class UnsafeEvent:
    """The first unsafe sub-step of an episode.

    t_s: its time (s); index: its row in the trajectory; constraint: a key of :data:`CONSTRAINTS`;
    vehicle: ``veh_f`` or ``veh_o``; margin: the constraint's margin then (gap in m, or h_ef);
    worst: the smallest margin of that constraint over the episode, at ``worst_t_s`` (s); later:
    (constraint, first time in s) of each other constraint violated afterwards, in time order."""

    t_s: float
    index: int
    constraint: str
    vehicle: str
    margin: float
    worst: float
    worst_t_s: float
    later: tuple[tuple[str, float], ...] = ()

    def label(self) -> str:
        """One line for a figure, e.g. ``collision with veh_o at 7.40 s, gap 0.00 m`` or
        ``ellipse h_ef = -0.003 at 5.10 s (min -0.030 at 5.62 s)``."""
        if self.constraint == "ellipse" and np.isfinite(self.margin):
            text = f"ellipse h_ef = {_h(self.margin)} at {self.t_s:.2f} s"
            return text + (f" (min {_h(self.worst)} at {self.worst_t_s:.2f} s)" if self.worst < self.margin else "")
        text = f"collision with {self.vehicle} at {self.t_s:.2f} s"
        return text + (f", gap {max(self.margin, 0.0) + 0.0:.2f} m" if np.isfinite(self.margin) else "")

    def then(self) -> str:
        """The later violations of other constraints, e.g. ``then collision with veh_f at 5.62 s``."""
        names = {"ellipse": "ellipse violated", "collision_front": "collision with veh_f",
                 "collision_opp": "collision with veh_o"}
        return ("then " + ", ".join(f"{names[c]} at {t:.2f} s" for c, t in self.later)) if self.later else ""


def _h(value: float) -> str:
    """A barrier value: three decimals, or two significant digits when that would read -0.000."""
    return f"{value:.3f}" if abs(value) >= 5e-4 else f"{value:.1e}"


def _values(traj: Mapping[str, np.ndarray], name: str, n: int) -> np.ndarray | None:
    if name not in traj:
        return None
    x = np.asarray(traj[name])
    return x.astype(np.float64) if x.dtype != object and len(x) == n else None


def violations(traj: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Per constraint of :data:`CONSTRAINTS` whose columns are stored, a (n,) bool mask of the
    sub-steps that violate it (NaN margins never do: no veh_o, or not measured)."""
    n = len(np.asarray(traj["t_s"]))
    out: dict[str, np.ndarray] = {}
    for name, (_, margin_col, _) in CONSTRAINTS.items():
        flag = _values(traj, name, n) if name != "ellipse" else None
        margin = _values(traj, margin_col, n)
        if flag is not None:
            out[name] = np.nan_to_num(flag) > 0.5
        elif margin is not None:
            out[name] = np.nan_to_num(margin, nan=np.inf) < 0.0 if name == "ellipse" else \
                np.nan_to_num(margin, nan=np.inf) <= 0.0
    return out


def first_unsafe_event(traj: Mapping[str, np.ndarray]) -> UnsafeEvent | None:
    """The first unsafe sub-step of ``traj`` (see the module docstring), None if it stayed safe."""
    masks = violations(traj)
    if not masks:
        return None
    t = np.asarray(traj["t_s"], dtype=np.float64)
    any_bad = np.logical_or.reduce(list(masks.values()))
    if not any_bad.any():
        return None
    k = int(np.argmax(any_bad))
    constraint = next(name for name in CONSTRAINTS if name in masks and masks[name][k])
    vehicle, margin_col, _ = CONSTRAINTS[constraint]
    later = tuple(sorted(((name, float(t[int(np.argmax(m))])) for name, m in masks.items()
                          if name != constraint and m.any()), key=lambda x: x[1]))
    margin = _values(traj, margin_col, len(t))
    if margin is None:  # only the flag is stored
        return UnsafeEvent(float(t[k]), k, constraint, vehicle, float("nan"), float("nan"), float(t[k]), later)
    finite = np.where(np.isfinite(margin), margin, np.inf)
    w = int(np.argmin(finite))
    return UnsafeEvent(float(t[k]), k, constraint, vehicle, float(margin[k]), float(margin[w]), float(t[w]), later)
