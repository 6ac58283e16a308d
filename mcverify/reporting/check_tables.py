"""The report's check tables: the end state after settling, the theorem checks (Theorem 2 and 5)
with the episodes worth replaying, and the solver statistics - from a run's summary only."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from mcverify.reporting.tables import DASH, Table, bound_name, fmt_num, fmt_rate, is_missing, method_name


def rate_note(summ: Mapping[str, Any]) -> str:
    return (f"k/n [low, high]: k episodes of n with the two-sided {summ['confidence_level']:.0%} "
            f"{method_name(summ['interval_method'])} interval; 0/n (≤ u) and n/n (≥ l): "
            f"{bound_name(summ['interval_method'])} "
            f"{summ['confidence_level']:.0%} bound when no or every episode counts.")


def value_of(c: Mapping[str, Any], name: str) -> Mapping[str, Any] | None:
    return c["values"].get(name)

def stat_text(v: Mapping[str, Any] | None, key: str, digits: int = 2) -> str:
    if not v:
        return DASH
    x = v["quantiles"].get(key) if key.startswith("q") else v.get(key)
    return fmt_num(x, digits)

def end_state_table(summ: Mapping[str, Any]) -> Table | None:
    """How the ego ends its manoeuvre per cell: |heading| and lateral speed at the goal test and after
    the settling period, the footprint past the lane line, settled and settling-unsafe rates (None
    for a run without the settling columns)."""
    cells = summ["cells"]
    if not any("conv_heading_rad" in c["values"] for c in cells):
        return None
    columns = ["cell", "converged", "heading at goal: min / max (rad)", "lateral speed at goal: min / max (m/s)",
               "past line at goal: max (m)", "heading at end: min / max (rad)", "lateral speed at end: min / max (m/s)",
               "past line while settling: max (m)", "settled in lane", "unsafe in settling"]
    rows = []
    for c in cells:
        h0, v0, h1, v1 = (value_of(c, n) for n in ("conv_heading_rad", "conv_lateral_speed_mps", "end_heading_rad",
                                                  "end_lateral_speed_mps"))
        pair = lambda v, d=2: f"{stat_text(v, 'min', d)} / {stat_text(v, 'max', d)}"  # noqa: E731
        rows.append([c["cell"], str(h0["count"]) if h0 else DASH, pair(h0), pair(v0),
                     stat_text(value_of(c, "conv_line_excess_m"), "max"), pair(h1, 3), pair(v1, 3),
                     stat_text(value_of(c, "settle_line_excess_max_m"), "max"),
                     fmt_rate(c["rates"].get("settled_in_lane")), fmt_rate(c["rates"].get("unsafe_in_settling"))])
    notes = ["At the goal test (overtook or went back) and at the end of the settling period (sim.settle_s of lane "
             "keeping, every safety check running; the outcome stays the goal test's). Past line: how far the ego "
             "footprint reached past the lane line, 0 inside. Heading and lateral speed at end cover every episode, "
             "timeouts included; the rates are over every episode that ran.", rate_note(summ)]
    return Table("end-state", "End state per cell: at the goal test and after settling", columns, rows, notes)

def limits_table(summ: Mapping[str, Any]) -> Table | None:
    """The ego's own limits on the true trajectory per cell: speed at every sub-step, the held input
    once per control period (None for a run made before they were counted)."""
    cells = summ["cells"]
    if not any("speed_limit_exceeded" in c["rates"] for c in cells):
        return None
    columns = ["cell", "over the speed limit", "largest speed excess (m/s)", "input beyond its bounds",
               "largest acceleration excess (m/s²)", "largest slip excess (rad)"]
    rows = [[c["cell"], fmt_rate(c["rates"].get("speed_limit_exceeded")),
             stat_text(value_of(c, "speed_excess_mps"), "max", 3), fmt_rate(c["rates"].get("input_limit_exceeded")),
             stat_text(value_of(c, "accel_excess_mps2"), "max", 3), stat_text(value_of(c, "slip_excess_rad"), "max", 4)]
            for c in cells]
    notes = ["The MPC bounds the ego's speed at its nodes; the plant integrates between them, so the true speed is "
             "checked at every integration sub-step, and the input held over each control period against the "
             "acceleration and slip bounds. Excess: the largest amount beyond the limit over the episode, the "
             "largest over the cell's episodes here (≤ 0: the limit held); per episode in speed_excess_mps, "
             "accel_excess_mps2 and slip_excess_rad, with the time in the *_t_s columns.", rate_note(summ)]
    return Table("limits", "Limits of the ego per cell: speed, acceleration and slip", columns, rows, notes)


def _int(d: Mapping[str, Any], key: str) -> str:
    return str(d[key]) if key in d else DASH

def _counted(counts: Mapping[str, int] | None) -> str:
    return ", ".join(f"{k} {v}" for k, v in (counts or {}).items()) or "none"

def theorem_table(summ: Mapping[str, Any]) -> Table:
    """Theorem checks per cell (2: the level set is invariant; 5: Q1 or Q2 is always feasible) and
    what drove the ego when it first left the safe set."""
    cells = summ["cells"]
    opp = any("opp_invariance_breaches" in c["theorem_checks"] for c in cells)
    held = any("held_steps" in c["theorem_checks"] for c in cells)
    split = any("both_certified_infeasible_steps" in c["theorem_checks"] for c in cells)
    cause = any("first_unsafe_cause" in c.get("counts", {}) for c in cells)
    columns = ["cell", "invariance breaches (Thm 2)"] + (["h_eo breaches"] if opp else []) + [
        "episodes with Q1 and Q2 unsolved (Thm 5)", "such steps"]
    columns += (["both certified infeasible", "budget / numerical", "longest run"] if split else [])
    columns += ["episodes with fallback", "fallback steps"]
    columns += (["episodes holding a failed plan", "held steps"] if held else [])
    columns += (["first unsafe step driven by"] if cause else [])
    rows = []
    for c in cells:
        t = c["theorem_checks"]
        row = [c["cell"], _int(t, "invariance_breaches")] + ([_int(t, "opp_invariance_breaches")] if opp else [])
        row += [_int(t, "episodes_with_both_infeasible"), _int(t, "both_infeasible_steps")]
        row += ([_int(t, "both_certified_infeasible_steps"), _int(t, "both_unsolved_uncertified_steps"),
                 _int(t, "both_infeasible_longest_run")] if split else [])
        row += [_int(t, "episodes_with_fallback"), _int(t, "fallback_steps")]
        row += ([_int(t, "episodes_with_held"), _int(t, "held_steps")] if held else [])
        row += ([_counted(c.get("counts", {}).get("first_unsafe_cause"))] if cause else [])
        rows.append(row)
    notes = ["Counts over the cell's episodes (steps: control steps). Fallback: neither problem solved, the ego "
             "brakes towards its lane."]
    if split:
        notes.append("Thm 5 steps split by evidence: both certified infeasible (IPOPT certified Q1 and Q2 "
                     "infeasible at that step: a counter-example up to local infeasibility) or budget / numerical "
                     "(an iteration limit, a numerical failure or a presumed infeasibility: no proof); longest run: "
                     "the most consecutive such steps in one episode. Every such episode is listed in "
                     "\"Theorem 5 findings\".")
    if cause:
        notes.append("First unsafe step driven by: the plan source in the control period where the ego first left "
                     "the safe set (planned: a solved plan; held: a failed problem's old plan; fallback: no plan).")
    return Table("theorem-checks", "Theorem checks per cell", columns, rows, notes,
                 align="l" + "r" * (len(columns) - 2) + ("l" if cause else "r"))

def findings_table(summ: Mapping[str, Any], run_dir: str = "RUN_DIR") -> Table | None:
    """Every episode with a step where neither Q1 nor Q2 solved (Theorem 5 says there is none), with
    the command that re-simulates it (``run_dir`` as given); None when the run has no such episode."""
    rows = []
    for c in summ["cells"]:
        for f in c.get("theorem_findings", []):
            eid = f.get("episode_id")
            rows.append([c["cell"], _int(f, "episode_id"), _int(f, "both_infeasible_steps"),
                         _int(f, "both_certified_infeasible_steps"), _int(f, "both_unsolved_uncertified_steps"),
                         _int(f, "both_infeasible_longest_run"),
                         f"mcverify replay {run_dir} {eid}" if eid is not None else DASH])
    if not rows:
        return None
    columns = ["cell", "episode", "steps with Q1 and Q2 unsolved", "both certified infeasible", "budget / numerical",
               "longest run", "replay"]
    notes = ["Each episode with a control step where neither Q1 nor Q2 solved. Both certified infeasible: IPOPT "
             "certified both problems infeasible at that step (a counter-example to Theorem 5 up to local "
             "infeasibility: inspect it); budget / numerical: an iteration limit, a numerical failure or a "
             "presumed infeasibility (no proof). Replay: re-simulates the episode bit for bit and writes its "
             "trajectory."]
    return Table("theorem-findings", "Theorem 5 findings: episodes with Q1 and Q2 unsolved", columns, rows, notes,
                 align="llrrrrl")

def solver_table(summ: Mapping[str, Any]) -> Table:
    """Decisions (Algorithm 1) and the solver per cell."""
    cells = summ["cells"]
    reasons = any("went_back_reason" in c.get("counts", {}) for c in cells)
    table_one = any(c.get("counts", {}).get("table_one_rows") for c in cells)
    columns = ["cell", "Q1 failed steps", "Q2 failed steps", "Q2-driven steps", "Q1 rescue steps", "solves",
               "cold retries", "mean / max iters", "mean / max solve time (ms)", "IPOPT statuses other than success"]
    columns += (["went back because"] if reasons else []) + (["Table I rows met (steps)"] if table_one else [])
    split = any("q1_fail_certified_steps" in c["theorem_checks"] for c in cells)
    abandoned_on = any(c.get("counts", {}).get("went_back_q1_failure") for c in cells)
    columns += (["Q1 failures: certified / presumed / iteration limit / other", "Q1 held (rule waited)"]
                if split else []) + (["abandoned on a Q1 failure of kind"] if abandoned_on else [])
    rows = []
    for c in cells:
        t, s, counts = c["theorem_checks"], c["solver"], c.get("counts", {})
        statuses = {k: v for k, v in s.get("statuses", {}).items() if k != "Solve_Succeeded"}
        row = [c["cell"], _int(t, "q1_fail_steps"), _int(t, "q2_fail_steps"), _int(t, "q2_driven_steps"),
               _int(t, "q1_rescue_steps"), _int(s, "solves"), _int(s, "cold_retries"),
               f"{fmt_num(s.get('iterations_mean'), 1)} / {s.get('iterations_max', DASH)}",
               f"{_ms(s.get('solve_time_mean_s'))} / {_ms(s.get('solve_time_max_s'))}", _counted(statuses)]
        row += ([_counted(counts.get("went_back_reason"))] if reasons else [])
        rows_met = {f"row {k}:": v for k, v in counts.get("table_one_rows", {}).items()}
        row += ([_counted(rows_met)] if table_one else [])
        if split:
            kinds = ("q1_fail_certified_steps", "q1_fail_presumed_steps", "q1_fail_iteration_limit_steps",
                     "q1_fail_other_steps")
            row += [" / ".join(_int(t, k) for k in kinds), _int(t, "q1_held_steps")]
        row += ([_counted(counts.get("went_back_q1_failure"))] if abandoned_on else [])
        rows.append(row)
    notes = ["Solve times are the only machine-dependent numbers of the report (they come from the stored "
             "episodes, so regenerating the report does not change them)."]
    if split:
        notes.append("Q1 failures by kind: certified infeasible (by IPOPT; for the MPC-DC baselines by default by "
                     "the C phase 1 from every start, mpc.infeasibility) / presumed infeasible (fast path only, "
                     "after a certificate) / out of iterations / other (numerical). Q1 held: overtaking steps where "
                     "Q1 failed, Q2 solved and the abandonment rule (mpc.abandon_rule) had not fired, so the ego kept "
                     "its last Q1 plan.")
    return Table("solver", "Decisions and solver per cell", columns, rows, notes,
                 align="l" + "r" * 8 + "l" * (len(columns) - 9))

def _ms(x: Any) -> str:
    return DASH if is_missing(x) else fmt_num(1e3 * float(x), 1)
