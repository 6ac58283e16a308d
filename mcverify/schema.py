"""The episode row, declared once: every column of ``episodes.parquet`` (and of the chunk files).

:data:`EPISODE_COLUMNS` lists, in file order, each column's name, Arrow type, unit and one-line
definition. The rollout's rows (:mod:`mcverify.episode.row`) carry exactly these names, the
executors' error rows a subset of them, the store writes and merges chunks with these types
(:func:`arrow_schema`), the summary reads them by these names, and the metric table of docs/metrics.md is
rendered from them (:func:`markdown_table`; a test keeps the two equal).

Units: ``m``, ``s``, ``m/s^2``; an empty unit means dimensionless, a count, a flag or text. The
barrier values (``h_*``, ``epsilon``, ``lambda0``) are dimensionless except h_eo, which is a
distance (m).

Beside these, one declared family, :data:`GRID_FAMILY`: the *grid values*, one column per model
field that the campaign's grid or axes vary between cells, named as in the campaign file
(``<section>.<field>``, e.g. ``barrier.epsilon``) and typed by :func:`grid_columns`. They are the
episode's inputs copied from its cell's overrides when the chunks are merged, not metrics: no
re-computation from the trajectory applies to them. ``cells.parquet`` has the same columns.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import pyarrow as pa

from mcverify.draws import DRAWS

#: ``outcome`` of an episode that could not be simulated (its metrics are null).
ERROR_OUTCOME = "error"
#: ``outcome`` of an episode a falsification search ended at its first violation (``sim.stop_at``).
STOPPED_OUTCOME = "stopped"
#: The column that carries an episode's error message (null for every simulated episode).
ERROR_COLUMN = "error_message"

_INT, _FLOAT, _STR, _BOOL = pa.int64(), pa.float64(), pa.string(), pa.bool_()


@dataclass(frozen=True)
class Column:
    """One episode column.

    name: the column name; type: its Arrow type; unit: its unit ("" if none); definition: one
    sentence; identity: it identifies the episode (present in every row, error rows included);
    wall_clock: it depends on the machine (the only columns not reproducible bit for bit);
    finite: finite for every simulated episode (NaN or inf there means the plant blew up).
    """

    name: str
    type: pa.DataType
    unit: str
    definition: str
    identity: bool = False
    wall_clock: bool = False
    finite: bool = False


def _c(name: str, type_: pa.DataType, unit: str, definition: str, **flags: bool) -> Column:
    return Column(name, type_, unit, definition, **flags)


#: Every column of ``episodes.parquet``, in file order.
EPISODE_COLUMNS: tuple[Column, ...] = (
    # identification
    _c("episode_id", _INT, "", "episode id, unique in the run (the cell's offset + cell_episode)", identity=True),
    _c("cell_episode", _INT, "", "episode id within its cell (0, 1, ...)", identity=True),
    _c("cell", _STR, "", "the cell's name", identity=True),
    _c("cell_index", _INT, "", "the cell's index in the campaign", identity=True),
    _c("seed", _INT, "", "the campaign's seed", identity=True),
    _c("controller", _STR, "", "the controller: vlcbf (the paper's dual TO-CBF-MPC), mpcdc (the baseline) or "
       "mpcdc_eps (the baseline at the level epsilon)"),
    _c("opposing_kind", _STR, "", "the opposing vehicle: none, autonomous or human"),
    *(_c(d.column, _FLOAT, d.unit, d.definition) for d in DRAWS),
    # outcome
    _c("outcome", _STR, "", "overtook, went_back, timeout, stopped (falsify mode: ended at its first violation "
       "before a goal, see stopped_at_violation) or error (an episode that could not be simulated)"),
    _c("overtook", _BOOL, "", "the paper's convergence test was met ahead of the front vehicle"),
    _c("went_back", _BOOL, "", "the episode ended behind the front vehicle in the ego lane (Q2's goal)"),
    _c("timeout", _BOOL, "", "neither goal was reached within the episode time limit"),
    _c("end_time_s", _FLOAT, "s", "simulated time until the episode ended"),
    _c("overtake_time_s", _FLOAT, "s", "time from the start to the paper's convergence test (x_e >= x_f + phi v_f "
       "and |y_e| <= eps_y on measured values); NaN unless overtaken"),
    _c("lane_borrow_time_s", _FLOAT, "s", "first to last sub-step with the ego footprint in the opposing lane"),
    # safety
    _c("collision_front", _BOOL, "", "the oriented footprints of ego and front vehicle overlapped at some sub-step"),
    _c("collision_opp", _BOOL, "", "the oriented footprints of ego and opposing vehicle overlapped at some sub-step"),
    _c("min_h_front", _FLOAT, "", "minimum of the barrier h_ef along the true trajectory", finite=True),
    _c("min_dist_front_m", _FLOAT, "m", "the paper's \"min dist. with veh_f\": smallest signed distance from the "
       "ego c.g. to the ellipse h_ef = 0, negative inside", finite=True),
    _c("min_gap_front_m", _FLOAT, "m", "smallest gap between the ego and front vehicle footprints", finite=True),
    _c("min_gap_opp_m", _FLOAT, "m", "the paper's \"min dist. with veh_o\": smallest footprint gap to veh_o while "
       "the ego footprint reaches into the opposing lane with veh_o ahead (NaN if never)"),
    _c("min_gap_opp_any_m", _FLOAT, "m", "smallest footprint gap to veh_o at any time (NaN without veh_o)"),
    _c("min_h_opp", _FLOAT, "m", "minimum of h_eo under the condition of min_gap_opp_m (NaN if never)"),
    _c("speed_excess_mps", _FLOAT, "m/s", "largest ego speed above ego.speed_max_mps on the true trajectory, at "
       "every sub-step (<= 0: the limit held; the MPC keeps it at its nodes only)", finite=True),
    _c("speed_excess_t_s", _FLOAT, "s", "when speed_excess_mps was reached (NaN if the limit held)"),
    _c("accel_excess_mps2", _FLOAT, "m/s^2", "largest excess of the applied acceleration alpha over "
       "[ego.accel_min_mps2, ego.accel_max_mps2] (<= 0: within)"),
    _c("accel_excess_t_s", _FLOAT, "s", "start of the control period of accel_excess_mps2 (NaN if within)"),
    _c("slip_excess_rad", _FLOAT, "rad", "largest excess of the applied slip abs(beta) over ego.slip_max_rad "
       "(<= 0: within)"),
    _c("slip_excess_t_s", _FLOAT, "s", "start of the control period of slip_excess_rad (NaN if within)"),
    _c("ellipse_violation", _BOOL, "", "min_h_front < 0: the ego c.g. entered the safety ellipse"),
    _c("safe", _BOOL, "", "no collision with either vehicle and no ellipse violation"),
    _c("first_unsafe_s", _FLOAT, "s", "start of the control period in which the ego first left the safe set"),
    _c("first_unsafe_cause", _STR, "", "what drove the ego then: planned (a solved plan), held (a failed "
       "problem's old plan), fallback (no plan) or lane_keeping (the settling law after the goal test); empty if "
       "safe"),
    _c("h0_front", _FLOAT, "", "h_ef at the start", finite=True),
    _c("epsilon", _FLOAT, "", "the cell's level epsilon of h_ef"),
    _c("lambda0", _FLOAT, "", "the cell's level parameter lambda0 (<= 0)"),
    _c("invariance_breach", _BOOL, "", "h_ef started at or above epsilon and fell below it (Theorem 2)"),
    _c("invariance_margin", _FLOAT, "", "min_h_front - epsilon"),
    _c("opp_invariance_breach", _BOOL, "", "h_eo fell below its level while the ego borrowed the opposing lane"),
    _c("opp_spawn_s", _FLOAT, "s", "when veh_o appeared: 0 with opposing.spawn = start, the ego's first entry "
       "into the opposing lane with lane_entry (NaN if it never entered it, or without veh_o)"),
    # settling: sim.settle_s of lane keeping after the goal test (mcverify.control.lane_keeping)
    _c("settle_end_s", _FLOAT, "s", "simulated time at which the episode's simulation stopped: end_time_s plus the "
       "settling period (cut at the time limit); every safety column covers the episode up to it"),
    _c("conv_heading_rad", _FLOAT, "rad", "ego heading psi at the goal test (NaN unless overtook or went_back)"),
    _c("conv_lateral_speed_mps", _FLOAT, "m/s", "ego lateral speed y' = v sin psi + v cos psi beta at the goal test, "
       "under the input then applied (NaN unless overtook or went_back)"),
    _c("conv_line_excess_m", _FLOAT, "m", "how far the ego footprint reached past the ego lane's left edge (the lane "
       "line) at the goal test, 0 inside (NaN unless overtook or went_back)"),
    _c("end_heading_rad", _FLOAT, "rad", "ego heading psi at settle_end_s"),
    _c("end_lateral_speed_mps", _FLOAT, "m/s", "ego lateral speed y' at settle_end_s, under the input then applied"),
    _c("end_line_excess_m", _FLOAT, "m", "how far the ego footprint reached past the lane line at settle_end_s, 0 "
       "inside"),
    _c("settle_line_excess_max_m", _FLOAT, "m", "largest conv_line_excess_m over the settling period, every sub-step "
       "from the goal test to settle_end_s (NaN unless overtook or went_back)"),
    _c("settled_in_lane", _BOOL, "", "the goal test fired and at settle_end_s the ego footprint lay inside its lane "
       "(between the road's outer edge and the lane line)"),
    _c("unsafe_in_settling", _BOOL, "", "the ego first left the safe set after the goal test, in the settling "
       "period (first_unsafe_s >= end_time_s)"),
    _c("stopped_at_violation", _BOOL, "", "falsify mode (sim.stop_at): the episode was ended at the end of the "
       "control period in which it first violated that requirement; its trajectory and every metric stop at "
       "settle_end_s (outcome stopped, or the goal's outcome if it was settling); always false in run and estimate"),
    # decisions (Theorem 5, Algorithm 1, Table I)
    _c("steps", _INT, "", "control steps run"),
    _c("opp_detected_steps", _INT, "", "control steps with veh_o detected"),
    _c("q1_fail_steps", _INT, "", "control steps where Q1 was solved and failed"),
    _c("q2_fail_steps", _INT, "", "control steps where Q2 was solved and failed (mpc.q2_solve = when_needed: Q2 is "
       "not solved while overtaking with Q1 solved)"),
    _c("both_infeasible_steps", _INT, "", "control steps with neither Q1 nor Q2 solved (Theorem 5)"),
    _c("fallback_steps", _INT, "", "control steps with no plan at all: brake in lane"),
    _c("held_steps", _INT, "", "control steps that applied the rest of the last plan (no problem solved)"),
    _c("q2_driven_steps", _INT, "", "control steps driven by Q2"),
    _c("q1_rescue_steps", _INT, "", "control steps going back where Q2 failed and Q1's plan was applied"),
    _c("switched_to_q2_at_s", _FLOAT, "s", "when the ego abandoned the overtake (NaN if never)"),
    _c("went_back_reason", _STR, "", "why it went back: q1_not_solved or table_one_row_<k>; empty if not"),
    _c("table_one_rows", _STR, "", "JSON counts of the Table I rows met (row -> steps)"),
    # Q1 failures by kind, abandonment (mpc.abandon_rule) and Theorem 5 by evidence
    _c("q1_fail_certified_steps", _INT, "", "q1_fail_steps where IPOPT certified Q1 infeasible (directly or as the "
       "fast path's fallback)"),
    _c("q1_fail_presumed_steps", _INT, "", "q1_fail_steps presumed infeasible: a fast-path-only failure of a Q1 "
       "certified infeasible shortly before (the infeasibility memo)"),
    _c("q1_fail_iteration_limit_steps", _INT, "", "q1_fail_steps that ended on the solver's iteration limit"),
    _c("q1_fail_other_steps", _INT, "", "the other q1_fail_steps: numerical failure, exception, invalid input or a "
       "solution rejected by the feasibility check (the four q1_fail_* columns sum to q1_fail_steps)"),
    _c("q1_held_steps", _INT, "", "control steps overtaking where Q1 failed, Q2 solved and mpc.abandon_rule had not "
       "fired: the ego kept its last Q1 plan"),
    _c("went_back_q1_failure", _STR, "", "the kind of the Q1 failure that abandoned the overtake: "
       "certified_infeasible, presumed_infeasible, iteration_limit or other; empty if none did"),
    _c("both_certified_infeasible_steps", _INT, "", "both_infeasible_steps where IPOPT certified both Q1 and Q2 "
       "infeasible at that step (a counter-example to Theorem 5, up to local infeasibility)"),
    _c("both_unsolved_uncertified_steps", _INT, "", "the other both_infeasible_steps: at least one of Q1, Q2 ran out "
       "of iterations, failed numerically or was only presumed infeasible (a solver budget, not a proof)"),
    _c("both_infeasible_longest_run", _INT, "", "longest run of consecutive control steps counted in "
       "both_infeasible_steps"),
    _c("both_infeasible_longest_run_first_step", _INT, "", "0-based control step at which that longest run began (the "
       "first of equally long runs; -1 if none)"),
    _c("theorem5_margin", _FLOAT, "", "lowest Theorem 5 margin of a control step: the larger signed room of the "
       "step's Q1 and Q2 solves (problem_margin: the smallest barrier-row slack of a solved plan, minus the "
       "returned point's violation of a failed one), negative exactly at the steps counted in "
       "both_infeasible_steps; NaN for MPC-DC (no Q2)"),
    # solver
    _c("solves", _INT, "", "problems solved (attempted) in the episode"),
    _c("cold_retries", _INT, "", "failed warm IPOPT starts retried cold"),
    _c("presumed_infeasible_solves", _INT, "", "fast-path-only solves of a problem IPOPT certified infeasible"),
    _c("q1_confirm_solves", _INT, "", "steps where a presumed Q1 failure met a solved Q2 while overtaking (a turn-back "
       "the fast path alone would decide): Q1 solved in full (IPM, then IPOPT) before the decision"),
    _c("q1_confirm_solved", _INT, "", "q1_confirm_solves that found a Q1 solution: the ego went on overtaking where "
       "the presumed verdict would have turned it back"),
    _c("hold_confirm_solves", _INT, "", "steps where no plan would be applied (the last plan held, or the brake) on a "
       "presumed failure of Q1 or Q2: the presumed problem solved in full (IPM, then IPOPT) first, the mode's own "
       "problem first"),
    _c("hold_confirm_solved", _INT, "", "hold_confirm_solves that found a solution: a plan was applied where the "
       "presumed verdict would have held the last one"),
    _c("infeasibility_audits", _INT, "", "C certificates of infeasibility IPOPT re-checked as the scheduled auditor "
       "(mpc.infeasibility = phase1, or phase1_mpcdc for the MPC-DC baselines; 0 otherwise)"),
    _c("infeasibility_audit_disagreements", _INT, "", "infeasibility_audits where IPOPT solved the problem (its "
       "solution was used)"),
    _c("iterations_mean", _FLOAT, "", "mean solver iterations per solve"),
    _c("iterations_max", _INT, "", "most solver iterations of one solve"),
    _c("solve_time_mean_s", _FLOAT, "s", "mean wall time per solve (machine-dependent)", wall_clock=True),
    _c("solve_time_max_s", _FLOAT, "s", "longest wall time of one solve (machine-dependent)", wall_clock=True),
    _c("solver_statuses", _STR, "", "JSON counts of solve statuses (str of SolveStatus: fallback: and "
       "presumed_infeasible:, audited: and audit_disagreed: mark the route)"),
    # failures
    _c(ERROR_COLUMN, _STR, "", "why the episode could not be simulated; null for every simulated episode"),
)

_BY_NAME: dict[str, Column] = {c.name: c for c in EPISODE_COLUMNS}

#: Column names in file order.
COLUMN_NAMES: tuple[str, ...] = tuple(_BY_NAME)
#: The columns that identify an episode (every row has them, error rows included).
IDENTITY_COLUMNS: tuple[str, ...] = tuple(c.name for c in EPISODE_COLUMNS if c.identity)
#: Columns that depend on wall-clock time; everything else is reproducible bit for bit.
TIMING_COLUMNS: tuple[str, ...] = tuple(c.name for c in EPISODE_COLUMNS if c.wall_clock)
#: Columns finite for every simulated episode; NaN or inf there means the plant state blew up.
FINITE_COLUMNS: tuple[str, ...] = tuple(c.name for c in EPISODE_COLUMNS if c.finite)
#: The boolean outcome flags, derived from ``outcome`` (False in an error row).
OUTCOME_FLAGS: tuple[str, ...] = ("overtook", "went_back", "timeout")


@dataclass(frozen=True)
class ColumnFamily:
    """Columns declared by a naming rule instead of one by one.

    pattern: how the names are written (for the docs); regex: the names it matches; unit and type:
    how each column's unit and Arrow type follow from its name and values; definition: one sentence."""

    pattern: str
    regex: re.Pattern[str]
    unit: str
    type: str
    definition: str


#: The grid values of an episode's cell (see the module docstring).
GRID_FAMILY = ColumnFamily(
    "<section>.<field>",
    re.compile(r"^[a-z][a-z0-9_]*\.[a-z][a-z0-9_]*$"),
    "the field's, from its name's suffix (_m, _s, _mps, _kmh, ...)",
    "int64, float64 (when any cell's value is a float), bool or string; a list (a range such as "
    "scenario.front_accel_range_mps2) as its JSON text",
    "the value, in the episode's cell, of a model field that the campaign's grid or axes vary between cells, "
    "named as in the campaign file (e.g. barrier.epsilon, noise.scale); an input copied from the cell's "
    "overrides, not a metric; fields equal in every cell (or set with --set) get no column",
)


def is_grid_column(name: str) -> bool:
    """Whether ``name`` belongs to :data:`GRID_FAMILY` (no declared column has a dot)."""
    return GRID_FAMILY.regex.match(name) is not None


def grid_columns(overrides: Sequence[Mapping[str, Any]]) -> dict[str, pa.DataType]:
    """The grid-value columns of a run whose cells have these ``overrides`` (one mapping
    ``"<section>.<field>" -> value`` per cell, as in the manifest): every field whose value differs
    between cells (or is set in some cells only), in the order it first appears, with the Arrow
    type of its values (see :data:`GRID_FAMILY`)."""
    keys: list[str] = []
    for o in overrides:
        keys += [k for k in o if k not in keys]
    out: dict[str, pa.DataType] = {}
    for key in keys:
        values = [o.get(key) for o in overrides]
        present = [v for v in values if v is not None]
        if len(present) == len(values) and all(v == present[0] for v in present):
            continue  # the same in every cell: not a grid value
        if not is_grid_column(key):
            raise ValueError(f"{key!r} is not a <section>.<field> name")
        out[key] = _grid_type(present)
    return out


def grid_value(value: Any, typ: pa.DataType) -> Any:
    """``value`` as a cell of a grid column of type ``typ`` (see :func:`grid_columns`)."""
    if value is None:
        return None
    if pa.types.is_string(typ):
        return value if isinstance(value, str) else json.dumps(value)
    if pa.types.is_floating(typ):
        return float(value)
    return value


def _grid_type(values: list[Any]) -> pa.DataType:
    if values and all(isinstance(v, bool) for v in values):
        return pa.bool_()
    if values and all(isinstance(v, int) and not isinstance(v, bool) for v in values):
        return pa.int64()
    if values and all(isinstance(v, int | float) and not isinstance(v, bool) for v in values):
        return pa.float64()
    return pa.string()


def column(name: str) -> Column:
    """The declared column ``name``; KeyError naming the column if it is not declared."""
    try:
        return _BY_NAME[name]
    except KeyError:
        raise KeyError(f"{name!r} is not an episode column (mcverify.schema.EPISODE_COLUMNS)") from None


def arrow_schema(names: Iterable[str] | None = None) -> pa.Schema:
    """The Arrow schema of the declared columns (all, or those in the collection ``names``), in
    file order; a name in ``names`` that is not declared raises KeyError."""
    if names is None:
        return pa.schema([pa.field(c.name, c.type) for c in EPISODE_COLUMNS])
    wanted = set(names)
    for name in wanted:
        column(name)
    return pa.schema([pa.field(c.name, c.type) for c in EPISODE_COLUMNS if c.name in wanted])


def markdown_table() -> str:
    """The metric table of docs/metrics.md: one line per column (name, type, unit, definition), file order."""
    lines = ["| column | type | unit | definition |", "|---|---|---|---|"]
    for c in EPISODE_COLUMNS:
        lines.append(f"| `{c.name}` | {c.type} | {c.unit} | {c.definition} |")
    f = GRID_FAMILY
    lines += ["", f"Grid values, after `seed`: one column `{f.pattern}` per varied field: {f.definition}. Type: "
              f"{f.type}. Unit: {f.unit}."]
    return "\n".join(lines)
