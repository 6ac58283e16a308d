"""The fair baseline of ``python -m benchmarks.engine``: the IPOPT loop a careful CasADi user writes.

Against :mod:`benchmarks.naive` (the paper's way: ``Opti`` without ``expand``, IPOPT defaults, a
primal-only warm start that ``mu_init`` 0.1 throws away), this loop does what a user who tunes
IPOPT for a closed loop does, and nothing that needs this project's code generation:

* ``nlpsol`` on the SX problem of :func:`mcverify.ocp.build_nlp` with ``expand=True`` (CasADi's
  SX virtual machine evaluates the functions and their derivatives, no gcc);
* a primal-dual warm start (the previous ``x``, ``lam_x``, ``lam_g``) with IPOPT's warm-start options
  and ``mu_init`` 1e-7, exactly the reference's options (:func:`mcverify.solver.backends.ipopt_options`);
  a failed warm start retried cold, like the reference;
* the same infeasibility policy as the engine: while the planner's infeasibility memo presumes a
  problem infeasible (``fast_only``, see :attr:`mcverify.model.Mpc.infeasible_recheck_steps`), the
  loop makes one IPOPT attempt (warm if it has a start, else cold) capped at ``mpc.max_iter``
  iterations instead of the full warm-then-cold attempt, and a failure is reported with the route
  :attr:`~mcverify.solver.status.SolveRoute.PRESUMED` - the analogue of the engine's fast-path-only
  attempt. The reference ``ipopt`` backend ignores ``fast_only``, so without this the baseline would
  pay IPOPT's full attempt on every presumed step and the ratio would flatter the engine.

Everything else (decisions, plant, noise, the common 1e-5 feasibility check of the returned point)
is the engine's, so episodes of the two loops pair by (seed, cell, episode id).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import casadi as ca
import numpy as np

from mcverify import ocp
from mcverify.control.planner import Planner
from mcverify.model import ModelParams
from mcverify.solver.backends import BackendResult, IpoptBackend, Problem, Start, ipopt_options
from mcverify.solver.mpc import MpcSolver
from mcverify.solver.status import SolveRoute

#: Name of the baseline in reports.
NAME = "compiled IPOPT loop"


def expanded_ipopt(name: str, structure: ocp.OcpStructure, params: ModelParams, warm: bool,
                   max_iter: int | None = None) -> ca.Function:
    """``nlpsol`` on the SX NLP of ``structure`` with ``expand=True`` and the reference's IPOPT options
    (warm: primal-dual warm start, ``mu_init`` 1e-7); ``max_iter`` overrides the iteration limit."""
    opts = ipopt_options(params, warm)
    opts["expand"] = True
    if max_iter is not None:
        opts["ipopt"] = {**opts["ipopt"], "max_iter": int(max_iter)}
    return ca.nlpsol(name, "ipopt", ocp.build_nlp(structure), opts)


class ExpandedIpoptBackend(IpoptBackend):
    """:class:`~mcverify.solver.backends.IpoptBackend`'s loop (warm, cold retry) on ``expand=True``
    solvers instead of the generated C kernel, plus the presumed-infeasible single attempt."""

    name = "ipopt-expand"

    def __init__(self, problem: Problem, params: ModelParams, structure: ocp.OcpStructure) -> None:
        # no super().__init__: that would build the reference's solvers on the compiled kernel
        self.problem = problem
        self._cold = expanded_ipopt("user_cold", structure, params, warm=False)
        self._warm = expanded_ipopt("user_warm", structure, params, warm=True)
        self._cold_short = expanded_ipopt("user_cold_short", structure, params, warm=False,
                                          max_iter=params.mpc.max_iter)

    def solve(
        self, p: np.ndarray, warm: Start | None, guess: Callable[[], np.ndarray], fast_only: bool = False
    ) -> BackendResult:
        """The reference loop; with ``fast_only`` one attempt of at most ``mpc.max_iter`` iterations."""
        if not fast_only:
            return super().solve(p, warm, guess)
        if warm is not None:
            res = self.problem.accept(self.run(p, warm), p)
        else:
            cold, self._cold = self._cold, self._cold_short  # run() calls self._cold for a cold start
            try:
                res = self.problem.accept(self.run(p, None, guess), p)
            finally:
                self._cold = cold
        if res.success:
            return res
        return dataclasses.replace(res, status=res.status.via(SolveRoute.PRESUMED))


def expanded_ipopt_solver(params: ModelParams, structure: ocp.OcpStructure) -> MpcSolver:
    """An :class:`~mcverify.solver.mpc.MpcSolver` (same packing, guesses and feasibility check) whose
    backend is :class:`ExpandedIpoptBackend`."""
    ref = dataclasses.replace(params, mpc=dataclasses.replace(params.mpc, backend="ipopt"))
    solver = MpcSolver(ref, structure)
    solver.backend = ExpandedIpoptBackend(solver.problem, ref, solver.structure)
    solver.kernel_hash = "ipopt-expand"
    return solver


def ipopt_loop_planner(params: ModelParams, wrap: Callable | None = None) -> Planner:
    """A :class:`~mcverify.control.planner.Planner` on the baseline's solvers; ``wrap(solver)``
    (e.g. a per-solve timer) is applied to each."""
    def make(p, st):
        s = expanded_ipopt_solver(p, st)
        return wrap(s) if wrap else s

    return Planner(params, solver_factory=make)
