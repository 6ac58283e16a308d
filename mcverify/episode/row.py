"""One row of ``episodes.parquet``: the metrics of a finished episode, or the row of one that failed.

The columns, their types and units are declared in :mod:`mcverify.schema`; the functions here fill
them. A simulated episode's row has every declared column but ``error_message`` (the store adds it
as null); an error row has the identity columns, the outcome flags, the cell's level and the
message, and nulls elsewhere (never counted as safe or unsafe).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from mcverify.schema import ERROR_COLUMN, ERROR_OUTCOME, IDENTITY_COLUMNS

if TYPE_CHECKING:  # types only: this module is imported by the executors, which must stay light
    from mcverify.cell import Cell
    from mcverify.control.episode_state import EpisodeState
    from mcverify.sim.plant import SafetyTrace

Row = dict[str, Any]


def identity(cell: Cell, seed: int, cell_episode: int) -> Row:
    """The :data:`~mcverify.schema.IDENTITY_COLUMNS` of episode ``cell_episode`` of ``cell``."""
    values = (cell.episode_offset + cell_episode, cell_episode, cell.name, cell.index, seed)
    return dict(zip(IDENTITY_COLUMNS, values, strict=True))


def error_row(cell: Cell, seed: int, cell_episode: int, message: str) -> Row:
    """The row of an episode that could not be simulated: identification, the cell's level, the
    message; outcome flags False, metrics null (unknown, never counted as safe or unsafe)."""
    return {
        **identity(cell, seed, cell_episode),
        "outcome": ERROR_OUTCOME,
        "overtook": False,
        "went_back": False,
        "timeout": False,
        "epsilon": cell.epsilon,
        "lambda0": cell.lambda0,
        ERROR_COLUMN: message,
    }


@dataclass(frozen=True)
class EndState:
    """How the ego ended its episode (the settling columns of :mod:`mcverify.schema`), filled by the
    rollout: at the goal test (``conv_*``, NaN for a timeout) and when the simulation stopped
    (``end_*`` at ``settle_end_s``); ``line_excess_max_m``: the footprint's largest reach past the lane
    line over the settling period (NaN for a timeout); ``in_lane``: the footprint inside the ego lane
    at ``settle_end_s``; ``stopped``: the episode was ended at its first violation of ``sim.stop_at``."""

    settle_end_s: float
    end_heading_rad: float
    end_lateral_speed_mps: float
    end_line_excess_m: float
    in_lane: bool
    conv_heading_rad: float = math.nan
    conv_lateral_speed_mps: float = math.nan
    conv_line_excess_m: float = math.nan
    line_excess_max_m: float = math.nan
    stopped: bool = False  # ended at its first violation of sim.stop_at (falsify mode)


def _settling(st: EpisodeState, end: EndState) -> Row:
    converged = st.outcome in ("overtook", "went_back")
    return {
        "settle_end_s": end.settle_end_s,
        "conv_heading_rad": end.conv_heading_rad,
        "conv_lateral_speed_mps": end.conv_lateral_speed_mps,
        "conv_line_excess_m": end.conv_line_excess_m,
        "end_heading_rad": end.end_heading_rad,
        "end_lateral_speed_mps": end.end_lateral_speed_mps,
        "end_line_excess_m": end.end_line_excess_m,
        "settle_line_excess_max_m": end.line_excess_max_m,
        "settled_in_lane": bool(converged and end.in_lane),
        "unsafe_in_settling": bool(converged and st.first_unsafe_s >= st.end_time_s),
        "stopped_at_violation": end.stopped,
    }


def _finite_or_nan(x: float) -> float:
    return float(x) if math.isfinite(x) else math.nan


def episode_row(
    cell: Cell, seed: int, st: EpisodeState, sample: dict[str, float], tr: SafetyTrace, h0: float, end: EndState
) -> Row:
    """The metrics of one finished episode, in the order of :data:`mcverify.schema.EPISODE_COLUMNS`.

    st: the episode's host-side state; sample: the scenario values drawn for it (column
    ``sample_<name>``); tr: its safety trace (one lane of :class:`~mcverify.sim.plant.SafetyTrace`);
    h0: h_ef at the start; end: how the ego ended (the settling columns).
    """
    p = cell.params
    eps = cell.epsilon
    min_h = float(tr.min_h_front)
    first, last = float(tr.first_opp_lane_s), float(tr.last_opp_lane_s)
    collision_front, collision_opp = bool(tr.collision_front), bool(tr.collision_opp)
    iters = np.array(st.iterations or [0])
    times = np.array(st.solve_times_s or [0.0])
    has_opp = p.opposing.kind != "none"
    min_h_opp = _finite_or_nan(float(tr.min_h_opp))
    return {
        **identity(cell, seed, st.episode_id),
        "controller": p.mpc.controller,
        "opposing_kind": p.opposing.kind,
        **{f"sample_{k}": v for k, v in sample.items()},
        "outcome": st.outcome,
        "overtook": st.outcome == "overtook",
        "went_back": st.outcome == "went_back",
        "timeout": st.outcome == "timeout",
        "end_time_s": st.end_time_s,
        "overtake_time_s": st.overtake_time_s,
        "lane_borrow_time_s": (last - first) if math.isfinite(first) else math.nan,
        "collision_front": collision_front,
        "collision_opp": collision_opp,
        "min_h_front": min_h,
        "min_dist_front_m": float(tr.min_dist_front_m),
        "min_gap_front_m": float(tr.min_gap_front_m),
        "min_gap_opp_m": _finite_or_nan(float(tr.min_gap_opp_m)) if has_opp else math.nan,
        "min_gap_opp_any_m": _finite_or_nan(float(tr.min_gap_opp_any_m)) if has_opp else math.nan,
        "min_h_opp": min_h_opp if has_opp else math.nan,
        "speed_excess_mps": float(tr.speed_excess_mps),
        "speed_excess_t_s": _finite_or_nan(float(tr.speed_excess_t_s)),
        "accel_excess_mps2": _finite_or_nan(float(tr.accel_excess_mps2)),
        "accel_excess_t_s": _finite_or_nan(float(tr.accel_excess_t_s)),
        "slip_excess_rad": _finite_or_nan(float(tr.slip_excess_rad)),
        "slip_excess_t_s": _finite_or_nan(float(tr.slip_excess_t_s)),
        "ellipse_violation": min_h < 0.0,
        "safe": (not collision_front) and (not collision_opp) and min_h >= 0.0,
        "first_unsafe_s": st.first_unsafe_s,
        "first_unsafe_cause": st.first_unsafe_cause,
        "h0_front": h0,
        "epsilon": eps,
        "lambda0": cell.lambda0,
        "invariance_breach": bool(h0 >= eps and min_h < eps),
        "invariance_margin": min_h - eps,
        "opp_invariance_breach": bool(has_opp and math.isfinite(min_h_opp) and min_h_opp < p.barrier.opp_epsilon_m),
        "opp_spawn_s": st.opp_spawn_s if has_opp else math.nan,
        **_settling(st, end),
        "steps": st.steps,
        "opp_detected_steps": st.opp_detected_steps,
        "q1_fail_steps": st.q1_fail_steps,
        "q2_fail_steps": st.q2_fail_steps,
        "both_infeasible_steps": st.both_infeasible_steps,
        "fallback_steps": st.fallback_steps,
        "held_steps": st.held_steps,
        "q2_driven_steps": st.q2_driven_steps,
        "q1_rescue_steps": st.q1_rescue_steps,
        "switched_to_q2_at_s": st.switched_to_q2_at_s,
        "went_back_reason": st.went_back_reason,
        "table_one_rows": json.dumps({str(k): v for k, v in sorted(st.table_one_rows.items())}),
        "q1_fail_certified_steps": st.q1_fail_certified_steps,
        "q1_fail_presumed_steps": st.q1_fail_presumed_steps,
        "q1_fail_iteration_limit_steps": st.q1_fail_iteration_limit_steps,
        "q1_fail_other_steps": st.q1_fail_other_steps,
        "q1_held_steps": st.q1_held_steps,
        "went_back_q1_failure": st.went_back_q1_failure,
        "both_certified_infeasible_steps": st.both_certified_infeasible_steps,
        "both_unsolved_uncertified_steps": st.both_unsolved_uncertified_steps,
        "both_infeasible_longest_run": st.both_infeasible_longest_run,
        "both_infeasible_longest_run_first_step": st.both_infeasible_longest_run_first_step,
        "theorem5_margin": st.theorem5_margin,
        "solves": len(st.iterations),
        "cold_retries": st.cold_retries,
        "presumed_infeasible_solves": st.presumed_infeasible_solves,
        "q1_confirm_solves": st.q1_confirm_solves,
        "q1_confirm_solved": st.q1_confirm_solved,
        "hold_confirm_solves": st.hold_confirm_solves,
        "hold_confirm_solved": st.hold_confirm_solved,
        "infeasibility_audits": st.infeasibility_audits,
        "infeasibility_audit_disagreements": st.infeasibility_audit_disagreements,
        "iterations_mean": float(iters.mean()),
        "iterations_max": int(iters.max()),
        "solve_time_mean_s": float(times.mean()),
        "solve_time_max_s": float(times.max()),
        "solver_statuses": json.dumps(dict(sorted(st.statuses.items()))),
    }
