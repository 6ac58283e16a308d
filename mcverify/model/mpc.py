"""The TO-CBF-MPC settings (:class:`Mpc`) and the names its fields accept."""

from __future__ import annotations

from dataclasses import dataclass

#: The valid values of ``Mpc.backend`` (implemented by :mod:`mcverify.solver.backends`).
BACKEND_NAMES = ("ipopt", "ipm")
#: The MPC-DC baselines (Sec. VI-D): "mpcdc" keeps the ellipses at the nodes (h >= 0), "mpcdc_eps"
#: at the level of the cell (h >= barrier.epsilon); everything else about them is the same.
MPCDC_CONTROLLERS = ("mpcdc", "mpcdc_eps")
#: The controllers that keep no level ε of h_ef: plain MPC-DC keeps the ellipse itself (h >= 0 at the
#: nodes), so a figure draws no ε line for it.
CONTROLLERS_WITHOUT_LEVEL = ("mpcdc",)


def kept_level(controller: str | None, epsilon: float) -> float | None:
    """The level of h_ef that ``controller`` keeps: the cell's ε, or None for plain MPC-DC (h >= 0)."""
    return None if controller in CONTROLLERS_WITHOUT_LEVEL else float(epsilon)


#: The evidence that makes the ego abandon the overtake (:attr:`Mpc.abandon_rule`).
ABANDON_RULES = ("first_failure", "consecutive", "certified")
#: When the dual planner solves Q2 while overtaking (:attr:`Mpc.q2_solve`).
Q2_SOLVE_POLICIES = ("every_step", "fast_when_unneeded", "when_needed")


@dataclass(frozen=True)
class Mpc:
    """TO-CBF-MPC settings (box eq.tompc): the controller, its optimal-control problem, and (last) the
    solver's tuning.

    Paper: N = 50, phi = 1.8 s (x_g = x_f + phi v_f). Named defaults: ``dt_max_s`` (eq.tompc_t; 0.3 s gives a
    15 s horizon, enough for the slowest Table II overtake), ``dt_min_s`` (the paper's "maximum time
    resolution"), ``eps_y_m`` (eq.tompc_y) and a small input-smoothing weight (allowed by the Remark after
    eq.tompc; it does not touch the safety constraints and makes the time-optimal problem well conditioned).
    ``abandon_rule`` reads Sec. IV's "whenever the feasibility of Q1 is being challenged, we merge back" three
    ways; while it waits, the ego follows its last Q1 plan (``q1_held_steps``). The ``ipm`` backend's attempts
    per controller family are data (:mod:`mcverify.solver.attempts`), not options: docs/decisions.md.
    """

    controller: str = "vlcbf"
    """vlcbf (the paper's dual TO-CBF-MPC), mpcdc (the Sec. VI-D baseline: distance constraints at the nodes, no
    Q2) or mpcdc_eps (the baseline at the level epsilon, h >= barrier.epsilon)."""
    horizon: int = 50
    """Number of MPC stages N. Valid: 2-500. Paper: 50."""
    dt_max_s: float = 0.3
    """Upper bound of every stage interval (eq.tompc_t). Valid: > dt_min_s. Paper: not given."""
    dt_min_s: float = 1e-4
    """Lower bound of every stage interval. Valid: > 0. Paper: 1e-4 (its time resolution)."""
    phi_s: float = 1.8
    """Goal reaction time phi: x_g = x_f + v_f T +- phi v_f. Valid: >= 0. Paper: 1.8."""
    eps_y_m: float = 0.25
    """Lateral goal tolerance epsilon_y (eq.tompc_y). Valid: > 0. Paper: not given."""
    smooth_weight: float = 1e-3
    """Weight of the input-smoothing term. Valid: >= 0. Paper: allowed by its Remark, no value."""
    abandon_rule: str = "first_failure"
    """What abandons the overtake: first_failure (Algorithm 1 literally: the first failed Q1 solve), consecutive
    (abandon_after_failures failed Q1 solves in a row) or certified (only a Q1 failure certified infeasible)."""
    abandon_after_failures: int = 3
    """Failed Q1 solves in a row that abandon with abandon_rule = consecutive. Valid: >= 1."""
    q2_solve: str = "every_step"
    """How Q2 is solved at the steps whose decision does not read it: every_step (Algorithm 1: in full),
    fast_when_unneeded (the fast path only) or when_needed (not at all)."""

    # ---- solver tuning: how the NLP is solved, not which NLP ----
    backend: str = "ipm"
    """NLP solver: ipm (the fast path, IPOPT as fallback) or ipopt (the reference)."""
    max_iter: int = 150
    """Solver iterations of a warm-started solve. Valid: >= 1."""
    max_iter_cold: int = 400
    """Solver iterations of a cold solve. Valid: >= 1."""
    tol: float = 1e-6
    """Solver tolerance on the scaled KKT error. Valid: > 0."""
    infeasible_recheck_steps: int = 10
    """After IPOPT certifies a VL-CBF problem infeasible, steps the fast path alone tries it (presumed infeasible
    when it fails) before IPOPT tries it in full again (1: every step); docs/decisions.md. Valid: >= 1."""
    infeasible_recheck_max_steps: int = 50
    """Largest wait of the doubling recheck period. Valid: >= infeasible_recheck_steps."""
    infeasibility_audit_every: int = 10
    """Where the C phase 1 certifies infeasibility (the MPC-DC baselines on the ipm backend): about one certificate
    in this many is re-checked by IPOPT (1: every one). Valid: >= 1."""

    @property
    def is_mpcdc(self) -> bool:
        """An MPC-DC baseline (:data:`MPCDC_CONTROLLERS`): distance constraints, no Q2."""
        return self.controller in MPCDC_CONTROLLERS
