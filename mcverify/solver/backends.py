"""Solver backends for the TO-CBF-MPC NLP: IPOPT (the reference) and a fast interior-point path.

A backend solves the NLP of :func:`mcverify.ocp.problem.build_nlp` (through the compiled kernel of
:mod:`mcverify.solver.kernels`) for one parameter vector ``p`` from a warm start (the primal-dual point of
the previous solve of the same problem) or cold (from :func:`mcverify.ocp.problem.initial_guess`), and
returns a :class:`BackendResult`: the point, the multipliers, a status, an iteration count and its
own success verdict, combined by :meth:`Problem.accept` with the common feasibility check (largest
violation <= 1e-5). :class:`mcverify.solver.mpc.MpcSolver` builds the
:class:`~mcverify.solver.mpc.MpcSolution` from it. Selection: ``params.mpc.backend``, one of
:data:`~mcverify.model.BACKEND_NAMES`.

``ipopt``: IPOPT with MUMPS through CasADi, cold or warm started, a failed warm start retried cold
(the behaviour of every result so far).

``ipm``: the interior-point method of :mod:`mcverify.solver.ipm` - IPOPT's algorithm, run in C on a
banded factorisation of the KKT system with the kernel's functions called directly - warm
started like the reference, with the attempts of :mod:`mcverify.solver.attempts` (per controller
family); IPOPT is its fallback:

* whatever the IPM does not solve (no convergence in its iteration limit, a failed line search,
  anything non-finite, a point that fails the common feasibility check) goes to the IPOPT
  reference path (warm, then cold) for the same solve, and the result's status has the route
  :attr:`~mcverify.solver.status.SolveRoute.FALLBACK`. So a failed solve always means "the
  reference could not solve it either", never "the fast path gave up";
* an IPM success has IPOPT's contract: scaled KKT error <= ``params.mpc.tol``, unscaled
  constraint violation <= 1e-7, then the common 1e-5 check;
* for the MPC-DC baselines (:attr:`mcverify.solver.attempts.AttemptPlan.phase1_certificates`; the
  VL-CBF controllers keep the rule above), before the fallback the C phase 1
  runs from the warm start and the cold guess; if both certify local infeasibility the certificate
  is the answer (status ``IPM_Infeasible_Problem_Detected``) and IPOPT runs only as the scheduled
  auditor (:meth:`IpmBackend.audit_due`): docs/engine.md, "The restoration phase and what
  infeasible means".

Safety of the fast path (the paper's continuous-time CBF condition at the sample). The node-0 row
of eq.tompc_cbf, hdot(x_0, u_0, t_0) + Lambda H(h(x_0, t_0)) >= 0, is affine in u_0 once x_0 and
t_0 are fixed, because the bicycle is control-affine (h depends on the state and time only, so
hdot = L_f h + L_g h u + dh/dt). The IPM sets X[:, 0] and t_0 of its starting point to the
measured state and 0 (the rows with a single constant Jacobian entry, "initial value embedding",
:class:`mcverify.solver.kkt.KktStructure`); those rows are linear, so every Newton step keeps them exact,
and the node-0 CBF row is then linear in the only variables that move it. Its residual
g - s (s the row's slack, kept strictly above 0 by the barrier) is therefore multiplied by exactly
(1 - alpha) by a step of length alpha: after the first full step (usually the first or second
iteration) the returned u_0 satisfies the CBF condition at the sample exactly, with a positive
margin, whether or not the rest of the plan has converged; and a converged plan satisfies it like
every other row. Tests: ``tests/solver/test_backends.py``.
"""

from __future__ import annotations

import dataclasses
import time
import zlib
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca
import numpy as np

from mcverify.errors import raise_noted_interrupt
from mcverify.model import BACKEND_NAMES, ModelParams
from mcverify.solver.attempts import ATTEMPTS, EASY_ATTEMPTS, AttemptPlan, attempt_plan
from mcverify.solver.cfun import CFunction
from mcverify.solver.ipm import COLD, WARM_ATTEMPTS, Ipm, IpmOptions, IpmResult
from mcverify.solver.kernels import Kernel, get_runtime_library
from mcverify.solver.status import SolveRoute, SolveStatus

#: Largest constraint or bound violation (unscaled, any unit) of a plan reported as a success.
MAX_VIOLATION = 1e-5


@dataclass(frozen=True)
class Start:
    """A primal-dual start: x (n_w,), lam_x (n_w,), lam_g (n_g,), in the layout of the NLP.

    hard_run: how many solves in a row, the one that produced it the last, were hard (:attr:`BackendResult.hard`;
    0: that one was not); read by the attempt plan's
    ``after_hard`` order (:mod:`mcverify.solver.attempts`).
    """

    x: np.ndarray
    lam_x: np.ndarray
    lam_g: np.ndarray
    hard_run: int = 0


@dataclass(frozen=True)
class BackendResult:
    """One solve: the point (w, multipliers), the backend's status, iterations and verdict.

    success: the backend's own verdict (IPOPT: a solved return status with finite output; the IPM:
    converged), then combined by :meth:`Problem.accept` with the common feasibility check.
    status: what the solver reported and which path answered (``status.fallback``: the IPM handed
    this solve to IPOPT). retried_cold: a warm IPOPT start failed and this is its cold retry.
    hard: (ipm backend) the IPM's two warm attempts did not solve it; another attempt or IPOPT answered.
    """

    w: np.ndarray
    lam_x: np.ndarray
    lam_g: np.ndarray
    status: SolveStatus
    iterations: int
    success: bool
    max_violation: float = float("nan")
    retried_cold: bool = False
    hard: bool = False


class Problem:
    """What every backend shares: bounds and a fast feasibility check on the compiled kernel.

    lbx, ubx (n_w,), lbg, ubg (n_g,): the NLP's bounds (fixed for the solver's life).
    """

    def __init__(self, kernel: Kernel, lbx, ubx, lbg, ubg) -> None:
        self.kernel = kernel
        self.lbx, self.ubx = np.asarray(lbx, float), np.asarray(ubx, float)
        self.lbg, self.ubg = np.asarray(lbg, float), np.asarray(ubg, float)
        self._g = CFunction(kernel.so_path, "nlp_g")

    @property
    def n_w(self) -> int:
        return self.lbx.size

    @property
    def n_g(self) -> int:
        return self.lbg.size

    def max_violation(self, w: np.ndarray, p: np.ndarray) -> float:
        """Largest violation of g's bounds and of w's bounds at (w, p); inf if anything is NaN."""
        w = np.asarray(w, dtype=float).ravel()
        if w.size != self.n_w or not np.all(np.isfinite(w)):
            return float("inf")
        self._g.inputs[0][:] = w
        self._g.inputs[1][:] = p
        g = self._g()[0]
        if not np.all(np.isfinite(g)):
            return float("inf")
        parts = (self.lbg - g, g - self.ubg, self.lbx - w, w - self.ubx)
        return max(0.0, *(float(np.max(v)) for v in parts))

    def min_slack(self, w: np.ndarray, p: np.ndarray, rows: np.ndarray) -> float:
        """Smallest slack g_i(w, p) - lbg_i over the inequality ``rows`` of g (negative where violated);
        NaN if w or g is not finite, +inf for no rows."""
        w = np.asarray(w, dtype=float).ravel()
        if w.size != self.n_w or not np.all(np.isfinite(w)):
            return float("nan")
        self._g.inputs[0][:] = w
        self._g.inputs[1][:] = p
        slack = self._g()[0][rows] - self.lbg[rows]
        if not np.all(np.isfinite(slack)):
            return float("nan")
        return float(np.min(slack)) if slack.size else float("inf")

    def accept(self, res: BackendResult, p: np.ndarray) -> BackendResult:
        """``res`` with max_violation filled in and success = own verdict AND finite AND feasible."""
        viol = self.max_violation(res.w, p)
        finite = bool(np.all(np.isfinite(res.lam_x)) and np.all(np.isfinite(res.lam_g)))
        ok = bool(res.success and finite and viol <= MAX_VIOLATION)
        return dataclasses.replace(res, max_violation=viol, success=ok)


# ------------------------------------------------------------------------------------------ IPOPT


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


class IpoptBackend:
    """IPOPT (MUMPS) on the compiled kernel: the reference backend."""

    name = "ipopt"

    def __init__(self, problem: Problem, params: ModelParams) -> None:
        self.problem = problem
        so = str(problem.kernel.so_path)
        self._cold = ca.nlpsol("tocbf_cold", "ipopt", so, ipopt_options(params, warm=False))
        self._warm = ca.nlpsol("tocbf_warm", "ipopt", so, ipopt_options(params, warm=True))

    def solve(
        self, p: np.ndarray, warm: Start | None, guess: Callable[[], np.ndarray], fast_only: bool = False
    ) -> BackendResult:
        """Warm from ``warm`` if given, else cold from ``guess()``; a failed warm start is retried cold.
        (``fast_only`` is ignored: the reference has no cheaper path.)

        A warm start that fails is not evidence of infeasibility: the interior point was started
        next to the previous active set (mu_init 1e-7) and, when that set changes (e.g. Q2's goal
        switches from braking behind veh_f to a lane change), IPOPT stalls or wrongly reports local
        infeasibility. Along Table II closed loops every such Q2 failure solved from the cold guess
        (40-60 iterations). The retry is counted (``retried_cold``).
        """
        if warm is not None:
            res = self.problem.accept(self.run(p, warm), p)
            if res.success:
                return res
            cold = self.problem.accept(self.run(p, None, guess), p)
            return dataclasses.replace(cold, iterations=res.iterations + cold.iterations, retried_cold=True)
        return self.problem.accept(self.run(p, None, guess), p)

    def run(self, p: np.ndarray, warm: Start | None, guess: Callable[[], np.ndarray] | None = None) -> BackendResult:
        """One IPOPT call (no feasibility check, no retry)."""
        pr = self.problem
        try:
            if warm is not None:
                out = self._warm(x0=warm.x, lam_x0=warm.lam_x, lam_g0=warm.lam_g, p=p,
                                 lbx=pr.lbx, ubx=pr.ubx, lbg=pr.lbg, ubg=pr.ubg)
                stats = self._warm.stats()
            else:
                out = self._cold(x0=guess(), p=p, lbx=pr.lbx, ubx=pr.ubx, lbg=pr.lbg, ubg=pr.ubg)
                stats = self._cold.stats()
        except Exception as exc:  # noqa: BLE001 - IPOPT/CasADi errors become a failed solve
            raise_noted_interrupt(str(exc))  # ... unless CasADi wrapped an interrupt in its error
            return _failed(pr, SolveStatus.exception(str(exc)))
        w = np.asarray(out["x"], dtype=float).ravel()
        lam_x = np.asarray(out["lam_x"], dtype=float).ravel()
        lam_g = np.asarray(out["lam_g"], dtype=float).ravel()
        if stats.get("return_status") == IPOPT_INTERRUPTED:
            raise_noted_interrupt()  # Ctrl-C / SIGTERM inside IPOPT: stop, never a failed solve
        status = SolveStatus.ipopt(str(stats.get("return_status", "unknown")))
        return BackendResult(w, lam_x, lam_g, status, int(stats.get("iter_count", -1)), status.outcome.converged)


#: IPOPT's status when CasADi caught an exception raised in its callbacks, e.g. a KeyboardInterrupt.
IPOPT_INTERRUPTED = "NonIpopt_Exception_Thrown"


def _failed(problem: Problem, status: SolveStatus) -> BackendResult:
    nan_w, nan_g = np.full(problem.n_w, np.nan), np.full(problem.n_g, np.nan)
    return BackendResult(nan_w, nan_w.copy(), nan_g, status, 0, False)


# -------------------------------------------------------------------------------------- fast path


class IpmBackend:
    """The fast path: the lean interior-point method of :mod:`mcverify.solver.ipm`, IPOPT as fallback.

    Warm starts try :data:`mcverify.solver.ipm.WARM_ATTEMPTS` in turn and then a cold start
    (:data:`mcverify.solver.ipm.COLD` from :func:`~mcverify.ocp.problem.initial_guess`); cold starts only the
    latter. Whatever the IPM does not solve goes to the IPOPT reference path (see the module
    docstring). The cold attempt after two failed warm ones: on the 26 of 652 noisy Table II warm
    solves (v_f = 25 km/h, 24 of them Q2) where both warm attempts failed, it converged in all 26,
    in 19 ms each; the IPOPT reference path took 144 ms each on the same solves.
    ``ipm_outcomes`` counts the outcome of every IPM attempt of this backend's life and
    ``ipm_cpu_s`` sums their CPU seconds (``time.process_time``) by the same tags (benchmarks and
    diagnostics only; not part of any result).
    """

    name = "ipm"

    def __init__(self, problem: Problem, params: ModelParams, kernel_dir=None, plan: AttemptPlan | None = None) -> None:
        """``plan``: the attempts (default: those of ``params.mpc.controller``'s family; tests give others)."""
        self.problem = problem
        self.reference = IpoptBackend(problem, params)
        lib = get_runtime_library("ipm", kernel_dir).so_path
        self.ipm = Ipm(problem.kernel.so_path, problem.lbx, problem.ubx, problem.lbg, problem.ubg, lib)
        self.plan = plan or attempt_plan(params.mpc)
        tol = params.mpc.tol
        self.options = {name: dataclasses.replace(opts, tol=tol) for name, (_, opts, _) in ATTEMPTS.items()}
        # the cold attempt of a full solve (not of a fast-only one: a restoration there mostly fails, at a price)
        self.cold_full = dataclasses.replace(self.options["cold"], restoration=self.plan.cold_restoration)
        self.ipm_outcomes: Counter[str] = Counter()
        self.ipm_cpu_s: Counter[str] = Counter()
        self.audit_every = params.mpc.infeasibility_audit_every
        self.phase1_warm = dataclasses.replace(WARM_ATTEMPTS[0], tol=tol, phase1=True)
        self.phase1_cold = dataclasses.replace(COLD, tol=tol, phase1=True)

    def solve(
        self, p: np.ndarray, warm: Start | None, guess: Callable[[], np.ndarray], fast_only: bool = False
    ) -> BackendResult:
        """The IPM attempts, then the IPOPT reference; ``fast_only``: no reference, a failure of the
        IPM is returned with the route :attr:`~mcverify.solver.status.SolveRoute.PRESUMED` (see
        :attr:`mcverify.model.Mpc.infeasible_recheck_steps`)."""
        iterations = 0
        for number, opts, start in self.attempts(warm, fast_only):
            x0, lx0, lg0 = (guess(), None, None) if start is None else (start.x, start.lam_x, start.lam_g)
            cpu0 = time.process_time()
            r = self.ipm.solve(p, x0, lx0, lg0, opts)
            iterations += r.iterations
            tag = f"{'cold' if start is None else 'warm'}{number}:{r.status}"
            self.ipm_outcomes[tag] += 1
            self.ipm_cpu_s[tag] += time.process_time() - cpu0
            hard = start is None or number > len(EASY_ATTEMPTS)  # not one of the two warm attempts
            res = self.problem.accept(
                BackendResult(r.w, r.lam_x, r.lam_g, SolveStatus.ipm(r.status), iterations, r.success, hard=hard), p
            )
            if res.success:
                return res
        if fast_only:
            return dataclasses.replace(res, status=res.status.via(SolveRoute.PRESUMED))
        if self.plan.phase1_certificates:
            cert = self.certify(p, warm, guess, iterations)
            if cert is not None:
                return dataclasses.replace(self.audit(p, warm, guess, cert) if self.audit_due(p) else cert, hard=True)
        ref = self.reference.solve(p, warm, guess)
        return dataclasses.replace(
            ref, status=ref.status.via(SolveRoute.FALLBACK), iterations=iterations + ref.iterations, hard=True
        )

    def attempts(self, warm: Start | None, fast_only: bool) -> list[tuple[int, IpmOptions, Start | None]]:
        """The IPM attempts of a solve in order (:attr:`plan`), as (number, options, start or None for the cold
        guess); the numbers tag the attempts in :attr:`ipm_outcomes` (:data:`mcverify.solver.attempts.ATTEMPTS`;
        the cold attempt is 1 without a warm start)."""
        names = self.plan.order(warm is not None, fast_only, warm is not None and warm.hard_run >= 1)
        out = []
        for name in names:
            number, _, from_warm = ATTEMPTS[name]
            opts = self.cold_full if name == "cold" and not fast_only else self.options[name]
            out.append((number if warm is not None else 1, opts, warm if from_warm else None))
        return out

    # ---------------------------------------------------------- phase-1 certificates (AttemptPlan)

    def certify(self, p: np.ndarray, warm: Start | None, guess: Callable[[], np.ndarray],
                iterations: int) -> BackendResult | None:
        """The start-independent certificate of infeasibility (docs/engine.md): phase 1 of the C
        restoration phase (:attr:`IpmOptions.phase1`) from the warm start, when there is one, and from
        the cold guess; a certificate only if every one of them ends with "Infeasible_Problem_Detected"
        (the cold one's point is returned). None otherwise (a feasible point or an undecided run)."""
        runs = [] if warm is None else [(self.phase1_warm, warm.x, warm.lam_x, warm.lam_g)]
        runs.append((self.phase1_cold, None, None, None))
        r: IpmResult | None = None
        for k, (opts, x0, lx0, lg0) in enumerate(runs):
            cpu0 = time.process_time()
            r = self.ipm.solve(p, guess() if x0 is None else x0, lx0, lg0, opts)
            iterations += r.iterations
            tag = f"phase1_{'warm' if lx0 is not None else 'cold'}{k + 1}:{r.status}"
            self.ipm_outcomes[tag] += 1
            self.ipm_cpu_s[tag] += time.process_time() - cpu0
            if not r.infeasible:
                return None
        return BackendResult(r.w, r.lam_x, r.lam_g, SolveStatus.ipm(r.status), iterations, False,
                             self.problem.max_violation(r.w, p))

    def audit_due(self, p: np.ndarray) -> bool:
        """Whether IPOPT re-checks this certificate: about one in ``infeasibility_audit_every``, chosen
        by a checksum of the parameter vector, so the schedule depends on the problem only (not on
        the order, chunk or worker it is solved in)."""
        return zlib.crc32(np.ascontiguousarray(p, dtype=np.float64).tobytes()) % self.audit_every == 0

    def audit(self, p: np.ndarray, warm: Start | None, guess: Callable[[], np.ndarray],
              cert: BackendResult) -> BackendResult:
        """IPOPT's full attempt (warm, then cold) on a certified problem: if it fails too, the
        certificate stands (route AUDITED); if it solves it, its solution is returned (route
        AUDIT_DISAGREED), so a disagreement never costs a solution."""
        ref = self.reference.solve(p, warm, guess)
        its = cert.iterations + ref.iterations
        if ref.success:
            return dataclasses.replace(ref, status=ref.status.via(SolveRoute.AUDIT_DISAGREED), iterations=its)
        return dataclasses.replace(cert, status=cert.status.via(SolveRoute.AUDITED), iterations=its)


#: Backend name -> implementation, one for every name of :data:`mcverify.model.BACKEND_NAMES`.
REGISTRY: dict[str, type] = {cls.name: cls for cls in (IpoptBackend, IpmBackend)}
if set(REGISTRY) != set(BACKEND_NAMES):  # a name the model accepts must have a solver (checked even under -O)
    raise ImportError(f"solver backends {sorted(REGISTRY)} do not implement BACKEND_NAMES {BACKEND_NAMES}")


def create_backend(name: str, problem: Problem, params: ModelParams, kernel_dir=None):
    """The backend called ``name`` (one of :data:`~mcverify.model.BACKEND_NAMES`); ``kernel_dir``: the kernel
    cache its compiled libraries come from (:func:`mcverify.solver.kernels.resolve_kernel_dir`)."""
    if name not in REGISTRY:
        raise ValueError(f"unknown solver backend {name!r}; valid: {', '.join(BACKEND_NAMES)}")
    if name == IpoptBackend.name:  # the reference needs only the kernel itself
        return IpoptBackend(problem, params)
    return REGISTRY[name](problem, params, kernel_dir=kernel_dir)
