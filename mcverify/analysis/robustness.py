"""Requirements and their signed robustness, computed from stored episode rows.

A requirement maps an episode row to one number, **negative iff the requirement is violated** (and
non-negative otherwise); larger means farther from a violation. The values come from the row's own
columns (each of which is itself recomputed from the stored trajectory by the tests of
:mod:`mcverify.episode`), so a robustness can be re-derived from ``episodes.parquet`` alone.

Requirements (the registry :data:`mcverify.requirements.REQUIREMENTS`; units differ between
requirements, so :func:`min_robustness` over a set compares raw values):

- ``collision_front`` / ``collision_opp`` (m): the smallest footprint gap to veh_f / veh_o; the
  stored gap is 0 when the footprints touched or overlapped (it does not measure penetration), so a
  collision scores :data:`COLLISION_ROBUSTNESS_M`; +inf without veh_o.
- ``ellipse`` (dimensionless): min h_ef along the true trajectory (the ego c.g. outside the ellipse).
- ``invariance`` (dimensionless): min h_ef - epsilon (Theorem 2) for an episode that started at or
  above the level; +inf for one that started below it (the theorem says nothing there).
- ``h_eo`` (m): min h_eo while the ego borrowed the opposing lane with veh_o ahead; +inf if never.
- ``theorem5`` (NLP row units): "Q1 or Q2 is solvable at every control step", graded: the row's
  ``theorem5_margin``, the lowest over the control steps of the larger signed room of the step's Q1
  and Q2 solves (:func:`mcverify.control.margins.problem_margin`: the smallest barrier-row slack of a
  solved plan, >= 0; minus the violation left at the point a failed solve returned, < 0), negative
  exactly when some step solved neither (per step: :func:`theorem5_step_margin`). A row without the
  margin (MPC-DC, or stored before it existed) falls back to -(steps with neither solved) if any,
  else +1. ``theorem5_certified`` (steps) counts only the steps where both failures were certificates
  of infeasibility: -(such steps), else +1.
- ``safe`` (dimensionless): the minimum of ``collision_front`` / :data:`SAFE_GAP_SCALE_M`,
  ``collision_opp`` / :data:`SAFE_GAP_SCALE_M` and ``ellipse``: the row's ``safe`` event (the same
  sign as the unscaled minimum), with the gaps in h_ef's unit.
- ``"stl:<formula>"``: a user's requirement in Signal Temporal Logic over the stored per-sub-step
  signals, evaluated by rtamt on the episode's stored trajectory (:mod:`mcverify.analysis.stl`;
  :func:`robustness` takes the trajectory; NaN without it). Not stepwise, no stop, no first-violation time.

An error row (an episode that could not be simulated) has NaN robustness for every requirement.

Guides (:data:`GUIDES`, what a search may minimise instead of its requirement, ``[falsify] guide``):
every requirement, and ``"<r>@go_back"`` for each per-step requirement r (:data:`STEPWISE`): the
minimum of r's per-sub-step signal over the sub-steps where the ego goes back (Q2's mode), +inf if
it never did (:func:`guide_value`, from the stored trajectory). Going back is part of the episode,
so a negative ``r@go_back`` is a violation of r too; the converse is not true.

When a violation begins (:func:`first_violation_s`, the ``first_violation_s`` of every counterexample):
the first stored sub-step at which it shows, from the trajectory for the per-step requirements and
``theorem5`` (the first control step whose recorded decision solved neither Q1 nor Q2), and for any
requirement an episode was stopped at (``sim.stop_at``) from the stop: the first sub-step of its last
control period.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from mcverify.analysis import stl
from mcverify.analysis.theorem5 import theorem5_step_margin
from mcverify.requirements import (
    GO_BACK_SUFFIX,
    REQUIREMENTS,
    RUN_SUFFIX,
    SAFE_SET,
    STEPWISE,
    Requirement,
    is_stl,
    requirement,
)
from mcverify.requirements import GUIDE_NAMES as GUIDES

__all__ = ["COLLISION_ROBUSTNESS_M", "GO_BACK_MODE", "GO_BACK_SUFFIX", "GUIDES", "REQUIREMENTS", "ROBUSTNESS",
           "RUN_FACTOR", "RUN_SUFFIX", "SAFE_SET", "SIGNALS", "STEPWISE", "THEOREM5_SATISFIED", "Requirement",
           "first_violation_s", "guide_value", "is_error_row", "min_robustness", "requirement", "robustness",
           "robustness_table", "running_robustness", "theorem5_step_margin", "violated", "SAFE_GAP_SCALE_M",
           "check_requirement", "needs_trajectory"]

#: Robustness of a collision (m): the stored footprint gap is 0 on contact, whatever the overlap.
COLLISION_ROBUSTNESS_M = -1.0
#: Robustness of "Q1 or Q2 solvable" when every step had a solvable problem (the row has no margin).
THEOREM5_SATISFIED = 1.0

Row = Mapping[str, Any]


def _num(row: Row, key: str) -> float:
    value = row.get(key)
    return math.nan if value is None else float(value)


def _collision(gap_key: str, flag_key: str, needs_opp: bool) -> Callable[[Row], float]:
    def rob(row: Row) -> float:
        if needs_opp and row.get("opposing_kind") in (None, "none"):
            return math.inf
        if bool(row.get(flag_key)):
            return COLLISION_ROBUSTNESS_M
        gap = _num(row, gap_key)
        return math.inf if math.isnan(gap) and needs_opp else gap

    return rob


def _ellipse(row: Row) -> float:
    return _num(row, "min_h_front")


def _invariance(row: Row) -> float:
    h0, eps = _num(row, "h0_front"), _num(row, "epsilon")
    if math.isnan(eps) or h0 < eps:
        return math.inf
    return _num(row, "min_h_front") - eps


def _h_eo(row: Row) -> float:
    value = _num(row, "min_h_opp")
    return math.inf if math.isnan(value) else value


def _theorem5_count(key: str) -> Callable[[Row], float]:
    def rob(row: Row) -> float:
        steps = _num(row, key)
        if math.isnan(steps):
            return math.nan
        return -steps if steps > 0 else THEOREM5_SATISFIED

    return rob


def _theorem5(row: Row) -> float:
    """The row's ``theorem5_margin`` (graded); a row without one (MPC-DC, which has no Q2, or a run
    stored before the margin existed) falls back to the step count (same sign)."""
    margin = _num(row, "theorem5_margin")
    return _theorem5_count("both_infeasible_steps")(row) if math.isnan(margin) else margin


#: The robustness of each requirement of :data:`mcverify.requirements.REQUIREMENTS` (the same keys,
#: checked by tests/test_requirements.py), a function of one episode row.
ROBUSTNESS: dict[str, Callable[[Row], float]] = {
    "collision_front": _collision("min_gap_front_m", "collision_front", needs_opp=False),
    "collision_opp": _collision("min_gap_opp_any_m", "collision_opp", needs_opp=True),
    "ellipse": _ellipse,
    "invariance": _invariance,
    "h_eo": _h_eo,
    "theorem5": _theorem5,
    "theorem5_certified": _theorem5_count("both_certified_infeasible_steps"),
    "safe": lambda row: _safe(row),
}


#: The length (m) that turns a footprint gap into ``safe``'s dimensionless unit: half the default
#: ellipse semi-axis a (``BarrierParams.ellipse_a_m`` / 2, checked by tests/analysis). At the ellipse's
#: longitudinal tip dh_ef/dx = 2/a, so a metre of gap weighs what a metre along the road weighs in
#: h_ef there. A fixed unit (not the cell's a), so that ``safe`` compares across cells.
SAFE_GAP_SCALE_M = 0.5 * math.sqrt(2.0) * 4.885


def _safe(row: Row) -> float:
    """min(collision_front / scale, collision_opp / scale, ellipse): every member in h_ef's
    dimensionless unit (:data:`SAFE_GAP_SCALE_M`); dividing by a positive length keeps each sign."""
    gaps = (ROBUSTNESS["collision_front"](row), ROBUSTNESS["collision_opp"](row))
    return min(*(g / SAFE_GAP_SCALE_M for g in gaps), _ellipse(row))


def _robustness_of(name: str) -> Callable[[Row], float]:
    requirement(name)  # ValueError listing the known names
    return ROBUSTNESS[name]


def check_requirement(name: str) -> None:
    """ValueError of one line unless ``name`` is a built-in requirement or an STL requirement whose
    formula parses over the known signals (:func:`mcverify.analysis.stl.parse`)."""
    if is_stl(name):
        stl.parse(name)
    else:
        requirement(name)


def needs_trajectory(name: str) -> bool:
    """Does requirement ``name``'s robustness read the episode's stored trajectory (an STL one)?"""
    return is_stl(name)


def is_error_row(row: Row) -> bool:
    return row.get("error_message") is not None or row.get("outcome") == "error"


def robustness(row: Row, name: str, trajectory: Mapping[str, np.ndarray] | None = None) -> float:
    """Signed robustness of requirement ``name`` for one episode row (NaN for an error row). An STL
    requirement (``"stl:<formula>"``, :mod:`mcverify.analysis.stl`) is evaluated on the episode's
    stored ``trajectory``; NaN without one."""
    if is_stl(name):
        formula = stl.parse(name)
        if is_error_row(row) or trajectory is None:
            return math.nan
        return stl.robustness(formula, trajectory)
    rob = _robustness_of(name)
    return math.nan if is_error_row(row) else float(rob(row))




def min_robustness(row: Row, names: Sequence[str]) -> float:
    """Minimum robustness over the requirements ``names`` (NaN for an error row)."""
    if is_error_row(row):
        return math.nan
    return min(float(_robustness_of(n)(row)) for n in names)


def robustness_table(rows: Sequence[Row], names: Sequence[str] | None = None) -> dict[str, np.ndarray]:
    """Robustness of every row for each requirement in ``names`` (default: all), as float64
    arrays of shape (len(rows),)."""
    names = list(REQUIREMENTS) if names is None else list(names)
    return {n: np.array([robustness(r, n) for r in rows], dtype=np.float64) for n in names}


def violated(rows: Sequence[Row], name: str) -> np.ndarray:
    """Boolean mask, shape (len(rows),): the rows that violate requirement ``name``."""
    rob = np.array([robustness(r, name) for r in rows], dtype=np.float64)
    return np.asarray(rob < 0.0, dtype=bool)


#: ``"<r>@run"``: the factor on r's remaining (positive) running robustness per control step of the
#: current run of steps at which the planner solved neither Q1 nor Q2.
RUN_FACTOR = 0.3


def _gap_signal(trajectory: Mapping[str, np.ndarray], key: str, flag: str) -> np.ndarray:
    g = np.asarray(trajectory[key], dtype=np.float64)
    g = np.where(np.isnan(g), math.inf, g)  # no veh_o (yet): nothing to touch
    return np.where(np.asarray(trajectory[flag]) > 0, COLLISION_ROBUSTNESS_M, g)


def _h_front(trajectory: Mapping[str, np.ndarray]) -> np.ndarray:
    return np.asarray(trajectory["h_front"], dtype=np.float64)


Signal = Callable[[Mapping[str, np.ndarray], float, float], np.ndarray]

#: The per-sub-step signal of each per-step requirement (:data:`~mcverify.requirements.STEPWISE`, the
#: same keys, checked by tests/test_requirements.py): (trajectory, epsilon, h0) -> shape (sub-steps,),
#: reading the requirement's ``step_columns``.
SIGNALS: dict[str, Signal] = {
    "collision_front": lambda tr, eps, h0: _gap_signal(tr, "gap_front_m", "collision_front"),
    "collision_opp": lambda tr, eps, h0: _gap_signal(tr, "gap_opp_m", "collision_opp"),
    "ellipse": lambda tr, eps, h0: _h_front(tr),
    "invariance": lambda tr, eps, h0: _h_front(tr) - eps if h0 >= eps else np.full_like(_h_front(tr), math.inf),
    "safe": lambda tr, eps, h0: np.minimum(np.minimum(_gap_signal(tr, "gap_front_m", "collision_front"),
                                                      _gap_signal(tr, "gap_opp_m", "collision_opp"))
                                           / SAFE_GAP_SCALE_M, _h_front(tr)),
}


def _substep_signal(trajectory: Mapping[str, np.ndarray], name: str, epsilon: float, h0: float) -> np.ndarray:
    if name not in SIGNALS:
        raise ValueError(f"requirement {name!r} has no per-step robustness; stepwise: {', '.join(STEPWISE)}")
    return SIGNALS[name](trajectory, epsilon, h0)


#: The trajectory's ``mode`` of a step going back (:class:`mcverify.control.decision.Mode` GO_BACK;
#: the analysis layer does not import the control layer, tests/falsify checks they agree).
GO_BACK_MODE = 1


def guide_value(row: Row, trajectory: Mapping[str, np.ndarray] | None, name: str, *,
                control_period_s: float = math.nan) -> float:
    """The value of guide ``name`` (:data:`GUIDES`) for one episode: its row's robustness for a
    requirement; for ``"<r>@go_back"`` the minimum of r's per-sub-step signal over the sub-steps of
    the stored ``trajectory`` with ``mode`` == :data:`GO_BACK_MODE` (+inf if none); for ``"<r>@run"``
    the last value of its :func:`running_robustness` (needs ``control_period_s``). NaN for an error row."""
    if name in REQUIREMENTS:
        return robustness(row, name)
    if name not in GUIDES:
        raise ValueError(f"unknown guide {name!r}; known: {', '.join(GUIDES)}")
    if is_error_row(row):
        return math.nan
    if trajectory is None:
        raise ValueError(f"guide {name!r} needs the episode's stored trajectory")
    if name.endswith(RUN_SUFFIX):
        running = running_robustness(trajectory, name, control_period_s, epsilon=_num(row, "epsilon"),
                                     h0=_num(row, "h0_front"))
        return float(running[-1]) if running.size else math.inf
    signal = _substep_signal(trajectory, name.removesuffix(GO_BACK_SUFFIX), _num(row, "epsilon"), _num(row, "h0_front"))
    going_back = np.asarray(trajectory["mode"]) == GO_BACK_MODE
    return float(np.min(signal[going_back])) if going_back.any() else math.inf


def first_violation_s(row: Row, trajectory: Mapping[str, np.ndarray] | None, name: str, *,
                      control_period_s: float, stopped_at: str = "") -> float:
    """Time (s) of the first stored sub-step at which the episode violates requirement ``name``;
    NaN if it does not violate it (or is an error row) or the time cannot be located.

    Located from the stored ``trajectory`` for the per-step requirements (:data:`STEPWISE`) and for
    ``theorem5`` (the first sub-step of the first control step whose decision solved neither Q1 nor Q2:
    ``q1_solved`` not 1 and ``q2_solved`` 0, as the planner counts it) and ``theorem5_certified`` (the
    first sub-step of the first control step with ``both_certified`` 1); and, for any requirement, from
    the stop when the episode was ended at it (``stopped_at`` is the cell's ``sim.stop_at`` and the
    row's ``stopped_at_violation`` is set): the first sub-step of its last control period, since the
    rollout ends an episode at the end of the control period in which it first violated. Without a
    trajectory, ``safe`` falls back to the row's ``first_unsafe_s``. ``h_eo`` of an episode that ran
    on is not located (the trajectory does not record which sub-steps count for it), nor is
    ``theorem5_certified`` in a trajectory recorded before ``both_certified`` existed, nor any
    requirement whose columns the trajectory lacks."""
    rob = robustness(row, name)
    if not rob < 0.0:
        return math.nan
    if trajectory is not None and "t_s" in trajectory and len(trajectory["t_s"]):
        t = np.asarray(trajectory["t_s"], dtype=np.float64)
        if name in STEPWISE:
            try:
                hit = _substep_signal(trajectory, name, _num(row, "epsilon"), _num(row, "h0_front")) < 0.0
            except KeyError:  # a trajectory without the columns this requirement reads
                hit = None
            if hit is not None:
                return float(t[np.argmax(hit)]) if hit.any() else math.nan
        if name == "theorem5" and "q1_solved" in trajectory and "q2_solved" in trajectory:
            q1, q2 = (np.asarray(trajectory[k], dtype=np.float64) for k in ("q1_solved", "q2_solved"))
            hit = (q1 != 1.0) & (q2 == 0.0)
            return float(t[np.argmax(hit)]) if hit.any() else math.nan
        if name == "theorem5_certified" and "both_certified" in trajectory:
            hit = np.asarray(trajectory["both_certified"], dtype=np.float64) == 1.0
            return float(t[np.argmax(hit)]) if hit.any() else math.nan
        if stopped_at == name and bool(row.get("stopped_at_violation")):
            last_period = t > t[-1] - control_period_s + 1e-9
            return float(t[np.argmax(last_period)])
    if name == "safe":
        return _num(row, "first_unsafe_s")
    return math.nan


def running_robustness(trajectory: Mapping[str, np.ndarray], name: str, control_period_s: float, *,
                       epsilon: float = 0.0, h0: float = math.inf) -> np.ndarray:
    """Shape (steps,): the lowest robustness of requirement ``name`` (one of :data:`STEPWISE`) reached
    by the end of each control step, from a recorded trajectory (columns of
    :mod:`mcverify.episode.recording`, one row per sub-step at ``t_s`` in (k dt, (k + 1) dt] for
    control step k). Its last value is the episode's robustness; ``epsilon`` and ``h0`` (the row's
    ``epsilon`` and ``h0_front``) are needed for ``invariance`` only.

    ``"<r>@run"``: r's running robustness rho_k brought forward by the planner's trouble, the running
    minimum of rho_k c^(n_k) while rho_k > 0 and of rho_k once it is <= 0, with n_k the current run of
    control steps (k included) at which neither Q1 nor Q2 was solved (``q1_solved`` not 1 and
    ``q2_solved`` 0, as the planner counts them) and c = :data:`RUN_FACTOR`. It is negative exactly
    when r is violated, and one more unsolved step outranks ordinary differences in margin: on the
    closed loop a violation of the ellipse follows a run of 4-5 such steps (docs/rare_events.md, "A
    score that traps"), the turn-backs that precede it are reached by climbing that run, and a run
    that ends takes the value back to rho_k."""
    t = np.asarray(trajectory["t_s"], dtype=np.float64)
    if not t.size:
        return np.zeros(0)
    step = np.maximum(np.ceil(t / control_period_s - 1e-6).astype(np.int64) - 1, 0)
    base = name.removesuffix(RUN_SUFFIX)
    per_step = np.full(int(step[-1]) + 1, math.inf)
    np.minimum.at(per_step, step, _substep_signal(trajectory, base, epsilon, h0))
    running = np.minimum.accumulate(per_step)
    if base == name:
        return running
    runs = _unsolved_runs(trajectory, step, running.size)
    with np.errstate(invalid="ignore"):  # inf * c^n stays inf
        brought = np.where(running > 0.0, running * RUN_FACTOR ** runs.astype(np.float64), running)
    return np.minimum.accumulate(brought)


def _unsolved_runs(trajectory: Mapping[str, np.ndarray], step: np.ndarray, steps: int) -> np.ndarray:
    """Shape (steps,): the current run of control steps at which neither Q1 nor Q2 was solved, after
    each step (0 after a solved step), from the sub-steps' ``q1_solved``/``q2_solved``."""
    q1, q2 = (np.asarray(trajectory[k], dtype=np.float64) for k in ("q1_solved", "q2_solved"))
    unsolved = np.zeros(steps, dtype=bool)
    unsolved[step[(q1 != 1.0) & (q2 == 0.0)]] = True
    runs = np.zeros(steps, dtype=np.int64)
    for k in range(steps):
        runs[k] = runs[k - 1] + 1 if unsolved[k] and k else int(unsolved[k])
    return runs
