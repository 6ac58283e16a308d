"""Host-side TO-CBF-MPC solve on the compiled kernel of :mod:`mcverify.solver.kernels`.

``MpcSolver(params).solve(ego_state, front_xyv, direction, level, warm)`` returns an
:class:`MpcSolution`; it never raises for numerical trouble (solver failures, exceptions, NaNs become
``success=False`` with a :class:`~mcverify.solver.status.SolveStatus`). Solves are deterministic:
the same inputs (including the same ``warm``) give bit-identical outputs; nothing depends on wall
time or on earlier solves.

The numerical work is done by the backend named in ``params.mpc.backend`` (:mod:`mcverify.solver.backends`:
"ipopt", the reference, or "ipm", the fast path with IPOPT as its fallback).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from mcverify.levels import Level
from mcverify.model import ModelParams
from mcverify.ocp import (
    NlpLayout,
    OcpStructure,
    constraint_bounds,
    decision_bounds,
    distance_margin,
    initial_guess,
    pack_params,
)
from mcverify.solver.backends import BackendResult, Problem, Start, create_backend
from mcverify.solver.kernels import get_kernel
from mcverify.solver.status import SolveStatus


@dataclass(frozen=True)
class WarmStart:
    """Primal-dual point of a solved plan, to start the next solve of the same problem from.

    x (n_w,), lam_x (n_w,), lam_g (n_g,) in the layout of :class:`~mcverify.ocp.problem.NlpLayout`;
    direction: the problem (+1 Q1, -1 Q2) it solved; a warm start of the other direction is ignored.
    hard_run: how many solves in a row, this one the last, were hard
    (:attr:`mcverify.solver.backends.BackendResult.hard`; 0: this one was not; read by the attempt plan).
    """

    x: np.ndarray
    lam_x: np.ndarray
    lam_g: np.ndarray
    direction: int
    hard_run: int = 0


@dataclass(frozen=True)
class MpcSolution:
    success: bool  # the backend solved it AND max constraint/bound violation <= backends.MAX_VIOLATION
    status: SolveStatus  # what the solver reported (raw text kept for display) and which path answered
    iterations: int
    solve_time_s: float  # wall time of this solve (time.perf_counter)
    total_time_s: float  # T = sum DT (the planned time to goal, seconds)
    x_plan: np.ndarray  # (N+1, 4) [x, y, psi, v]
    u_plan: np.ndarray  # (N, 2) [alpha, beta]
    dt_plan: np.ndarray  # (N,)
    warm: WarmStart | None  # what to pass to the next solve of the same problem; None on failure
    max_violation: float = float("nan")  # largest constraint or bound violation of the returned plan
    retried_cold: bool = False  # the warm start failed and this is the cold retry's result
    opp_plan: np.ndarray | None = None  # (N+1, 2) predicted veh_o [x_o, v_o]; None without one
    # smallest slack of the barrier rows of g (the front and opposing vehicles' CBF, or MPC-DC's distance
    # rows) over the horizon at the returned plan, in those rows' units; NaN unless solved (Theorem 5's margin)
    cbf_slack: float = float("nan")


class MpcSolver:
    """TO-CBF-MPC (box eq.tompc) on a compiled, cached kernel, solved by ``params.mpc.backend``.

    params: the model; structure: defaults to ``OcpStructure.from_params(params)``; kernel_dir: the
    kernel cache (see :func:`mcverify.solver.kernels.resolve_kernel_dir`). The kernel is loaded, or
    generated and compiled once, here.
    """

    def __init__(
        self,
        params: ModelParams,
        structure: OcpStructure | None = None,
        kernel_dir=None,
    ) -> None:
        structure = structure or OcpStructure.from_params(params)
        if structure.order_m != params.barrier.order_m:
            raise ValueError(f"structure.order_m={structure.order_m} but params.barrier has "
                             f"{params.barrier.order_m} lambdas")
        self.params = params
        self.structure = structure
        self.layout = NlpLayout.of(structure)
        self.kernel = get_kernel(structure, kernel_dir)
        self.kernel_hash: str = self.kernel.hash
        lbx, ubx = decision_bounds(params, structure)
        lbg, ubg = constraint_bounds(structure, distance_margin(params))
        self.problem = Problem(self.kernel, lbx, ubx, lbg, ubg)
        self.backend = create_backend(params.mpc.backend, self.problem, params, kernel_dir=kernel_dir)
        gs = self.layout.g_slices
        # the rows whose slack measures how much room a solved plan leaves (MpcSolution.cbf_slack)
        self._barrier_rows = np.r_[gs["front"], gs["opp"]]

    # ------------------------------------------------------------------------------------------
    def solve(
        self,
        ego_state: np.ndarray,
        front_xyv: np.ndarray,
        direction: int,
        level: Level,
        warm: WarmStart | None = None,
        opp_xv: np.ndarray | None = None,
        guess: np.ndarray | None = None,
        fast_only: bool = False,
    ) -> MpcSolution:
        """Solve Q1 (direction +1) or Q2 (-1) from the measured states.

        ego_state (4,) [x m, y m, psi rad, v m/s]; front_xyv (3,) [x_f m, y_f m, v_f m/s];
        level: the cell's VL-CBF level (:class:`mcverify.levels.Level`); warm: the ``warm`` of the
        previous solution of the same direction, or None for a cold start from
        :func:`~mcverify.ocp.problem.initial_guess`;
        opp_xv (2,) [x_o m, v_o m/s signed]: the measured opposing vehicle, required (only) when the
        structure has one; guess (n_w,): a primal starting point for a cold solve instead of
        :func:`~mcverify.ocp.problem.initial_guess` (e.g. the plain problem's plan, :func:`guess_from_plan`).
        fast_only: the backend's fast path only, no IPOPT fallback (for a problem IPOPT has just
        certified infeasible; the ``ipopt`` backend ignores it).
        """
        t0 = time.perf_counter()
        try:
            p = pack_params(
                self.params, ego_state, front_xyv, direction, level, opp_xv=opp_xv, structure=self.structure
            )
        except ValueError as exc:  # wrong shapes or direction: a caller error, not numerics
            raise ValueError(f"MpcSolver.solve: {exc}") from exc
        if not np.all(np.isfinite(p)):
            return self._failure(SolveStatus.invalid_input("non-finite ego_state, front_xyv or level"), t0)
        use_warm = warm is not None and warm.direction == direction and warm.x.size == self.layout.n_w
        start = Start(warm.x, warm.lam_x, warm.lam_g, hard_run=warm.hard_run) if use_warm else None

        def cold_guess() -> np.ndarray:
            if guess is not None:
                return np.asarray(guess, dtype=float)
            return initial_guess(self.params, self.structure, ego_state, front_xyv, direction, opp_xv)

        try:
            res = self.backend.solve(p, start, cold_guess, fast_only=fast_only)
        except Exception as exc:  # noqa: BLE001 - solver errors become a failed solution
            return self._failure(SolveStatus.exception(str(exc)), t0)
        return self._solution(res, direction, t0, 0 if start is None else start.hard_run, p)

    def guess_from_plan(self, plan: MpcSolution, opp_xv: np.ndarray | None) -> np.ndarray | None:
        """A primal guess for this solver's structure from a plan of another structure (the same
        ego variables; veh_o, if this structure has one, extrapolated at its measured speed)."""
        if not plan.success:
            return None
        xo = None
        if self.structure.with_opposing:
            t = np.concatenate([[0.0], np.cumsum(plan.dt_plan)])
            x_o, v_o = np.asarray(opp_xv, dtype=float).reshape(2)
            xo = np.column_stack([x_o + v_o * t, np.full(t.size, v_o)])
        return self.layout.pack(plan.x_plan, plan.u_plan, plan.dt_plan, xo)

    # ------------------------------------------------------------------------------------------
    def max_violation(self, w: np.ndarray, p: np.ndarray) -> float:
        """Largest violation of g's bounds and of w's bounds at (w, p); inf if anything is NaN."""
        return self.problem.max_violation(w, p)

    def _solution(self, res: BackendResult, direction: int, t0: float, start_hard_run: int,
                  p: np.ndarray) -> MpcSolution:
        """start_hard_run: the hard solves in a row before this one (the warm start's count; 0 for a cold
        solve); p: the parameters it was solved for (the barrier rows' slack is evaluated at them)."""
        x_plan, u_plan, dt_plan = self.layout.unpack(res.w)
        run = start_hard_run + 1 if res.hard else 0
        warm = WarmStart(res.w, res.lam_x, res.lam_g, int(direction), hard_run=run) if res.success else None
        return MpcSolution(
            success=bool(res.success),
            status=res.status,
            iterations=res.iterations,
            solve_time_s=time.perf_counter() - t0,
            total_time_s=float(np.sum(dt_plan)),
            x_plan=x_plan,
            u_plan=u_plan,
            dt_plan=dt_plan,
            warm=warm,
            max_violation=res.max_violation,
            retried_cold=res.retried_cold,
            opp_plan=self.layout.unpack_opposing(res.w) if self.structure.with_opposing else None,
            cbf_slack=self.problem.min_slack(res.w, p, self._barrier_rows) if res.success else float("nan"),
        )

    def _failure(self, status: SolveStatus, t0: float) -> MpcSolution:
        n = self.structure.horizon
        return MpcSolution(
            success=False,
            status=status,
            iterations=0,
            solve_time_s=time.perf_counter() - t0,
            total_time_s=float("nan"),
            x_plan=np.full((n + 1, 4), np.nan),
            u_plan=np.full((n, 2), np.nan),
            dt_plan=np.full(n, np.nan),
            warm=None,
        )
