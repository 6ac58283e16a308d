"""Host-side TO-CBF-MPC solve: IPOPT on the compiled kernel of :mod:`mcverify.kernels`.

``MpcSolver(params).solve(ego_state, front_xyv, direction, lambda0, warm)`` returns an
:class:`MpcSolution`; it never raises for numerical trouble (IPOPT failures, exceptions, NaNs become
``success=False`` with a status string). Solves are deterministic: the same inputs (including the
same ``warm``) give bit-identical outputs; nothing depends on wall time or on earlier solves.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from mcverify.kernels import get_kernel
from mcverify.model import ModelParams
from mcverify.ocp import (
    NlpLayout,
    OcpStructure,
    constraint_bounds,
    decision_bounds,
    initial_guess,
    pack_params,
)

#: IPOPT's return_status values that count as solved (before our own feasibility check).
SOLVED_STATUSES = frozenset({"Solve_Succeeded", "Solved_To_Acceptable_Level"})
#: Largest constraint or bound violation (unscaled, any unit) of a plan reported as a success.
MAX_VIOLATION = 1e-5


def ipopt_options(params: ModelParams, warm: bool) -> dict:
    """IPOPT options of the cold (``warm=False``) or warm-started solver.

    * ``tol`` and ``max_iter`` (warm) / ``max_iter_cold`` from :class:`~mcverify.model.Mpc`;
      ``constr_viol_tol`` 1e-7 (default 1e-4) so that "Solve_Succeeded" implies our own 1e-5
      feasibility check; the acceptable-level exit (15 iterations at ``acceptable_tol``) keeps the
      default 1e-6 but its constraint tolerance is tightened from 1e-2 to 1e-6 for the same reason.
    * Warm: ``warm_start_init_point`` with small bound pushes (1e-6), so the previous primal-dual
      point is kept nearly as is, and ``mu_init`` 1e-7 instead of 0.1, which would push the iterate
      back to the central path and throw the warm start away. Measured along Table II closed loops
      (25 and 36 km/h Q1, Q2 from alongside veh_f; about 1000 solves): mean iterations 3.4 / 3.3 /
      5.1 at mu_init 1e-7, 6.4 / 6.4 / 7.4 at 1e-6; on shorter stretches of the same loops 12-19
      at 1e-4 and 35-94 without ``warm_start_init_point``; 1e-8 and 1e-9 were no better than 1e-7.
    * The previous plan is used as it is (not shifted): shifting one stage cost more iterations
      (4.1 / 4.2 / 11.1), and re-timing it by the ego's progress helped Q1 (2.5 / 2.0) but hurt Q2
      (7.1), so the simplest choice stays.
    """
    opts = {
        "print_level": 0,
        "sb": "yes",
        "max_iter": params.mpc.max_iter if warm else params.mpc.max_iter_cold,
        "tol": params.mpc.tol,
        "constr_viol_tol": 1e-7,
        "acceptable_constr_viol_tol": 1e-6,
    }
    if warm:
        opts.update({
            "warm_start_init_point": "yes",
            "warm_start_bound_push": 1e-6,
            "warm_start_bound_frac": 1e-6,
            "warm_start_slack_bound_push": 1e-6,
            "warm_start_slack_bound_frac": 1e-6,
            "warm_start_mult_bound_push": 1e-6,
            "mu_init": 1e-7,
        })
    return {"print_time": False, "error_on_fail": False, "ipopt": opts}


@dataclass(frozen=True)
class WarmStart:
    """Primal-dual point of a solved plan, to start the next solve of the same problem from.

    x (n_w,), lam_x (n_w,), lam_g (n_g,) in the layout of :class:`~mcverify.ocp.NlpLayout`;
    direction: the problem (+1 Q1, -1 Q2) it solved; a warm start of the other direction is ignored.
    """

    x: np.ndarray
    lam_x: np.ndarray
    lam_g: np.ndarray
    direction: int


@dataclass(frozen=True)
class MpcSolution:
    success: bool  # IPOPT solved (or acceptable) AND max constraint/bound violation <= MAX_VIOLATION
    status: str  # IPOPT return_status, or "exception: <msg>" / "invalid_input: <msg>"
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


class MpcSolver:
    """TO-CBF-MPC (box eq.tompc) solved by IPOPT on a compiled, cached kernel.

    params: the model; structure: defaults to ``OcpStructure.from_params(params)``; kernel_dir: the
    kernel cache (see :func:`mcverify.kernels.resolve_kernel_dir`). The kernel is loaded, or
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
        so = str(self.kernel.so_path)
        self._cold = ca.nlpsol("tocbf_cold", "ipopt", so, ipopt_options(params, warm=False))
        self._warm = ca.nlpsol("tocbf_warm", "ipopt", so, ipopt_options(params, warm=True))
        self._g = ca.external("nlp_g", so)
        self._lbx, self._ubx = decision_bounds(params, structure)
        self._lbg, self._ubg = constraint_bounds(structure)

    # ------------------------------------------------------------------------------------------
    def solve(
        self,
        ego_state: np.ndarray,
        front_xyv: np.ndarray,
        direction: int,
        lambda0: float,
        warm: WarmStart | None = None,
        opp_xv: np.ndarray | None = None,
        guess: np.ndarray | None = None,
    ) -> MpcSolution:
        """Solve Q1 (direction +1) or Q2 (-1) from the measured states.

        ego_state (4,) [x m, y m, psi rad, v m/s]; front_xyv (3,) [x_f m, y_f m, v_f m/s];
        lambda0: level parameter (<= 0); warm: the ``warm`` of the previous solution of the same
        direction, or None for a cold start from :func:`~mcverify.ocp.initial_guess`;
        opp_xv (2,) [x_o m, v_o m/s signed]: the measured opposing vehicle, required (only) when the
        structure has one; guess (n_w,): a primal starting point for a cold solve instead of
        :func:`~mcverify.ocp.initial_guess` (e.g. the plain problem's plan, :func:`guess_from_plan`).
        """
        t0 = time.perf_counter()
        try:
            p = pack_params(
                self.params, ego_state, front_xyv, direction, lambda0, opp_xv=opp_xv, structure=self.structure
            )
        except ValueError as exc:  # wrong shapes or direction: a caller error, not numerics
            raise ValueError(f"MpcSolver.solve: {exc}") from exc
        if not np.all(np.isfinite(p)):
            return self._failure("invalid_input: non-finite ego_state, front_xyv or lambda0", t0)
        use_warm = warm is not None and warm.direction == direction and warm.x.size == self.layout.n_w
        if use_warm:
            sol = self._run(p, direction, t0, warm=warm)
            if sol.success:
                return sol
            # A warm start that fails is not evidence of infeasibility: the interior point was
            # started next to the previous active set (mu_init 1e-7) and, when that set changes
            # (e.g. Q2's goal switches from braking behind veh_f to a lane change), IPOPT stalls
            # or wrongly reports local infeasibility. Along Table II closed loops every such Q2
            # failure solved from the cold guess (40-60 iterations). The retry is counted.
            cold = self._run(p, direction, t0, warm=None, ego_state=ego_state, front_xyv=front_xyv, opp_xv=opp_xv,
                             guess=guess)
            return dataclasses.replace(cold, iterations=sol.iterations + cold.iterations, retried_cold=True)
        return self._run(p, direction, t0, warm=None, ego_state=ego_state, front_xyv=front_xyv, opp_xv=opp_xv,
                         guess=guess)

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

    def _run(self, p, direction, t0, *, warm, ego_state=None, front_xyv=None, opp_xv=None, guess=None) -> MpcSolution:
        """One IPOPT call: warm from ``warm`` or cold from :func:`~mcverify.ocp.initial_guess`."""
        try:
            if warm is not None:
                res = self._warm(
                    x0=warm.x, lam_x0=warm.lam_x, lam_g0=warm.lam_g, p=p,
                    lbx=self._lbx, ubx=self._ubx, lbg=self._lbg, ubg=self._ubg,
                )
                stats = self._warm.stats()
            else:
                w0 = guess if guess is not None else initial_guess(
                    self.params, self.structure, ego_state, front_xyv, direction, opp_xv
                )
                res = self._cold(x0=w0, p=p, lbx=self._lbx, ubx=self._ubx, lbg=self._lbg, ubg=self._ubg)
                stats = self._cold.stats()
        except Exception as exc:  # noqa: BLE001 - IPOPT/CasADi errors become a failed solution
            return self._failure(f"exception: {exc}".splitlines()[0], t0)
        return self._solution(res, stats, p, direction, t0)

    # ------------------------------------------------------------------------------------------
    def max_violation(self, w: np.ndarray, p: np.ndarray) -> float:
        """Largest violation of g's bounds and of w's bounds at (w, p); inf if anything is NaN."""
        g = np.asarray(self._g(w, p), dtype=float).ravel()
        if not (np.all(np.isfinite(g)) and np.all(np.isfinite(w))):
            return float("inf")
        parts = [self._lbg - g, g - self._ubg, self._lbx - w, w - self._ubx]
        return max(0.0, *(float(np.max(v)) for v in parts))

    def _solution(self, res: dict, stats: dict, p: np.ndarray, direction: int, t0: float) -> MpcSolution:
        w = np.asarray(res["x"], dtype=float).ravel()
        lam_x = np.asarray(res["lam_x"], dtype=float).ravel()
        lam_g = np.asarray(res["lam_g"], dtype=float).ravel()
        status = str(stats.get("return_status", "unknown"))
        iterations = int(stats.get("iter_count", -1))
        violation = self.max_violation(w, p)
        finite = all(np.all(np.isfinite(a)) for a in (w, lam_x, lam_g))
        success = status in SOLVED_STATUSES and finite and violation <= MAX_VIOLATION
        x_plan, u_plan, dt_plan = self.layout.unpack(w)
        warm = WarmStart(w, lam_x, lam_g, int(direction)) if success else None
        return MpcSolution(
            success=bool(success),
            status=status,
            iterations=iterations,
            solve_time_s=time.perf_counter() - t0,
            total_time_s=float(np.sum(dt_plan)),
            x_plan=x_plan,
            u_plan=u_plan,
            dt_plan=dt_plan,
            warm=warm,
            max_violation=violation,
            opp_plan=self.layout.unpack_opposing(w) if self.structure.with_opposing else None,
        )

    def _failure(self, status: str, t0: float) -> MpcSolution:
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
