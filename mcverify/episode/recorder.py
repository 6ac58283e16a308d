"""The recorder of a chunk's recorded episodes: their full-resolution trajectories, per-step decisions
and plan snapshots, as the tables of :class:`~mcverify.episode.recording.EpisodeRecording`."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from mcverify.cell import Cell
from mcverify.control.margins import both_certified_infeasible, problem_margin
from mcverify.control.planner import StepRecord
from mcverify.episode.recording import EpisodeRecording
from mcverify.sim.plant import Substep

#: Planned trajectories of recorded episodes are kept every this many seconds (figures).
PLAN_SNAPSHOT_PERIOD_S = 0.5


class Recorder:
    """Collects full-resolution trajectories, per-step decisions and plan snapshots of some episodes."""

    def __init__(self, lanes: list[int], cell: Cell) -> None:
        self.lanes = lanes
        self.cell = cell
        self.parts: dict[int, list[dict[str, np.ndarray]]] = {b: [] for b in lanes}
        self.plans: dict[int, list[dict[str, np.ndarray]]] = {b: [] for b in lanes}
        self.next_snapshot_s = {b: 0.0 for b in lanes}

    def add(self, t_s: float, subs: Substep, u, records: dict[int, StepRecord], front_meas, opp_meas, active) -> None:
        k = subs.t_s.shape[1]
        for b in self.lanes:
            if not active[b]:
                continue
            r = records.get(b)
            rep = lambda v: np.full(k, v, dtype=float)  # noqa: E731 - per control step -> per sub-step
            ego, front, opp = subs.ego[b], subs.front[b], subs.opp[b]
            has_opp = self.cell.params.opposing.kind != "none"
            self.parts[b].append({
                "t_s": subs.t_s[b],
                "ego_x_m": ego[:, 0], "ego_y_m": ego[:, 1], "ego_psi_rad": ego[:, 2], "ego_speed_mps": ego[:, 3],
                "front_x_m": front[:, 0], "front_y_m": np.zeros(k), "front_speed_mps": front[:, 1],
                "opp_x_m": opp[:, 0] if has_opp else rep(np.nan),
                "opp_y_m": rep(self.cell.params.road.opp_lane_y_m if has_opp else np.nan),
                "opp_speed_mps": -opp[:, 1] if has_opp else rep(np.nan),
                "alpha_mps2": rep(u[b, 0]), "beta_rad": rep(u[b, 1]),
                "h_front": subs.h_front[b], "dist_front_m": subs.dist_front_m[b], "gap_front_m": subs.gap_front_m[b],
                "collision_front": subs.collision_front[b].astype(float),
                "h_opp": subs.h_opp[b] if has_opp else rep(np.nan),
                "gap_opp_m": subs.gap_opp_m[b] if has_opp else rep(np.nan),
                "collision_opp": subs.collision_opp[b].astype(float),
                "active_problem": rep(int(r.source) if r else 0),
                "mode": rep(int(r.mode) if r else -1),
                "opp_detected": rep(float(r.detected) if r else 0.0),
                "q1_solved": rep(_solved(r.q1) if r else np.nan),
                "q2_solved": rep(_solved(r.q2) if r else np.nan),
                "q1_time_s": rep(_total(r.q1) if r else np.nan),
                "q2_time_s": rep(_total(r.q2) if r else np.nan),
                "table_one_row": rep(r.table_row if r else -1),
                "both_certified": rep(float(both_certified_infeasible(r.q1, r.q2)) if r else np.nan),
                "q1_margin": rep(_margin(r.q1) if r else np.nan),
                "q2_margin": rep(_margin(r.q2) if r else np.nan),
                "meas_front_x_m": rep(front_meas[b, 0]), "meas_front_y_m": rep(front_meas[b, 1]),
                "meas_front_speed_mps": rep(front_meas[b, 2]),
                "meas_opp_x_m": rep(opp_meas[b, 0] if has_opp else np.nan),
                "meas_opp_speed_mps": rep(-opp_meas[b, 1] if has_opp else np.nan),
            })
            if r is not None and t_s + 1e-9 >= self.next_snapshot_s[b]:
                self.next_snapshot_s[b] += PLAN_SNAPSHOT_PERIOD_S
                for name, sol in (("Q1", r.q1), ("Q2", r.q2)):
                    if sol is not None and sol.success:
                        self.plans[b].append(_plan_table(t_s, name, sol))

    def recordings(self, ids: Sequence[int]) -> dict[int, EpisodeRecording]:
        """Cell-local episode id -> its recording (the per-step parts concatenated)."""
        return {ids[b]: EpisodeRecording(_concat(self.parts[b]), _concat(self.plans[b])) for b in self.lanes}


def _concat(parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    return {key: np.concatenate([pt[key] for pt in parts]) for key in parts[0]} if parts else {}


def _solved(sol) -> float:
    return np.nan if sol is None else float(sol.success)


def _margin(sol) -> float:
    return np.nan if sol is None else problem_margin(sol)


def _total(sol) -> float:
    return sol.total_time_s if sol is not None and sol.success else np.nan


def _plan_table(t_s: float, name: str, sol) -> dict[str, np.ndarray]:
    n = sol.x_plan.shape[0]
    t_nodes = t_s + np.concatenate([[0.0], np.cumsum(sol.dt_plan)])
    opp_x = sol.opp_plan[:, 0] if sol.opp_plan is not None else np.full(n, np.nan)
    return {
        "t_s": np.full(n, t_s), "problem": np.array([name] * n), "node": np.arange(n),
        "t_node_s": t_nodes, "x_m": sol.x_plan[:, 0], "y_m": sol.x_plan[:, 1], "speed_mps": sol.x_plan[:, 3],
        "opp_x_m": opp_x,
    }
