"""The controller on the host: one control step of one episode (Algorithm 1, Table I, MPC-DC).

A :class:`Planner` holds the compiled solvers of one parameter set (the TO-CBF-MPC without and
with the opposing vehicle, for the cell's controller) and turns measurements into the input to
apply. All per-episode memory (mode, warm starts, counters) lives in an :class:`EpisodeState`, so
a planner serves any number of episodes and its output depends only on that episode's history.

Controllers (``params.mpc.controller``):

* "vlcbf", the paper's dual TO-CBF-MPC: Q1 and Q2 every step (with eq.tompcAdd once veh_o is
  detected; :attr:`Mpc.q2_solve` can give the steps whose decision ignores Q2 only the fast path, or
  skip Q2 there); Algorithm 1 for no or an autonomous veh_o, Table I for a human driver
  (:mod:`mcverify.control.decision`). Going back, Q2 alone is solved; when it fails, Q1 is solved as well
  (Theorem 5 is then checked exactly) and, if Q1 has a plan, the ego follows it for that step
  instead of braking blindly (``q1_rescue_steps``, a deviation from Algorithm 1, which has no
  answer for a failed Q2). The fallback brake only when neither problem solves.
* When a failed Q1 abandons the overtake is :attr:`mcverify.model.Mpc.abandon_rule` (default: the
  first failure, Algorithm 1 read literally); while the rule waits, the ego follows its last Q1
  plan (``q1_held_steps``). Every Q1 failure is counted by kind (:func:`failure_kind`), and every
  step with neither problem solved by whether both failures are certificates (Theorem 5).
* "mpcdc", the baseline of Sec. VI-D: only the overtaking problem, with the ellipses as distance
  constraints at the nodes; no Q2 backup. "mpcdc_eps" is the same with the constraints at the
  cell's level (h >= barrier.epsilon, :func:`mcverify.ocp.layout.distance_margin`).

When no applicable problem has a solution, both controllers apply the rest of the last plan they
followed (``held_steps``; it was verified one step earlier from nearly this state), and brake in
lane once it is used up (``fallback_steps``). A failure the infeasibility memo only presumed never
decides the control: the problem is solved in full first when it would turn the ego back
(:meth:`Planner._confirm_q1`) or hold the plan (:meth:`Planner._confirm_hold`); docs/decisions.md,
"The confirmation rule" and "The hold confirmation".
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from mcverify.control.decision import Mode, Source, TableOneInput, abandon_overtake, decide, table_one
from mcverify.control.episode_state import EpisodeState, failure_kind
from mcverify.levels import Level
from mcverify.model import ModelParams
from mcverify.ocp.problem import OcpStructure
from mcverify.solver.mpc import MpcSolution, MpcSolver, WarmStart
from mcverify.solver.status import SolveRoute

Q1, Q2 = +1, -1  # the OCP's direction parameter: goal ahead of / behind the front vehicle


@dataclass(frozen=True)
class StepRecord:
    """What one control step decided (kept for recorded episodes: trajectories and figures)."""

    source: Source
    mode: Mode
    detected: bool
    q1: MpcSolution | None
    q2: MpcSolution | None
    table_row: int  # Table I row (0-5), -1 when Table I was not consulted


class Planner:
    """The compiled solvers of one parameter set and the per-step decision logic."""

    def __init__(self, params: ModelParams, kernel_dir=None, solver_factory=None) -> None:
        """solver_factory(params, structure) -> a solver with :class:`MpcSolver`'s ``solve``,
        ``guess_from_plan`` and ``kernel_hash``; default the compiled-kernel :class:`MpcSolver`
        (the benchmark's naive reference passes its own, benchmarks/naive.py)."""
        self.params = params
        make = solver_factory or (lambda p, s: MpcSolver(p, s, kernel_dir))
        self.plain = make(params, OcpStructure.from_params(params, with_opposing=False))
        self.with_opp = (
            make(params, OcpStructure.from_params(params, with_opposing=True))
            if params.opposing.kind != "none"
            else None
        )

    @property
    def kernel_hashes(self) -> dict[str, str]:
        out = {"plain": self.plain.kernel_hash}
        if self.with_opp is not None:
            out["opposing"] = self.with_opp.kernel_hash
        return out

    @property
    def kernel_hash(self) -> str:
        """The kernels this planner runs, joined (one string for the run manifest)."""
        return "+".join(self.kernel_hashes.values())

    # ---------------------------------------------------------------------------------------------
    def detects(self, ego: np.ndarray, opp_meas: np.ndarray | None) -> bool:
        """veh_o is seen (Algorithm 1's "detect veh_o"): ahead of the ego within the sensor range."""
        if opp_meas is None or self.with_opp is None:
            return False
        ahead_m = float(opp_meas[0] - ego[0])
        return 0.0 < ahead_m < self.params.opposing.detect_range_m

    def committed(self, ego: np.ndarray, front_meas: np.ndarray) -> bool:
        """The ego is in its own lane and ahead of veh_f by more than the ellipse's semi-axis a."""
        ahead_m = float(ego[0] - front_meas[0])
        return ahead_m > self.params.barrier.ellipse_a_m and ego_in_own_lane(ego, self.params)

    def converged(self, state: EpisodeState, ego: np.ndarray, front_meas: np.ndarray) -> str | None:
        """The paper's convergence test on the *measured* state (what the controller knows):
        "overtook", "went_back" or None.

        Q1's goal x_e >= x_f + phi v_f with |y_e - y_g| <= eps_y ends the episode as overtaken in
        either mode (a go-back that Q1 had to rescue can still end ahead of veh_f); Q2's goal
        x_e <= x_f - phi v_f (same lateral test) only while going back - at the start the ego is
        already there.
        """
        p = self.params
        if abs(ego[1] - p.road.ego_lane_y_m) > p.mpc.eps_y_m:
            return None
        offset = p.mpc.phi_s * front_meas[2]
        if ego[0] >= front_meas[0] + offset:
            return "overtook"
        if state.mode is Mode.GO_BACK and ego[0] <= front_meas[0] - offset:
            return "went_back"
        return None

    def step(
        self,
        state: EpisodeState,
        t_s: float,
        ego: np.ndarray,
        front_meas: np.ndarray,
        opp_meas: np.ndarray | None,
        level: Level,
    ) -> tuple[np.ndarray, StepRecord]:
        """The input (2,) [alpha m/s^2, beta rad] to apply now, and what was decided.

        ego (4,): the ego's own state; front_meas (3,) [x, y, v]: measured veh_f; opp_meas (2,)
        [x, v signed] or None: measured veh_o.
        """
        detected = self.detects(ego, opp_meas)
        state.steps += 1
        state.opp_detected_steps += int(detected)
        if self.params.mpc.is_mpcdc:
            return self._step_mpcdc(state, t_s, ego, front_meas, opp_meas if detected else None, level, detected)
        solver = self.with_opp if detected else self.plain
        opp = opp_meas if detected else None
        starts = {Q1: state.warm.get((Q1, detected)), Q2: state.warm.get((Q2, detected))}
        q1 = self._solve(state, solver, ego, front_meas, Q1, level, opp) if state.mode is Mode.OVERTAKE else None
        unread = self._q2_unread(q1, detected)
        q2 = (None if unread and self.params.mpc.q2_solve == "when_needed" else
              self._solve(state, solver, ego, front_meas, Q2, level, opp,
                          fast_path_only=unread and self.params.mpc.q2_solve == "fast_when_unneeded"))
        if self._switch_presumed(state, ego, front_meas, q1, q2):
            q1 = self._confirm_q1(state, solver, ego, front_meas, level, opp, starts[Q1])
        if q1 is None and not q2.success:
            # Going back and Q2 failed: solve Q1 too, so that "both unsolved" (Theorem 5) is counted
            # exactly and the ego can follow a feasible plan instead of braking blindly.
            q1 = self._solve(state, solver, ego, front_meas, Q1, level, opp)
        q1, q2 = self._confirm_holds(state, solver, ego, front_meas, level, opp, q1, q2, starts)
        q1_ok, q2_ok = q1 is not None and q1.success, q2 is not None and q2.success
        q1_failed = q1 is not None and not q1_ok
        if q1_failed:
            state.count_q1_failure(q1)
        state.q2_fail_steps += int(q2 is not None and not q2_ok)
        state.count_theorem_five(q1, q2)
        if state.mode is Mode.OVERTAKE:
            state.q1_failures_in_a_row = state.q1_failures_in_a_row + 1 if q1_failed else 0
        abandon = not q1_failed or state.mode is not Mode.OVERTAKE or self._abandons(state, q1, t_s)

        before, row = state.mode, -1
        if state.mode is Mode.OVERTAKE and self.committed(ego, front_meas):
            # Back in its own lane ahead of veh_f: the overtake is finished in all but the goal test,
            # and going back behind veh_f would mean stopping in front of it (the paper: "if ... veh_e
            # already cut into L_ego in front of veh_f, we will keep finishing the overtaking process").
            mode, source = Mode.OVERTAKE, (Source.Q1 if q1_ok else Source.FALLBACK)
        elif state.mode is Mode.OVERTAKE and detected and self.params.opposing.kind == "human":
            overtake, row = table_one(self._table_one_input(ego, front_meas, q1, q2))
            state.table_one_rows[row] = state.table_one_rows.get(row, 0) + 1
            if overtake:
                mode, source = Mode.OVERTAKE, Source.Q1
            elif row == 0 and q2_ok and not abandon:  # Q1 failed, the abandonment rule waits
                mode, source = Mode.OVERTAKE, Source.HELD
            elif q2_ok:
                mode, source = Mode.GO_BACK, Source.Q2
            else:  # nothing to go back with: keep the overtake's last plan (held), decide again next step
                mode, source = Mode.OVERTAKE, Source.FALLBACK
        else:
            mode, source = decide(state.mode, q1_ok, q2_ok, abandon)
            if source is Source.FALLBACK and mode is Mode.GO_BACK and q1_ok:
                source = Source.Q1  # a deviation from Algorithm 1, counted: Q1 rescues the go-back
                state.q1_rescue_steps += 1
        state.mode = mode
        if before is Mode.OVERTAKE and mode is Mode.GO_BACK:
            state.switched_to_q2_at_s = t_s
            state.went_back_reason = f"table_one_row_{row}" if row >= 0 else "q1_not_solved"
            state.went_back_q1_failure = failure_kind(q1) if q1_failed and row <= 0 else ""
        if source is Source.HELD:
            state.q1_held_steps += 1
        if source in (Source.FALLBACK, Source.HELD):
            return self._no_plan(state, t_s, ego, front_meas, StepRecord(source, mode, detected, q1, q2, row))
        state.q2_driven_steps += int(source is Source.Q2)
        applied = q1 if source is Source.Q1 else q2
        state.held = (applied.u_plan, applied.dt_plan, t_s)
        return applied.u_plan[0], StepRecord(source, mode, detected, q1, q2, row)

    def _switch_presumed(self, state: EpisodeState, ego, front_meas, q1: MpcSolution | None,
                         q2: MpcSolution | None) -> bool:
        """Would this step turn back on a presumed Q1 failure? Overtaking, not yet committed, Q1 failed
        on the fast path alone (the infeasibility memo: IPOPT was not asked) and Q2 has a plan to go
        back with: the one situation in which Algorithm 1 or Table I (row 0) may abandon the overtake
        for good on a verdict IPOPT never gave (docs/decisions.md, "The confirmation rule")."""
        return (state.mode is Mode.OVERTAKE and q1 is not None and not q1.success
                and q1.status.presumed_infeasible and q2 is not None and q2.success
                and not self.committed(ego, front_meas))

    def _confirm_q1(self, state: EpisodeState, solver, ego, front_meas, level, opp,
                    start: WarmStart | None) -> MpcSolution:
        """Q1 solved in full (:meth:`_solve_in_full`): the verdict that decides a switch."""
        sol = self._solve_in_full(state, solver, ego, front_meas, Q1, level, opp, start)
        state.q1_confirm_solves += 1
        state.q1_confirm_solved += int(sol.success)
        return sol

    def _confirm_holds(self, state: EpisodeState, solver, ego, front_meas, level, opp, q1: MpcSolution | None,
                       q2: MpcSolution | None, starts: dict) -> tuple[MpcSolution | None, MpcSolution | None]:
        """(q1, q2) after the hold confirmation: each presumed failure of :meth:`_presumed_holds` solved in full,
        in order, until one gives a plan (a held plan decides the control as a turn-back does;
        docs/decisions.md, "The hold confirmation")."""
        sols = {Q1: q1, Q2: q2}
        for direction in self._presumed_holds(state, ego, front_meas, q1, q2):
            sols[direction] = self._confirm_hold(state, solver, ego, front_meas, direction, level, opp,
                                                 starts[direction])
            if sols[direction].success:
                break
        return sols[Q1], sols[Q2]

    def _presumed_holds(self, state: EpisodeState, ego, front_meas, q1: MpcSolution | None,
                        q2: MpcSolution | None) -> list[int]:
        """The presumed failures that would make this step hold its last plan or brake: none when a plan will
        be applied; otherwise the problems (the mode's own first) that could give one and failed on the fast
        path alone."""
        committed = state.mode is Mode.OVERTAKE and self.committed(ego, front_meas)
        useful = (Q1,) if committed else ((Q2, Q1) if state.mode is Mode.GO_BACK else (Q1, Q2))
        sols = {Q1: q1, Q2: q2}
        if any(sols[d] is not None and sols[d].success for d in useful):
            return []
        return [d for d in useful if sols[d] is not None and sols[d].status.presumed_infeasible]

    def _confirm_hold(self, state: EpisodeState, solver, ego, front_meas, direction: int, level, opp,
                      start: WarmStart | None) -> MpcSolution:
        """A presumed failure that would hold the plan, solved in full (:meth:`_solve_in_full`); a solution is
        applied."""
        sol = self._solve_in_full(state, solver, ego, front_meas, direction, level, opp, start)
        state.hold_confirm_solves += 1
        state.hold_confirm_solved += int(sol.success)
        return sol

    def _solve_in_full(self, state: EpisodeState, solver, ego, front_meas, direction: int, level, opp,
                       start: WarmStart | None) -> MpcSolution:
        """A problem solved in full (the fast path, then IPOPT) whatever the memo says, from ``start``, the warm
        start its presumed solve had: a solution ends the memo, a failure is the memo's full attempt after a
        wait (its wait doubles)."""
        if start is not None:
            state.warm[(direction, opp is not None)] = start
        return self._solve(state, solver, ego, front_meas, direction, level, opp, confirm=True)

    def _q2_unread(self, q1: MpcSolution | None, detected: bool) -> bool:
        """Will this step's decision ignore Q2 (:attr:`Mpc.q2_solve`)? Overtaking with Q1 solved and no
        Table I to consult: Algorithm 1 then applies Q1 whatever Q2 says."""
        if q1 is None or not q1.success:
            return False
        return not (detected and self.params.opposing.kind == "human")

    def _abandons(self, state: EpisodeState, q1: MpcSolution, t_s: float) -> bool:
        """Does this step's failed Q1 solve (overtaking) abandon the overtake? The rule of
        :attr:`Mpc.abandon_rule`; a rule that waits still abandons when there is no Q1 plan left to
        hold (none yet, or used up)."""
        m = self.params.mpc
        if m.abandon_rule == "first_failure":
            return True
        if held_input(state.held, t_s) is None:
            return True
        return abandon_overtake(m.abandon_rule, state.q1_failures_in_a_row, failure_kind(q1), m.abandon_after_failures)

    def _no_plan(self, state: EpisodeState, t_s: float, ego: np.ndarray, front_meas: np.ndarray, record: StepRecord):
        """No problem solved this step: the rest of the last applied plan (it was verified safe one
        step ago from nearly this state), then the brake-in-lane fallback once it is used up."""
        u = held_input(state.held, t_s)
        if u is not None:
            state.held_steps += 1
            return u, dataclasses.replace(record, source=Source.HELD)
        state.fallback_steps += 1
        return fallback_input(ego, front_meas, self.params), dataclasses.replace(record, source=Source.FALLBACK)

    # ---------------------------------------------------------------------------------------------
    def _step_mpcdc(self, state, t_s, ego, front_meas, opp, level, detected):
        solver = self.with_opp if opp is not None else self.plain
        # No presumed infeasibility here: MPC-DC has no second problem, so a presumed failure would
        # itself decide the control (the held plan) - see Mpc.infeasible_recheck_steps.
        q1 = self._solve(state, solver, ego, front_meas, Q1, level, opp, presume=False)
        if q1.success:
            state.held = (q1.u_plan, q1.dt_plan, t_s)
            return q1.u_plan[0], StepRecord(Source.Q1, state.mode, detected, q1, None, -1)
        state.count_q1_failure(q1)
        record = StepRecord(Source.FALLBACK, state.mode, detected, q1, None, -1)
        return self._no_plan(state, t_s, ego, front_meas, record)

    def _solve(self, state, solver, ego, front_meas, direction, level, opp, presume: bool = True,
               fast_path_only: bool = False, confirm: bool = False) -> MpcSolution:
        """One problem, warm-started from its last solution; ``presume``: may a problem IPOPT certified
        infeasible get only the fast path for a while (the infeasibility memo)? ``fast_path_only``: an
        unread Q2 (:attr:`Mpc.q2_solve` = "fast_when_unneeded"): the fast path alone, and a failure
        teaches the memo nothing (IPOPT was not asked). ``confirm``: a full attempt whatever the memo
        says (:meth:`_confirm_q1`); a solution ends the memo."""
        key = (direction, opp is not None)
        guess = None
        if opp is not None and key not in state.warm:
            # Two-stage cold start: the plain problem (no veh_o, cheap cold and warm) gives the primal
            # guess, far better than the heuristic guess for the problem with veh_o (docs/decisions.md).
            plain = self.plain.solve(ego, front_meas, direction, level, state.warm.get((direction, False)))
            state.record_solve(plain)
            if plain.success:
                state.warm[(direction, False)] = plain.warm
            guess = solver.guess_from_plan(plain, opp)
        memo = state.infeasible.get(key) if presume else None
        presumed = memo is not None and memo[0] + 1 < memo[1] and not confirm
        extra = {"fast_only": True} if presumed or fast_path_only else {}
        sol = solver.solve(ego, front_meas, direction, level, state.warm.get(key), opp_xv=opp, guess=guess, **extra)
        unread_failure = fast_path_only and not presumed and not sol.success
        if unread_failure:
            sol = dataclasses.replace(sol, status=sol.status.via(SolveRoute.UNREAD))
        state.record_solve(sol)
        if sol.success:
            state.warm[key] = sol.warm
        else:
            state.warm.pop(key, None)  # never restart from a stale point
        if unread_failure:
            return sol  # the memo stays as it was: only a full attempt can certify or end it
        memo = self._next_memo(memo, sol, presumed) if presume and not (confirm and sol.success) else None
        if memo is None:
            state.infeasible.pop(key, None)
        else:
            state.infeasible[key] = memo
        return sol

    def _next_memo(self, memo: tuple[int, int] | None, sol: MpcSolution, fast_only: bool) -> tuple[int, int] | None:
        """The infeasibility memo of a problem after ``sol`` (see :attr:`Mpc.infeasible_recheck_steps`)."""
        m = self.params.mpc
        if sol.success:  # solved now; a failure within the wait is still presumed (noise flickers near the edge)
            return (memo[0] + 1, memo[1]) if memo is not None and memo[0] + 1 < memo[1] else None
        if fast_only:  # presumed again: the count goes on
            return (memo[0] + 1, memo[1])
        if memo is not None:  # the full attempt after a wait failed too: wait twice as long
            return (0, min(2 * memo[1], m.infeasible_recheck_max_steps))
        if sol.status.certified_infeasible:  # newly certified
            return (0, m.infeasible_recheck_steps)
        return None

    def _table_one_input(self, ego, front_meas, q1: MpcSolution, q2: MpcSolution) -> TableOneInput:
        p = self.params
        nan = math.nan
        q1_ok, q2_ok = q1 is not None and q1.success, q2.success
        t2 = q2.total_time_s if q2_ok else nan
        x_goal_q2 = front_meas[0] + front_meas[2] * t2 - p.mpc.phi_s * front_meas[2] if q2_ok else nan
        return TableOneInput(
            q1_ok=q1_ok,
            q2_ok=q2_ok,
            t1_s=q1.total_time_s if q1_ok else nan,
            t2_s=t2,
            x_e_q1_end_m=float(q1.x_plan[-1, 0]) if q1_ok else nan,
            x_o_q1_end_m=float(q1.opp_plan[-1, 0]) if q1_ok else nan,
            x_o_q2_end_m=float(q2.opp_plan[-1, 0]) if q2_ok else nan,
            x_goal_q2_m=float(x_goal_q2),
            ego_in_own_lane=ego_in_own_lane(ego, p),
        )


def ego_in_own_lane(ego: np.ndarray, p: ModelParams) -> bool:
    """The ego footprint lies entirely below the lane line (Table I's y_e in L_ego)."""
    psi = float(ego[2])
    top = ego[1] + 0.5 * p.geometry.length_m * abs(math.sin(psi)) + 0.5 * p.geometry.width_m * math.cos(psi)
    return bool(top <= 0.5 * (p.road.ego_lane_y_m + p.road.opp_lane_y_m))


def held_input(held: tuple[np.ndarray, np.ndarray, float] | None, t_s: float) -> np.ndarray | None:
    """The input of the last plan at the stage containing t_s, or None when the plan is used up."""
    if held is None:
        return None
    u_plan, dt_plan, t_solved = held
    ends = np.cumsum(dt_plan)
    k = int(np.searchsorted(ends, t_s - t_solved, side="right"))
    return u_plan[k] if k < len(u_plan) else None


def fallback_input(ego: np.ndarray, front_meas: np.ndarray, p: ModelParams) -> np.ndarray:
    """No plan at all: stay in lane - the heading steered back to the road direction, no lateral
    move - and brake fully (without reversing), unless the ego is ahead of veh_f, where braking
    would invite veh_f (which does not react) into its back: there it holds its speed.

    Why not steer back to the own lane: beside veh_f that steers into it (it did, in early
    versions, on Table IV-like runs)."""
    e = p.ego
    ahead = ego[0] > front_meas[0]
    accel = 0.0 if ahead else max(e.accel_min_mps2, -ego[3] / p.sim.control_period_s)
    beta = float(np.clip(-ego[2], -e.slip_max_rad, e.slip_max_rad))
    return np.array([accel, beta])
