"""The fast path's attempt order per controller family, as data: one place says which IPM attempts a
solve runs, in which order, and what happens when they all fail.

The ``ipm`` backend (:class:`mcverify.solver.backends.IpmBackend`) runs the attempts named here, then the
IPOPT reference. The MPC-DC baselines and the VL-CBF dual planner differ: the baselines' hard stretches
(a goal row that moves by metres with the measured veh_f speed) are answered by more IPM attempts and by the
C phase-1 certificate, while the VL-CBF controllers keep the attempts whose answers match IPOPT's on the
paper's tables. Why each family runs what it runs, with the measurements: docs/decisions.md and
docs/engine.md, "The solver path".

Attempt names and the numbers that tag them in :attr:`IpmBackend.ipm_outcomes` (whatever their order):

* ``warm1``, ``warm2``: :data:`mcverify.solver.ipm.WARM_ATTEMPTS` from the warm start (numbers 1, 2);
* ``cold``: :data:`mcverify.solver.ipm.COLD` from the cold guess (number 3; 1 when there is no warm start);
* ``central``: :data:`mcverify.solver.ipm.CENTRAL_WARM`, the warm start at mu 1e-2 (number 4);
* ``retry``: :data:`mcverify.solver.ipm.CENTRAL_RETRY`, the warm start at mu 3e-2 (number 5);
* ``lower_mu``: :data:`mcverify.solver.ipm.AFTER_HARD_WARM`, the warm start at mu 3e-3 (number 6).

A solve answered by anything but ``warm1`` or ``warm2`` is *hard*
(:attr:`mcverify.solver.backends.BackendResult.hard`).
"""

from __future__ import annotations

from dataclasses import dataclass

from mcverify.model import Mpc
from mcverify.solver.ipm import AFTER_HARD_WARM, CENTRAL_RETRY, CENTRAL_WARM, COLD, WARM_ATTEMPTS, IpmOptions

#: Attempt name -> (number in the outcome tags, IPM options, runs from the warm start).
ATTEMPTS: dict[str, tuple[int, IpmOptions, bool]] = {
    "warm1": (1, WARM_ATTEMPTS[0], True),
    "warm2": (2, WARM_ATTEMPTS[1], True),
    "cold": (3, COLD, False),
    "central": (4, CENTRAL_WARM, True),
    "retry": (5, CENTRAL_RETRY, True),
    "lower_mu": (6, AFTER_HARD_WARM, True),
}
#: A solve answered by one of these was not hard.
EASY_ATTEMPTS = ("warm1", "warm2")
#: What every family runs when the solve is fast-path only (a presumed-infeasible problem, an unread Q2): the
#: warm attempts and the cold one, never the restoration phase.
FAST_ONLY_ORDER = ("warm1", "warm2", "cold")


@dataclass(frozen=True)
class AttemptPlan:
    """The ipm backend's attempts for one controller family.

    usual: the attempts of a full warm-started solve, in order, before IPOPT.
    after_hard: the order instead when the previous solve of the same problem was hard (None: ``usual``).
    cold_restoration: the cold attempt of a full solve (not of a fast-only one) runs the C restoration phase
      after a failed line search instead of ending.
    phase1_certificates: once every attempt failed, the C phase 1 from the warm start and the cold guess may
      certify the problem infeasible (IPOPT then only audits about one certificate in
      ``mpc.infeasibility_audit_every``); False: IPOPT alone certifies.
    """

    family: str
    usual: tuple[str, ...]
    after_hard: tuple[str, ...] | None
    cold_restoration: bool
    phase1_certificates: bool

    def order(self, warm: bool, fast_only: bool, after_hard: bool) -> tuple[str, ...]:
        """The attempt names of one solve: ``warm`` (a warm start exists), ``fast_only`` (no IPOPT after),
        ``after_hard`` (the previous solve of this problem was hard)."""
        if not warm:
            return ("cold",)
        if fast_only:
            return FAST_ONLY_ORDER
        return self.after_hard if after_hard and self.after_hard is not None else self.usual


#: The MPC-DC baselines ("mpcdc", "mpcdc_eps").
MPCDC_PLAN = AttemptPlan(
    family="mpcdc",
    usual=("warm1", "warm2", "cold", "central", "retry"),
    after_hard=("lower_mu", "warm1", "warm2", "cold", "retry"),
    cold_restoration=True,
    phase1_certificates=True,
)
#: The VL-CBF dual planner ("vlcbf").
VLCBF_PLAN = AttemptPlan(
    family="vlcbf",
    usual=("warm1", "warm2", "cold"),
    after_hard=None,
    cold_restoration=False,
    phase1_certificates=False,
)


def attempt_plan(mpc: Mpc) -> AttemptPlan:
    """The attempt plan of the controller ``mpc.controller``."""
    return MPCDC_PLAN if mpc.is_mpcdc else VLCBF_PLAN
