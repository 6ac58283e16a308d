"""Closed-loop rollout of a chunk of disturbed episodes: the plant in JAX, the controller on the host.

One control step of the chunk:

1. ``observe`` (:mod:`mcverify.sim.plant`, JAX, vmapped): every episode's planner measures veh_f and
   veh_o with perception noise drawn from keys that depend only on (episode key, step);
2. the host runs each active episode's controller (:class:`mcverify.control.planner.Planner`: Q1/Q2 with
   the cached CasADi kernels, Algorithm 1, Table I, MPC-DC);
3. ``advance`` (JAX, vmapped, ``lax.scan`` over sub-steps): the plant runs under zero-order hold
   and every safety check is evaluated at every sub-step.

Settling: once the planner's goal test fires, the episode's outcome and time are decided, but the
plant keeps running for ``sim.settle_s`` (at most until ``sim.max_time_s``) with the input of the
lane-keeping law (:mod:`mcverify.control.lane_keeping`, no MPC) instead of the planner's, every
check included, so the safety columns cover how the ego ends its manoeuvre; the end state (heading,
lateral speed, footprint past the lane line) is kept at the goal test and when settling ends.

Episodes that finish (settling included) are frozen while the rest go on. Every result is a pure function of (campaign
cell, seed, episode id): not of the chunk, its size or the other episodes in it (the plant runs in
fixed-width lane groups, see :mod:`mcverify.sim.plant`), which ``mcverify replay`` checks bit for bit.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from mcverify.cell import Cell
from mcverify.control import lane_keeping
from mcverify.control.decision import Source
from mcverify.control.episode_state import EpisodeState
from mcverify.control.planner import Planner, StepRecord
from mcverify.episode import stop
from mcverify.episode.draws import SCENARIO_STREAM, episode_key, noise_branches, sample_scenario, truncated_normal
from mcverify.episode.recorder import Recorder
from mcverify.episode.recording import EpisodeRecording
from mcverify.episode.row import EndState, Row, episode_row
from mcverify.episode.snapshot import Branching, branch_key
from mcverify.sim.lanes import LaneGroups
from mcverify.sim.plant import SafetyTrace, footprint_top_y_m, initial_plant
from mcverify.sim.schedule import ErrorInput, ErrorSchedule
from mcverify.sim.tilt import NoiseTilt

__all__ = ["SCENARIO_STREAM", "SETTLING_CAUSE", "UNSAFE_CAUSES", "ChunkResult", "PhaseClock",
           "episode_key", "noise_branches", "run_episodes", "sample_scenario", "truncated_normal"]

Array = jax.Array



# --------------------------------------------------------------------------------------- phases


class PhaseClock:
    """CPU seconds (``time.process_time``: every thread of the process) spent per phase of the loop.

    The phases of :func:`run_episodes` are sequential (the host waits for the JAX results it reads),
    so process time split at their boundaries attributes XLA's worker threads to the JAX phases.
    ``cpu_s``: phase name -> seconds; ``calls``: phase name -> number of times it ran.
    """

    def __init__(self) -> None:
        self.cpu_s: dict[str, float] = {}
        self.calls: dict[str, int] = {}

    @contextmanager
    def phase(self, name: str) -> Iterator[None]:
        t0 = time.process_time()
        try:
            yield
        finally:
            self.cpu_s[name] = self.cpu_s.get(name, 0.0) + time.process_time() - t0
            self.calls[name] = self.calls.get(name, 0) + 1


@contextmanager
def _untimed(name: str) -> Iterator[None]:
    yield


def _spawn_opposing(world: LaneGroups, states: list[EpisodeState], samples: list[dict[str, float]],
                    entered_s: list[float], ego: np.ndarray, t_s: float, p) -> None:
    """The spawn rule ``opposing.spawn = "lane_entry"``: veh_o appears ``opp_spawn_gap_m`` ahead of
    the ego ``opp_spawn_delay_s`` (the episode's draws) after the first control step at which the
    ego's footprint is over the lane line (``entered_s``: that step's time per episode, NaN until
    then; updated here)."""
    over = footprint_top_y_m(ego, p) > 0.5 * p.road.lane_width_m
    for b, st in enumerate(states):
        if st.done or not math.isnan(st.opp_spawn_s):
            continue
        if over[b] and math.isnan(entered_s[b]):
            entered_s[b] = t_s
        if not math.isnan(entered_s[b]) and t_s >= entered_s[b] + samples[b]["opp_spawn_delay_s"] - 1e-9:
            st.opp_spawn_s = t_s
            world.place_opposing(b, float(ego[b, 0]) + samples[b]["opp_spawn_gap_m"], -samples[b]["opp_speed_mps"])


# ------------------------------------------------------------------------------ host loop


@dataclass
class ChunkResult:
    """Rows (one per episode, :mod:`mcverify.episode.row`) and the recordings of the recorded
    episodes, by cell-local episode id; under error schedules, ``realised``: each episode's error as the
    time schedule it applied (:meth:`mcverify.sim.lanes.LaneGroups.realised`), by cell-local episode id."""

    rows: list[Row]
    recordings: dict[int, EpisodeRecording] = field(default_factory=dict)
    realised: dict[int, ErrorSchedule] = field(default_factory=dict)


def run_episodes(
    cell: Cell,
    episode_ids: Sequence[int],
    seed: int,
    planner: Planner,
    *,
    common_random_numbers: bool = False,
    record: bool | Sequence[int] = False,
    on_step: Callable[[int], None] | None = None,
    clock: PhaseClock | None = None,
    branching: Branching | None = None,
    scenarios: Mapping[int, Mapping[str, float]] | None = None,
    on_episode: Callable[[int, bool], None] | None = None,
    noise_tilt: NoiseTilt | None = None,
    schedules: Sequence[ErrorInput] | None = None,
) -> ChunkResult:
    """Simulate ``episode_ids`` (ids within the cell) of ``cell`` as one batch; one row per episode.

    record: True for every episode, or the ids of the episodes whose full-resolution trajectory,
    step decisions and plan snapshots are returned as well.
    clock: where to add the CPU time of the loop's phases ("plant": JAX observe and advance with
    their host-device transfers; "planner": the host controllers, solver included), for ``bench``.
    branching: for one episode only: start from a snapshot (with a branch's noise), take snapshots,
    report the running score (:mod:`mcverify.episode.snapshot`); None leaves the loop as it is.
    scenarios: episode id -> scenario values (keys of :func:`sample_scenario`) that replace the
    episode's own draws (importance sampling over the scenario); the noise is unchanged.
    on_episode: called as ``on_episode(episode id, unsafe)`` as soon as an episode stops (settling
    included), before the chunk ends; ``unsafe`` is what its row's ``safe`` will say, negated
    (progress bars; it changes nothing in the loop).
    noise_tilt: draw veh_f's y noise near veh_f from this proposal (importance sampling,
    :class:`~mcverify.sim.tilt.NoiseTilt`); each row then carries ``noise_log_lr``, the log likelihood
    ratio (nominal over proposal) of its noise, and ``noise_tilt_sums`` (9) / ``noise_tilt_counts`` (3),
    the statistics a cross-entropy refit of the tilt needs. None: the nominal noise, and no such keys.
    schedules: one error input per episode, in the order of ``episode_ids``
    (:class:`~mcverify.sim.schedule.ErrorSchedule` or :class:`~mcverify.sim.schedule.GapBandSchedule`): the
    measurement errors come from them alone (no draw; the structured disturbances and the noise branches'
    keys are not used), and the result's ``realised`` holds what each applied. Refused with ``noise_tilt``.
    None: the drawn noise, bit for bit as without this argument. The scenario draws are unchanged.
    """
    phase = clock.phase if clock is not None else _untimed
    ch = _start(cell, [int(e) for e in episode_ids], seed, common_random_numbers, scenarios, noise_tilt, schedules)
    p, ids, world, states, settling = cell.params, ch.ids, ch.world, ch.states, ch.settling
    recorded = set(ids) if record is True else set(record or ())
    rec = Recorder([b for b, e in enumerate(ids) if e in recorded], cell) if recorded else None
    n_steps = int(math.ceil(p.sim.max_time_s / p.sim.control_period_s - 1e-9))
    first_step = _restore(ch, branching)
    switches = noise_branches(p)
    if switches and branching is not None and branching.start is not None:
        raise ValueError("a snapshot branch of an episode with scheduled noise branches (noise.branch_after_steps)")

    for step in range(first_step, n_steps):
        t_s = step * p.sim.control_period_s
        if step - 1 in switches:  # the noise of the steps to come: a branch of each episode's root key
            for b in range(len(ids)):
                world.set_lane_key(b, branch_key(np.asarray(ch.keys[b]), switches[step - 1]))
        with phase("plant"):
            ego = world.ego()
            if p.opposing.appears_at_lane_entry:
                _spawn_opposing(world, states, ch.samples, ch.entered_s, ego, t_s, p)
            live = None if noise_tilt is None else ch.active()
            front_meas, opp_meas = world.observe(step, live)
        with phase("planner"):
            u, records = _plan(ch, planner, step, t_s, ego, front_meas, opp_meas)
        active = ch.active()
        if on_episode is not None:
            _report_stopped(on_episode, ids, active, ch.reported, world)
        if not active.any():
            break
        ch.u_last[active] = u[active]
        with phase("plant"):
            subs = world.advance(u, active)
            trace = world.trace()
            if settling:
                sub_ego = np.concatenate([np.asarray(s.ego) for s in subs])
                for b, settle in settling.items():
                    settle.note(sub_ego[b], p)
        _note_first_unsafe(states, trace, records, t_s, settling)
        if rec is not None:
            rec.add(t_s, world.substeps_of(subs), u, records, front_meas, opp_meas, active)
        t_next = (step + 1) * p.sim.control_period_s
        if p.sim.stop_at:
            hit = stop.violated(p.sim.stop_at, trace, states, ch.h0, cell.epsilon, ch.has_opp) & active
            _stop(hit, states, settling, ch.ends, world, ch.u_last, t_next, p)
        if on_step is not None:
            on_step(step)
        if branching is not None:
            branching.after_step(step, world, ch.keys[0], states[0], ch.entered_s[0], ch.u_last[0], settling.get(0),
                                 ch.ends.get(0))
            if branching.stopped:  # splitting: the score reached the failure level (absorbing)
                _stop(active, states, settling, ch.ends, world, ch.u_last, t_next, p)
    _time_out(ch, n_steps * p.sim.control_period_s)
    if on_episode is not None:
        _report_stopped(on_episode, ids, np.zeros(len(ids), dtype=bool), ch.reported, world)
    rows = _rows(ch, seed, noise_tilt)
    realised = {} if schedules is None else {e: world.realised(b) for b, e in enumerate(ids)}
    return ChunkResult(rows, {} if rec is None else rec.recordings(ids), realised)


@dataclass
class _Chunk:
    """The host-side state of a chunk's episodes (lane b is episode ``ids[b]``) during the loop."""

    cell: Cell
    ids: list[int]
    keys: Array  # (episodes, 2) root keys
    samples: list[dict[str, float]]  # the scenario draws
    world: LaneGroups
    h0: np.ndarray  # h_ef at the start
    states: list[EpisodeState]
    entered_s: list[float]  # when each ego first had its footprint over the lane line (NaN until then)
    u_last: np.ndarray  # (episodes, 2) the input each episode had applied last (lateral speed)
    settle_steps: int
    has_opp: bool
    settling: dict[int, _Settling] = field(default_factory=dict)  # lane -> its settling memory, while it settles
    ends: dict[int, EndState] = field(default_factory=dict)
    reported: set[int] = field(default_factory=set)  # lanes whose stop on_episode has been told

    def active(self) -> np.ndarray:
        """(episodes,) bool: still running (settling included)."""
        return np.array([not st.done or b in self.settling for b, st in enumerate(self.states)])


def _start(cell: Cell, ids: list[int], seed: int, common_random_numbers: bool,
           scenarios: Mapping[int, Mapping[str, float]] | None, noise_tilt: NoiseTilt | None,
           schedules: Sequence[ErrorInput] | None = None) -> _Chunk:
    """The chunk at t = 0: keys, scenario draws (``scenarios`` replacing an episode's own), the plant."""
    p = cell.params
    cell_key = None if common_random_numbers else cell.index
    keys = jnp.stack([episode_key(seed, cell_key, e, p.noise.key_seed) for e in ids])
    samples = [sample_scenario(k, p) for k in keys]
    for b, e in enumerate(ids):
        samples[b].update((scenarios or {}).get(e, {}))
    plant = initial_plant(p, [s["front_accel_mps2"] for s in samples], [s["opp_speed_mps"] for s in samples],
                          [s["front_accel_onset_s"] for s in samples], [s["front_accel_duration_s"] for s in samples])
    world = LaneGroups(plant, keys, p, tilt=noise_tilt,
                       schedules=None if schedules is None else list(schedules))
    h0 = world.trace().min_h_front.copy()
    states = [EpisodeState(e) for e in ids]
    if p.opposing.kind != "none" and not p.opposing.appears_at_lane_entry:
        for st in states:
            st.opp_spawn_s = 0.0
    return _Chunk(cell, ids, keys, samples, world, h0, states, [math.nan] * len(ids), np.zeros((len(ids), 2)),
                  settle_steps=int(math.ceil(p.sim.settle_s / p.sim.control_period_s - 1e-9)),
                  has_opp=p.opposing.kind != "none")


def _restore(ch: _Chunk, branching: Branching | None) -> int:
    """Start a branching episode from its snapshot, if any; the first control step to simulate."""
    if branching is None:
        return 0
    if len(ch.ids) != 1:
        raise ValueError(f"branching runs one episode at a time, got {len(ch.ids)}")
    if branching.start is not None:
        if branching.start.episode_id != ch.ids[0]:
            raise ValueError(f"snapshot of episode {branching.start.episode_id} given for episode {ch.ids[0]}")
        ch.states[0], ch.entered_s[0], ch.u_last[0], settle, end = branching.restore(ch.world)
        ch.settling.update({0: settle} if settle is not None else {})
        ch.ends.update({0: end} if end is not None else {})
    return branching.first_step()


def _plan(ch: _Chunk, planner: Planner, step: int, t_s: float, ego: np.ndarray, front_meas: np.ndarray,
          opp_meas: np.ndarray) -> tuple[np.ndarray, dict[int, StepRecord]]:
    """Every running episode's input for this control period: the planner's, or the lane-keeping law's
    while settling after the goal test (which this step may fire); the planner's step records."""
    p, settling, ends, u_last = ch.cell.params, ch.settling, ch.ends, ch.u_last
    u = np.zeros((len(ch.ids), 2))
    records: dict[int, StepRecord] = {}
    for b, st in enumerate(ch.states):
        if b in settling:
            if step >= settling[b].until_step:
                ends[b] = settling.pop(b).end(t_s, ego[b], u_last[b], p)
            else:
                u[b] = settling[b].input(ego[b], front_meas[b], p)
            continue
        if st.done:
            continue
        outcome = planner.converged(st, ego[b], front_meas[b])
        if outcome is not None:
            _finish(st, t_s, outcome)
            settle = _Settling.start(step + ch.settle_steps, ego[b], u_last[b], p)
            if ch.settle_steps == 0:
                ends[b] = settle.end(t_s, ego[b], u_last[b], p)
            else:
                settling[b] = settle
                u[b] = settle.input(ego[b], front_meas[b], p)
            continue
        u[b], records[b] = planner.step(st, t_s, ego[b], front_meas[b], opp_meas[b] if ch.has_opp else None,
                                        ch.cell.level)
    return u, records


def _time_out(ch: _Chunk, t_end: float) -> None:
    """End at the time limit: a running episode as a timeout, a settling one with its settling cut."""
    p = ch.cell.params
    ego = ch.world.ego()
    for b, st in enumerate(ch.states):
        if not st.done:
            st.done, st.outcome, st.end_time_s = True, "timeout", t_end
            ch.ends[b] = _end_state(t_end, ego[b], ch.u_last[b], p)
        elif b in ch.settling:  # cut by the time limit
            ch.ends[b] = ch.settling.pop(b).end(t_end, ego[b], ch.u_last[b], p)


def _rows(ch: _Chunk, seed: int, noise_tilt: NoiseTilt | None) -> list[Row]:
    """One row per episode, with its noise tilt's likelihood ratio and statistics under a tilt."""
    trace = ch.world.trace()
    rows = [
        episode_row(ch.cell, seed, st, ch.samples[b], SafetyTrace(*(np.asarray(a)[b] for a in trace)),
                    float(ch.h0[b]), ch.ends[b])
        for b, st in enumerate(ch.states)
    ]
    if noise_tilt is not None:
        sums, counts = ch.world.tilt_statistics()
        log_lr = ch.world.noise_log_lr()
        for b, row in enumerate(rows):
            row["noise_log_lr"] = float(log_lr[b])
            row["noise_tilt_sums"] = [float(v) for v in sums[b]]
            row["noise_tilt_counts"] = [float(v) for v in counts[b]]
    return rows


#: What drove the ego in the control period where it first left the safe set (``first_unsafe_cause``):
#: "planned" - a solved Q1/Q2 (or MPC-DC) plan, so the plan itself or the noise let it in (for MPC-DC:
#: the ellipse held only at its nodes); "held" - no applicable problem solved, the rest of the last
#: applied plan; "fallback" - no plan at all.
UNSAFE_CAUSES = {Source.Q1: "planned", Source.Q2: "planned", Source.HELD: "held", Source.FALLBACK: "fallback"}
#: ``first_unsafe_cause`` of an ego that left the safe set while settling (after the goal test).
SETTLING_CAUSE = "lane_keeping"


def _note_first_unsafe(states: list[EpisodeState], trace: SafetyTrace, records: dict[int, StepRecord], t_s: float,
                       settling=()):
    unsafe = (np.asarray(trace.min_h_front) < 0) | np.asarray(trace.collision_front) | np.asarray(trace.collision_opp)
    for b, st in enumerate(states):
        if unsafe[b] and not st.first_unsafe_cause and (b in records or b in settling):
            st.first_unsafe_s = t_s
            st.first_unsafe_cause = UNSAFE_CAUSES[records[b].source] if b in records else SETTLING_CAUSE


def _report_stopped(on_episode: Callable[[int, bool], None], ids: Sequence[int], active: np.ndarray,
                    reported: set[int], world: LaneGroups) -> None:
    """Tell ``on_episode`` about each lane that stopped since the last call (its trace is final)."""
    stopped = [b for b in range(len(ids)) if not active[b] and b not in reported]
    if not stopped:
        return
    tr = world.trace()
    unsafe = (np.asarray(tr.min_h_front) < 0) | np.asarray(tr.collision_front) | np.asarray(tr.collision_opp)
    for b in stopped:
        reported.add(b)
        on_episode(ids[b], bool(unsafe[b]))


def _stop(hit: np.ndarray, states: list[EpisodeState], settling: dict[int, _Settling], ends: dict[int, EndState],
          world: LaneGroups, u_last: np.ndarray, t_s: float, p) -> None:
    """End the episodes of the mask ``hit`` (shape (episodes,), active ones only) at ``t_s``, the end of
    the control period just simulated, where their recorded trajectories end too: falsify mode's
    first violation of ``sim.stop_at``, or a splitting branch whose score reached its level."""
    if not hit.any():
        return
    ego = world.ego()
    for b in (int(i) for i in np.flatnonzero(hit)):
        st = states[b]
        if b in settling:  # the goal was reached: the outcome stays, the settling is cut
            end = settling.pop(b).end(t_s, ego[b], u_last[b], p)
        else:
            st.done, st.outcome, st.end_time_s = True, stop.STOPPED_OUTCOME, t_s
            end = _end_state(t_s, ego[b], u_last[b], p)
        ends[b] = dataclasses.replace(end, stopped=True)


def _finish(st: EpisodeState, t_s: float, outcome: str) -> None:
    st.done, st.end_time_s, st.outcome = True, t_s, outcome
    if outcome == "overtook":
        st.overtake_time_s = t_s


def _end_state(t_s: float, ego: np.ndarray, u: np.ndarray, p, **conv: float) -> EndState:
    """The ego's end state at ``t_s`` (``ego`` its state then, ``u`` the input it held)."""
    return EndState(
        settle_end_s=t_s,
        end_heading_rad=float(ego[2]),
        end_lateral_speed_mps=lane_keeping.lateral_speed_mps(ego, u),
        end_line_excess_m=float(lane_keeping.line_excess_m(ego[1], ego[2], p)),
        in_lane=lane_keeping.footprint_in_lane(ego, p),
        **conv,
    )


@dataclass
class _Settling:
    """One episode's memory from its goal test until settling ends (host side)."""

    until_step: int  # the control step at which settling ends
    v_converged_mps: float
    heading_rad: float  # at the goal test
    lateral_speed_mps: float
    line_excess_m: float
    line_excess_max_m: float  # so far

    @classmethod
    def start(cls, until_step: int, ego: np.ndarray, u_last: np.ndarray, p) -> _Settling:
        excess = float(lane_keeping.line_excess_m(ego[1], ego[2], p))
        return cls(until_step, float(ego[3]), float(ego[2]), lane_keeping.lateral_speed_mps(ego, u_last), excess,
                   excess)

    def input(self, ego: np.ndarray, front_meas: np.ndarray, p) -> np.ndarray:
        v_ref = lane_keeping.reference_speed(self.v_converged_mps, ego, front_meas, p)
        return lane_keeping.lane_keeping_input(ego, v_ref, p)

    def note(self, sub_ego: np.ndarray, p) -> None:
        """Take in one control period's sub-steps (substeps, 4) of the ego."""
        self.line_excess_max_m = max(self.line_excess_max_m,
                                     float(lane_keeping.line_excess_m(sub_ego[:, 1], sub_ego[:, 2], p).max()))

    def end(self, t_s: float, ego: np.ndarray, u: np.ndarray, p) -> EndState:
        return _end_state(t_s, ego, u, p, conv_heading_rad=self.heading_rad,
                          conv_lateral_speed_mps=self.lateral_speed_mps, conv_line_excess_m=self.line_excess_m,
                          line_excess_max_m=self.line_excess_max_m)
