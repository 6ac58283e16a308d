"""Algorithm 1 (alg.framework) and the Conditions for Overtaking (Table I, tab.cons_for_overtaking).

Pure decision logic, no solving: which problem drives the ego in this control step.

* No opposing vehicle detected, or an autonomous one: the ego follows Q1 while Q1 can be solved.
  When Q1 cannot be solved (e.g. veh_f accelerates away, thm.one_in_two_feasibility) it breaks out
  of the Q1 loop for good and follows Q2 back behind veh_f.
* A human-driven opposing vehicle: Table I decides from the two plans (:func:`table_one`).
* What counts as "Q1 cannot be solved" is :attr:`mcverify.model.Mpc.abandon_rule`
  (:func:`abandon_overtake`): the first failed solve (Algorithm 1 read literally, the default), k
  consecutive failed solves, or only a certified infeasibility. While the rule has not fired, a
  failed Q1 leaves the ego on its last Q1 plan (``Source.HELD``) instead of going back.
* Going back, the ego applies Q2 while Q2 solves. When no applicable problem has a solution the
  planner applies the rest of the last plan it followed, then brakes in its own lane
  (:mod:`mcverify.control.planner`), and the step is counted.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum


class Mode(IntEnum):
    """What the ego is doing: overtaking (the Q1 loop) or going back (the Q2 loop)."""

    OVERTAKE = 0
    GO_BACK = 1


class Source(IntEnum):
    """Where the input applied in one control step came from."""

    Q1 = 1
    Q2 = 2
    FALLBACK = 3  # no applicable problem solved, no plan left to hold: stay in lane and brake
    HELD = 4  # no applicable problem solved: the rest of the last applied plan (either controller)


#: How a failed solve failed, from the strongest evidence of infeasibility to the weakest (the
#: split of ``q1_fail_steps`` and the ``went_back_q1_failure`` column).
FAILURE_KINDS = ("certified_infeasible", "presumed_infeasible", "iteration_limit", "other")


def abandon_overtake(rule: str, failures_in_a_row: int, failure: str, k: int) -> bool:
    """Does this step's failed Q1 solve abandon the overtake (:attr:`Mpc.abandon_rule`)?

    rule: "first_failure", "consecutive" or "certified"; failures_in_a_row: failed Q1 solves in a
    row up to and including this one; failure: this solve's kind (:data:`FAILURE_KINDS`); k:
    ``Mpc.abandon_after_failures``.
    """
    if rule == "first_failure":
        return True
    if rule == "consecutive":
        return failures_in_a_row >= k
    if rule == "certified":
        return failure in ("certified_infeasible", "presumed_infeasible")
    raise ValueError(f"unknown abandon rule {rule!r}")


def decide(mode: Mode, q1_ok: bool, q2_ok: bool, abandon: bool = True) -> tuple[Mode, Source]:
    """Next mode and the source of this step's input (Algorithm 1 without a human opposing driver).

    - overtaking and Q1 solved: apply Q1;
    - overtaking, Q1 unsolvable, Q2 solved: break out of the Q1 loop (the overtake is abandoned
      for good) and apply Q2 - if ``abandon`` (the abandonment rule fired, :func:`abandon_overtake`;
      always with the default rule); else keep overtaking on the last Q1 plan (``Source.HELD``);
    - going back: apply Q2 while it solves;
    - otherwise: fall back (neither applicable problem solved).
    """
    if mode is Mode.OVERTAKE:
        if q1_ok:
            return Mode.OVERTAKE, Source.Q1
        if q2_ok:
            return (Mode.GO_BACK, Source.Q2) if abandon else (Mode.OVERTAKE, Source.HELD)
        return Mode.OVERTAKE, Source.FALLBACK
    if q2_ok:
        return Mode.GO_BACK, Source.Q2
    return Mode.GO_BACK, Source.FALLBACK


@dataclass(frozen=True)
class TableOneInput:
    """The quantities Table I compares (all from this step's plans and measurements).

    q1_ok, q2_ok: whether Q1 / Q2 were solved; t1_s, t2_s: their planned times T1, T2;
    x_e_q1_end_m: the ego's planned final x under Q1; x_o_q1_end_m, x_o_q2_end_m: the worst-case
    predicted x of veh_o at the end of Q1 / Q2; x_goal_q2_m: x_g^2, Q2's goal at T2;
    ego_in_own_lane: the ego footprint is entirely in L_ego now.
    """

    q1_ok: bool
    q2_ok: bool
    t1_s: float
    t2_s: float
    x_e_q1_end_m: float
    x_o_q1_end_m: float
    x_o_q2_end_m: float
    x_goal_q2_m: float
    ego_in_own_lane: bool


#: Table I's rows, numbered as in the paper (1-5), plus 0 for "Q1 not solved" (the text's "whenever
#: the feasibility of Q1 is being challenged, we merge back").
TABLE_ONE_ROWS = {
    0: "go back: Q1 not solved",
    1: "overtake: T1 > T2 and veh_o ends ahead of the ego under Q1",
    2: "overtake: T1 <= T2, going back at risk, but the ego is already in its own lane",
    3: "go back: T1 <= T2, going back at risk and the ego out of its own lane",
    4: "overtake: veh_o ends ahead of the ego under Q1 and beyond x_g^2 under Q2",
    5: "go back: veh_o would reach the ego's final position under Q1",
    6: "overtake: Q2 not solved, Q1 is the feasible problem (Theorem 5)",
}


def table_one(c: TableOneInput) -> tuple[bool, int]:
    """(overtake?, row) of Table I for a human-driven veh_o.

    Columns: T1 > T2; x_o,Q1^N > x_e,Q1^N (veh_o still ahead of where Q1 ends); x_o,Q2^N > x_g^2
    (going back is safe: veh_o has not reached Q2's goal when Q2 ends); y_e in L_ego. The table
    leaves blanks ("not care") and its rows 2-4 overlap; we read it with the paper's text: Q1's
    column decides first (row 5); T1 > T2 overtakes (row 1); with T1 <= T2 a safe Q2 overtakes
    (row 4), and an unsafe Q2 overtakes only if the ego already cut back into its own lane (row 2),
    else it goes back (row 3) - while Q2 still has a solution to go back with. When Q2 has none and
    Q1 has one that keeps veh_o ahead, the ego overtakes (row 6): abandoning the only feasible plan
    for an infeasible one is what the table means to avoid (a literal "unsolved Q2 = at risk = go
    back" drove the ego into the fallback brake beside veh_f, and into it).
    """
    if not c.q1_ok:
        return False, 0
    if not c.x_o_q1_end_m > c.x_e_q1_end_m:
        return False, 5
    if not c.q2_ok:
        return True, 6
    if c.t1_s > c.t2_s:
        return True, 1
    if c.x_o_q2_end_m > c.x_goal_q2_m:
        return True, 4
    if c.ego_in_own_lane:
        return True, 2
    return False, 3
