"""Users' requirements in Signal Temporal Logic, evaluated on a stored trajectory by rtamt.

A requirement named ``"stl:<formula>"`` (:data:`mcverify.requirements.STL_PREFIX`) holds when
``<formula>``, in rtamt's STL syntax (``always``, ``eventually``, ``until``, ``and``, ``or``, ``not``,
``implies``, time bounds ``[a:b]`` in seconds, comparisons and arithmetic over signals), holds at the
episode's first recorded sub-step. Its robustness is rtamt's discrete-time quantitative semantics
there (the offline :class:`rtamt.StlDiscreteTimeSpecification`): for ``x >= c`` the value x - c,
``always`` the minimum, ``eventually`` the maximum, ``and``/``or`` min/max; negative iff violated.
``always (h_ef >= 0.3)`` thus reads min h_ef - 0.3 over the episode, the built-in ``invariance``
robustness at ε = 0.3 bit for bit (tests/analysis/test_stl.py).

Time base: the recorded sub-steps of :mod:`mcverify.episode.recording` (``t_s``, one sample per
integration sub-step, the control step's decision and measurements repeated over its sub-steps), with
the sampling period their median spacing; the first sample is the end of the first sub-step, not t = 0.

Signals (:data:`SIGNALS`): every numeric column of the stored trajectory by its own name, and
``h_ef`` (= ``h_front``), ``h_eo`` (= ``h_opp``), ``theorem5_margin``
(:func:`mcverify.analysis.robustness.theorem5_step_margin`). A NaN sample (no veh_o yet or at all, a
problem not solved at that step) reads as +inf: there is nothing there to violate. A formula naming
any other signal, or one rtamt cannot parse, is a ValueError of one line.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import math
import re
from collections.abc import Iterator, Mapping
from typing import NamedTuple

import numpy as np

from mcverify.analysis.theorem5 import theorem5_step_margin
from mcverify.requirements import STL_PREFIX

#: The stored trajectory columns a formula may name (:mod:`mcverify.episode.recording`).
TRAJECTORY_SIGNALS: tuple[str, ...] = (
    "ego_x_m", "ego_y_m", "ego_psi_rad", "ego_speed_mps", "front_x_m", "front_y_m", "front_speed_mps",
    "opp_x_m", "opp_y_m", "opp_speed_mps", "alpha_mps2", "beta_rad",
    "h_front", "dist_front_m", "gap_front_m", "collision_front", "h_opp", "gap_opp_m", "collision_opp",
    "active_problem", "mode", "opp_detected", "q1_solved", "q2_solved", "q1_time_s", "q2_time_s",
    "table_one_row", "both_certified", "q1_margin", "q2_margin",
    "meas_front_x_m", "meas_front_y_m", "meas_front_speed_mps", "meas_opp_x_m", "meas_opp_speed_mps",
)
#: Other names for stored columns (the paper's).
ALIASES: dict[str, str] = {"h_ef": "h_front", "h_eo": "h_opp"}
#: Signals computed from the stored columns.
DERIVED: tuple[str, ...] = ("theorem5_margin",)
#: Every signal a formula may name.
SIGNALS: tuple[str, ...] = TRAJECTORY_SIGNALS + tuple(ALIASES) + DERIVED
#: rtamt's sampling tolerance: the share of the period by which a sample's spacing may differ from it.
SAMPLING_TOLERANCE = 0.1


class StlFormula(NamedTuple):
    """A parsed STL requirement: its ``name`` (``"stl:<formula>"``), the ``formula`` text and the
    ``signals`` it reads (a subset of :data:`SIGNALS`, in that order)."""

    name: str
    formula: str
    signals: tuple[str, ...]


@contextlib.contextmanager
def _quiet() -> Iterator[None]:
    """rtamt announces an undeclared variable on the root logger before failing on it."""
    logging.disable(logging.WARNING)
    try:
        yield
    finally:
        logging.disable(logging.NOTSET)


def _spec(formula: str, signals: tuple[str, ...], period_s: float = 1.0):
    import rtamt  # noqa: PLC0415 - the parser (antlr) loads only when a formula is used

    spec = rtamt.StlDiscreteTimeSpecification()
    for name in signals:
        spec.declare_var(name, "float")
    spec.set_sampling_period(period_s, "s", SAMPLING_TOLERANCE)
    spec.spec = formula
    with _quiet():
        spec.parse()
    return spec


@functools.lru_cache(maxsize=64)
def parse(name: str) -> StlFormula:
    """The STL requirement ``name`` (``"stl:<formula>"``), checked: ValueError of one line for a formula
    rtamt cannot parse or one naming a signal outside :data:`SIGNALS`."""
    if not name.startswith(STL_PREFIX):
        raise ValueError(f"requirement {name!r} is not an STL requirement ({STL_PREFIX}<formula>)")
    formula = name.removeprefix(STL_PREFIX).strip()
    if not formula:
        raise ValueError(f"requirement {name!r}: empty STL formula after {STL_PREFIX!r}")
    try:
        spec = _spec(formula, SIGNALS)
    except KeyError as exc:  # rtamt's parser on an undeclared variable
        raise ValueError(f"STL formula {formula!r}: unknown signal {exc.args[0]!r}; known: {', '.join(SIGNALS)}") \
            from None
    except Exception as exc:  # noqa: BLE001 - rtamt raises its own and antlr's exceptions, with multi-line text
        message = " ".join(str(exc).split()) or type(exc).__name__
        raise ValueError(f"STL formula {formula!r}: {message}") from None
    del spec  # parsed with every signal declared; evaluated with only those the formula names
    used = set(re.findall(r"[A-Za-z_][A-Za-z_0-9]*", formula))
    return StlFormula(name, formula, tuple(s for s in SIGNALS if s in used))


def signal(trajectory: Mapping[str, np.ndarray], name: str) -> np.ndarray:
    """Signal ``name`` (:data:`SIGNALS`) of a stored trajectory, float64 of shape (sub-steps,), NaN read
    as +inf. KeyError if the trajectory lacks the column it needs (one recorded before it existed)."""
    if name == "theorem5_margin":
        values = theorem5_step_margin(trajectory)
    else:
        values = np.asarray(trajectory[ALIASES.get(name, name)], dtype=np.float64)
    return np.where(np.isnan(values), math.inf, values)


def robustness(formula: StlFormula, trajectory: Mapping[str, np.ndarray]) -> float:
    """The robustness of ``formula`` at the first recorded sub-step of ``trajectory`` (NaN for an empty
    one); ValueError naming the column if the trajectory lacks one the formula reads."""
    t = np.asarray(trajectory["t_s"], dtype=np.float64)
    if not t.size:
        return math.nan
    try:
        data = {name: signal(trajectory, name).tolist() for name in formula.signals}
    except KeyError as exc:
        raise ValueError(f"STL formula {formula.formula!r} reads {exc.args[0]!r}, which this stored trajectory "
                         "lacks (recorded by an older version)") from None
    period_s = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    spec = _spec(formula.formula, formula.signals, period_s)
    data["time"] = t.tolist()
    with _quiet():
        result = spec.evaluate(data)
    return float(result[0][1])
