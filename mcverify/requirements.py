"""The requirements, estimate targets and splitting scores: one registry, one vocabulary.

Every layer that names a requirement reads it from here: the model's ``sim.stop_at`` and
``[falsify] guide`` (:data:`REQUIREMENT_NAMES`, :data:`GUIDE_NAMES`), the rollout's stop test
(:attr:`Requirement.stop`), the robustness of :mod:`mcverify.analysis.robustness` (one implementation
per name here, checked complete by tests/test_requirements.py), the estimate targets of
:mod:`mcverify.analysis.estimates` (:data:`TARGETS`), the splitting and importance scores of
:mod:`mcverify.estimate.closed_loop` (:data:`SCORES`) and the command line's choices and help.

A new requirement is one :class:`Requirement` here and its robustness in
:mod:`mcverify.analysis.robustness` (and, if it has a per-step form, its per-sub-step signal there).

This module is a low layer: numpy only, no JAX, no model, no analysis.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np


class StopInputs(NamedTuple):
    """What the rollout knows of a chunk after a control step, for the stop test of ``sim.stop_at``
    (each array of shape (episodes,)): the running safety trace, Theorem 5's counters, h_ef at the
    start, the cell's level and whether the cell has veh_o."""

    collision_front: np.ndarray
    collision_opp: np.ndarray
    min_h_front: np.ndarray
    min_h_opp: np.ndarray
    both_infeasible_steps: np.ndarray
    both_certified_infeasible_steps: np.ndarray
    h0_front: np.ndarray
    epsilon: float
    has_opp: bool


StopMask = Callable[[StopInputs], np.ndarray]


@dataclass(frozen=True)
class Requirement:
    """One requirement.

    name: the name every layer uses; unit: of its robustness ("" dimensionless); statement: one line
    of help; columns: the stored per-episode columns its robustness reads; step_columns: the columns
    of a stored trajectory its per-sub-step signal reads (() when it has no per-step form);
    stepwise: whether it has a per-sub-step signal (a ``@go_back``/``@run`` guide, a splitting
    search); stop: the mask of the episodes that have violated it so far (``sim.stop_at``); target:
    the estimate target whose event is exactly its violation ("" none)."""

    name: str
    unit: str
    statement: str
    columns: tuple[str, ...]
    step_columns: tuple[str, ...]
    stepwise: bool
    stop: StopMask
    target: str = ""


def _collision_front(s: StopInputs) -> np.ndarray:
    return np.asarray(s.collision_front, dtype=bool)


def _collision_opp(s: StopInputs) -> np.ndarray:
    return np.asarray(s.collision_opp, dtype=bool) & s.has_opp


def _ellipse(s: StopInputs) -> np.ndarray:
    return np.asarray(s.min_h_front, dtype=float) < 0.0


def _invariance(s: StopInputs) -> np.ndarray:
    return (np.asarray(s.h0_front) >= s.epsilon) & (np.asarray(s.min_h_front, dtype=float) - s.epsilon < 0.0)


def _h_eo(s: StopInputs) -> np.ndarray:
    return (np.asarray(s.min_h_opp, dtype=float) < 0.0) & s.has_opp


def _theorem5(s: StopInputs) -> np.ndarray:
    return np.asarray(s.both_infeasible_steps) > 0


def _theorem5_certified(s: StopInputs) -> np.ndarray:
    return np.asarray(s.both_certified_infeasible_steps) > 0


def _safe(s: StopInputs) -> np.ndarray:
    return _collision_front(s) | _collision_opp(s) | _ellipse(s)


_GAP_FRONT = ("gap_front_m", "collision_front")
_GAP_OPP = ("gap_opp_m", "collision_opp")

#: The requirement behind the row's ``safe`` flag (``safe`` is the minimum of their robustness).
SAFE_SET: tuple[str, ...] = ("collision_front", "collision_opp", "ellipse")

_ALL: tuple[Requirement, ...] = (
    Requirement("collision_front", "m", "the ego and veh_f footprints never touch",
                ("min_gap_front_m", "collision_front"), _GAP_FRONT, True, _collision_front),
    Requirement("collision_opp", "m", "the ego and veh_o footprints never touch",
                ("min_gap_opp_any_m", "collision_opp", "opposing_kind"), _GAP_OPP, True, _collision_opp),
    Requirement("ellipse", "", "the ego c.g. stays outside veh_f's safety ellipse (h_ef >= 0)",
                ("min_h_front",), ("h_front",), True, _ellipse, target="ellipse"),
    Requirement("invariance", "", "h_ef stays at or above the level epsilon once there (Theorem 2)",
                ("min_h_front", "h0_front", "epsilon"), ("h_front",), True, _invariance, target="invariance"),
    Requirement("h_eo", "m", "h_eo >= 0 while the ego borrows the opposing lane with veh_o ahead",
                ("min_h_opp",), (), False, _h_eo, target="opp_invariance"),
    Requirement("theorem5", "steps", "Q1 or Q2 is solved at every control step (Theorem 5)",
                ("both_infeasible_steps",), ("q1_solved", "q2_solved"), False, _theorem5),
    Requirement("theorem5_certified", "steps", "no control step where IPOPT certified both Q1 and Q2 infeasible",
                ("both_certified_infeasible_steps",), ("both_certified",), False, _theorem5_certified),
    Requirement("safe", "", "no collision with veh_f or veh_o and no ellipse violation (the row's safe flag)",
                ("min_gap_front_m", "collision_front", "min_gap_opp_any_m", "collision_opp", "opposing_kind",
                 "min_h_front"), _GAP_FRONT + _GAP_OPP + ("h_front",), True, _safe, target="unsafe"),
)

#: Every requirement by name, in the order the reports list them.
REQUIREMENTS: dict[str, Requirement] = {r.name: r for r in _ALL}
#: Their names: the valid ``sim.stop_at`` and ``[falsify] requirement`` values.
REQUIREMENT_NAMES: tuple[str, ...] = tuple(REQUIREMENTS)
#: The requirements with a per-sub-step signal (a splitting search's, a ``@go_back``/``@run`` guide's).
STEPWISE: tuple[str, ...] = tuple(r.name for r in _ALL if r.stepwise)
#: The suffix of a guide restricted to the sub-steps where the ego goes back.
GO_BACK_SUFFIX = "@go_back"
#: The suffix of a guide brought forward by the current run of steps with neither problem solved.
RUN_SUFFIX = "@run"
#: What a falsification search may minimise instead of its requirement (``[falsify] guide``): any
#: requirement, or a per-step one restricted to the sub-steps going back or brought forward by the run
#: of unsolved steps (:func:`mcverify.analysis.robustness.guide_value`).
GUIDE_NAMES: tuple[str, ...] = REQUIREMENT_NAMES + tuple(
    f"{name}{suffix}" for suffix in (GO_BACK_SUFFIX, RUN_SUFFIX) for name in STEPWISE)


#: The prefix of a user's requirement in Signal Temporal Logic: ``"stl:<formula>"`` names the requirement
#: that ``<formula>`` (rtamt's STL syntax over the stored per-sub-step signals) holds from the episode's first
#: recorded sub-step; its robustness is :func:`mcverify.analysis.stl.robustness` on the stored trajectory.
STL_PREFIX = "stl:"


def is_stl(name: str) -> bool:
    """Is ``name`` an STL requirement (``"stl:<formula>"``)?"""
    return name.startswith(STL_PREFIX)


def _never_stops(s: StopInputs) -> np.ndarray:
    raise ValueError("an STL requirement cannot stop an episode (sim.stop_at): it is evaluated on the stored "
                     "trajectory after the episode")


def _stl_requirement(name: str) -> Requirement:
    formula = name.removeprefix(STL_PREFIX).strip()
    if not formula:
        raise ValueError(f"requirement {name!r}: empty STL formula after {STL_PREFIX!r}")
    return Requirement(name, "", f"the STL formula {formula} holds (robustness by rtamt on the stored trajectory)",
                       (), (), False, _never_stops)


def requirement(name: str) -> Requirement:
    """The requirement ``name`` (a built-in one, or ``"stl:<formula>"``, whose formula is parsed where
    it is evaluated, :mod:`mcverify.analysis.stl`); ValueError listing the known names otherwise."""
    if is_stl(name):
        return _stl_requirement(name)
    try:
        return REQUIREMENTS[name]
    except KeyError:
        raise ValueError(f"unknown requirement {name!r}; known: {', '.join(REQUIREMENTS)} or "
                         f"{STL_PREFIX}<formula>") from None


# ------------------------------------------------------------------------------ estimate targets


@dataclass(frozen=True)
class Target:
    """An event whose rate ``mcverify estimate`` reports.

    definition: one line; flags: the stored boolean columns whose OR is the event (a missing column
    reads as False); negated: the event is the flag's negation instead (one column; a row without it
    shows no event); requirements: the requirements whose violation it is."""

    name: str
    definition: str
    flags: tuple[str, ...]
    requirements: tuple[str, ...]
    negated: bool = False


_TARGETS: tuple[Target, ...] = (
    Target("collision", "the ego footprint overlapped the front or the opposing vehicle's (collision_front or "
           "collision_opp)", ("collision_front", "collision_opp"), ("collision_front", "collision_opp")),
    Target("ellipse", "h_ef < 0 at some sub-step (ellipse_violation)", ("ellipse_violation",), ("ellipse",)),
    Target("unsafe", "not safe: a collision or h_ef < 0 (not safe)", ("safe",), ("safe",), negated=True),
    Target("invariance", "h_ef started at or above ε and fell below it (invariance_breach)",
           ("invariance_breach",), ("invariance",)),
    Target("opp_invariance", "h_eo fell below its level while borrowing the opposing lane (opp_invariance_breach)",
           ("opp_invariance_breach",), ("h_eo",)),
)

#: Every estimate target by name (``mcverify estimate --target``).
TARGETS: dict[str, Target] = {t.name: t for t in _TARGETS}


# ------------------------------------------------------------------------------ splitting scores


@dataclass(frozen=True)
class Score:
    """A running score of the closed loop (splitting levels, importance stages), >= 0 exactly at its
    target's event. signal: what it is the running minimum of ("h_ef" or "gap", the footprint gap to
    veh_f and veh_o); unsolved: how the steps with neither problem solved bring it forward ("" not,
    "count" all of them, "run" the current run; :mod:`mcverify.estimate.closed_loop`)."""

    name: str
    target: str
    signal: str
    unsolved: str
    help: str


_SCORES: tuple[Score, ...] = (
    Score("h_ef", "ellipse", "h_ef", "", "minus the running minimum of h_ef"),
    Score("h_ef_held", "ellipse", "h_ef", "count", "h_ef brought forward by all steps with neither problem solved"),
    Score("h_ef_run", "ellipse", "h_ef", "run", "h_ef brought forward by the current run of such steps"),
    Score("gap", "collision", "gap", "", "minus the running minimum footprint gap to veh_f and veh_o"),
    Score("gap_run", "collision", "gap", "run", "the gap brought forward by the current run of such steps"),
)

#: Every score by name (``mcverify estimate --score``).
SCORE_REGISTRY: dict[str, Score] = {s.name: s for s in _SCORES}
#: Score name -> the target event it reaches at level 0.
SCORES: dict[str, str] = {s.name: s.target for s in _SCORES}
#: The scores built on h_ef (the others on the footprint gap).
H_EF_SCORES: tuple[str, ...] = tuple(s.name for s in _SCORES if s.signal == "h_ef")
#: The targets a score reaches (what splitting and importance sampling can estimate).
SCORED_TARGETS: tuple[str, ...] = tuple(t for t in TARGETS if any(s.target == t for s in _SCORES))
#: The performance functions subset simulation can climb (``mcverify estimate --performance``), the default
#: first; each is <= 0 exactly at its target's event (:mod:`mcverify.estimate.input_vector`).
PLAIN_ROBUSTNESS = "robustness"
PRECURSOR_LADDER = "precursor-ladder"
MARGIN_LADDER = "margin-ladder"
#: margin-ladder: a Theorem 5 margin of -0.1 halves the robustness, as one unsolved step does on the precursor
#: ladder (the events' margins are -0.4 to -2.4 on the validation cell at 1.25 and 2 times the paper's noise).
MARGIN_FACTOR = 10.0
PERFORMANCES: tuple[str, ...] = (PLAIN_ROBUSTNESS, PRECURSOR_LADDER, MARGIN_LADDER)
#: What each performance function other than the plain robustness climbs, in words (reports, help).
PERFORMANCE_TEXT: dict[str, str] = {
    PRECURSOR_LADDER: "the robustness / (1 + the longest run of control steps with neither Q1 nor Q2 solved)",
    MARGIN_LADDER: f"the robustness / (1 + {MARGIN_FACTOR:g} x the depth of the lowest Theorem 5 margin below 0)",
}


def margin_ladder(value: float, theorem5_margin: float) -> float:
    """``value`` divided by 1 + MARGIN_FACTOR times the depth of ``theorem5_margin`` below 0 (no depth where the
    margin is not negative or not measured): a positive divisor, so the sign of ``value`` is kept, and among
    equal values the episode whose planner went deeper into having neither problem solvable ranks lower
    (subset simulation's ``margin-ladder`` performance function)."""
    depth = max(0.0, -theorem5_margin) if math.isfinite(theorem5_margin) else 0.0
    return value / (1.0 + MARGIN_FACTOR * depth)


def default_score(target: str) -> str:
    """The plain score of a scored target (its first score): "gap" for collision, "h_ef" for ellipse."""
    return next(s.name for s in _SCORES if s.target == target)


# ------------------------------------------------------------------------------ command-line help


def requirement_help() -> str:
    """The requirement names as the command line lists them: "a, b, ... or z"."""
    return _spoken(REQUIREMENT_NAMES + (f"{STL_PREFIX}<formula> (STL over the stored signals)",))


def target_help() -> str:
    """The target names as the command line lists them."""
    return ", ".join(TARGETS)


def score_help() -> str:
    """Each score with its target and what it is, for ``mcverify estimate --score``."""
    return "; ".join(f"{s.name} (target {s.target}): {s.help}" for s in _SCORES)


def _spoken(names: tuple[str, ...]) -> str:
    return f"{', '.join(names[:-1])} or {names[-1]}" if len(names) > 1 else "".join(names)
