"""The naive reference loop of the benchmark: the paper's way of running the controller.

A Python loop over episodes and control steps; each step solves each problem with CasADi's ``Opti``
and IPOPT at its default settings (problem built once, re-solved with ``set_value``, warm-started with
``set_initial`` from the previous primal solution, as a CasADi user writes it). No generated code, no
batching, no tuned warm starts. Everything else is the engine's: the same NLP maths
(:func:`mcverify.ocp.ocp.build_nlp`, wrapped into the Opti problem), the same decisions
(:class:`mcverify.control.planner.Planner` with this solver), the same plant and noise draws (the JAX plant run
one episode at a time) - so the safety verdicts of naive and engine episodes can be paired.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence

import casadi as ca
import numpy as np

from mcverify import ocp
from mcverify.cell import Cell
from mcverify.control.planner import Planner
from mcverify.episode.rollout import run_episodes
from mcverify.model import ModelParams
from mcverify.solver.mpc import MpcSolution, WarmStart
from mcverify.solver.status import SolveStatus


class NaiveOptiSolver:
    """One TO-CBF-MPC structure as an ``Opti`` problem (MX graph calling the SX maths, interpreted)."""

    def __init__(self, params: ModelParams, structure: ocp.OcpStructure) -> None:
        self.params, self.structure = params, structure
        self.layout = ocp.NlpLayout.of(structure)
        nlp = ocp.build_nlp(structure)
        fn = ca.Function("nlp", [nlp["x"], nlp["p"]], [nlp["f"], nlp["g"]])
        self.opti = ca.Opti()
        self.w = self.opti.variable(self.layout.n_w)
        self.p = self.opti.parameter(ocp.ParamLayout.of(structure).size)
        f, g = fn(self.w, self.p)
        lbx, ubx = ocp.decision_bounds(params, structure)
        lbg, ubg = ocp.constraint_bounds(structure, ocp.distance_margin(params))
        self.opti.minimize(f)
        n_eq = self.layout.n_eq
        self.opti.subject_to(g[:n_eq] == 0)
        self.opti.subject_to(g[n_eq:] >= lbg[n_eq:])
        finite_lo, finite_hi = np.isfinite(lbx), np.isfinite(ubx)
        self.opti.subject_to(self.opti.bounded(lbx[finite_lo], self.w[np.flatnonzero(finite_lo).tolist()],
                                               np.where(finite_hi, ubx, np.inf)[finite_lo]))
        only_hi = finite_hi & ~finite_lo
        if only_hi.any():
            self.opti.subject_to(self.w[np.flatnonzero(only_hi).tolist()] <= ubx[only_hi])
        self.opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "sb": "yes",
                                                          "max_iter": params.mpc.max_iter_cold})
        self.kernel_hash = "naive-opti"

    def solve(
        self, ego_state, front_xyv, direction, level, warm=None, opp_xv=None, guess=None, fast_only=False
    ) -> MpcSolution:
        """One Opti solve (``fast_only`` is ignored: the paper's loop runs IPOPT in full every time)."""
        t0 = time.perf_counter()
        p = ocp.pack_params(self.params, ego_state, front_xyv, direction, level, opp_xv=opp_xv,
                            structure=self.structure)
        self.opti.set_value(self.p, p)
        if warm is not None and warm.direction == direction and warm.x.size == self.layout.n_w:
            start = warm.x
        elif guess is not None:
            start = guess
        else:
            start = ocp.initial_guess(self.params, self.structure, ego_state, front_xyv, direction, opp_xv)
        self.opti.set_initial(self.w, start)
        try:
            sol = self.opti.solve()
            w = np.asarray(sol.value(self.w), dtype=float).ravel()
            stats = sol.stats()
        except RuntimeError:  # Opti raises when IPOPT does not succeed
            w = np.asarray(self.opti.debug.value(self.w), dtype=float).ravel()
            stats = self.opti.stats()
        status = SolveStatus.ipopt(str(stats.get("return_status", "unknown")))
        success = status.outcome.converged and bool(np.all(np.isfinite(w)))
        x_plan, u_plan, dt_plan = self.layout.unpack(w)
        return MpcSolution(
            success=success, status=status, iterations=int(stats.get("iter_count", -1)),
            solve_time_s=time.perf_counter() - t0, total_time_s=float(np.sum(dt_plan)), x_plan=x_plan,
            u_plan=u_plan, dt_plan=dt_plan,
            warm=WarmStart(w, np.zeros_like(w), np.zeros(self.layout.n_g), int(direction)) if success else None,
            opp_plan=self.layout.unpack_opposing(w) if self.structure.with_opposing else None,
        )

    def guess_from_plan(self, plan: MpcSolution, opp_xv) -> np.ndarray | None:
        if not plan.success:
            return None
        xo = None
        if self.structure.with_opposing:
            t = np.concatenate([[0.0], np.cumsum(plan.dt_plan)])
            xo = np.column_stack([opp_xv[0] + opp_xv[1] * t, np.full(t.size, opp_xv[1])])
        return self.layout.pack(plan.x_plan, plan.u_plan, plan.dt_plan, xo)


def naive_planner(params: ModelParams, wrap=None) -> Planner:
    """A planner on :class:`NaiveOptiSolver`; ``wrap(solver)`` (e.g. a per-solve timer) is applied to each."""
    return Planner(params, solver_factory=lambda p, st: (wrap or (lambda s: s))(NaiveOptiSolver(p, st)))


def run_naive(cell: Cell, episode_ids: Sequence[int], seed: int, *, common_random_numbers: bool = False) -> list[dict]:
    """The reference loop: one episode after the other, each its own closed loop with Opti solves."""
    planner = naive_planner(cell.params)
    rows = []
    for e in episode_ids:
        rows.extend(run_episodes(cell, [e], seed, planner, common_random_numbers=common_random_numbers).rows)
    return rows


def per_solve_seconds(rows: list[dict]) -> float:
    solves = sum(r["solves"] for r in rows)
    return math.nan if not solves else sum(r["solve_time_mean_s"] * r["solves"] for r in rows) / solves
