"""The fast path's attempt order per controller family (mcverify.solver.attempts), as the ipm backend runs it.

The orders are data; the backend tests run them on the VL-CBF kernel with every IPM attempt failing, giving the
backend the MPC-DC plan where the baselines' attempts are tested (the kernel does not change the order)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_backends import EGO, LEVEL, P_IPM, attempt_starts

from mcverify.model import Mpc
from mcverify.solver import attempts, backends
from mcverify.solver.attempts import MPCDC_PLAN, VLCBF_PLAN, attempt_plan
from mcverify.solver.ipm import AFTER_HARD_WARM, CENTRAL_RETRY, CENTRAL_WARM, COLD, WARM_ATTEMPTS
from mcverify.solver.mpc import MpcSolver, WarmStart

FRONT = np.array([64.0, 0.0, 25.0 / 3.6])
WARM1, WARM2 = (WARM_ATTEMPTS[0].mu_init, True), (WARM_ATTEMPTS[1].mu_init, True)
COLD_RUN = (COLD.mu_init, False)


@pytest.mark.parametrize(("controller", "plan"), [("vlcbf", VLCBF_PLAN), ("mpcdc", MPCDC_PLAN),
                                                  ("mpcdc_eps", MPCDC_PLAN)])
def test_each_controller_has_its_family_plan(controller, plan):
    assert attempt_plan(Mpc(controller=controller)) is plan


def test_the_orders_as_data():
    assert VLCBF_PLAN.order(warm=True, fast_only=False, after_hard=True) == ("warm1", "warm2", "cold")
    assert MPCDC_PLAN.order(True, False, False) == ("warm1", "warm2", "cold", "central", "retry")
    assert MPCDC_PLAN.order(True, False, True) == ("lower_mu", "warm1", "warm2", "cold", "retry")
    for plan in (VLCBF_PLAN, MPCDC_PLAN):
        assert plan.order(True, True, True) == attempts.FAST_ONLY_ORDER == ("warm1", "warm2", "cold")
        assert plan.order(False, False, True) == ("cold",)
    assert MPCDC_PLAN.cold_restoration and MPCDC_PLAN.phase1_certificates
    assert not (VLCBF_PLAN.cold_restoration or VLCBF_PLAN.phase1_certificates)


def _solver(plan) -> MpcSolver:
    solver = MpcSolver(P_IPM)
    solver.backend = backends.IpmBackend(solver.problem, P_IPM, plan=plan)
    return solver


def test_the_vlcbf_attempts_then_ipopt(monkeypatch):
    solver = _solver(VLCBF_PLAN)
    warm = solver.solve(EGO, FRONT, 1, LEVEL)
    assert warm.success
    assert attempt_starts(solver, warm.warm, monkeypatch) == [WARM1, WARM2, COLD_RUN]
    hard = dataclasses.replace(warm.warm, hard_run=3)  # no other order after a hard solve
    assert attempt_starts(solver, hard, monkeypatch) == [WARM1, WARM2, COLD_RUN]
    assert not solver.backend.cold_full.restoration


def test_the_mpcdc_attempts_in_a_full_and_a_fast_only_solve(monkeypatch):
    solver = _solver(MPCDC_PLAN)
    warm = dataclasses.replace(solver.solve(EGO, FRONT, 1, LEVEL).warm, hard_run=0)  # (the cold solve was hard)
    central, retry = (CENTRAL_WARM.mu_init, True), (CENTRAL_RETRY.mu_init, True)
    phase1 = (WARM_ATTEMPTS[0].mu_init, True)  # then phase 1 from the warm start: no certificate, IPOPT answers
    assert attempt_starts(solver, warm, monkeypatch) == [WARM1, WARM2, COLD_RUN, central, retry, phase1]
    assert solver.backend.ipm_outcomes["warm4:Line_Search_Failed"] == 1  # the tags keep their numbers
    assert solver.backend.ipm_outcomes["warm5:Line_Search_Failed"] == 1
    assert attempt_starts(solver, warm, monkeypatch, fast_only=True) == [WARM1, WARM2, COLD_RUN]
    assert solver.backend.cold_full.restoration and not solver.backend.options["cold"].restoration


def test_after_a_hard_mpcdc_solve_the_lower_mu_attempt_leads(monkeypatch):
    solver = _solver(MPCDC_PLAN)
    warm = solver.solve(EGO, FRONT, 1, LEVEL)
    hard: WarmStart = dataclasses.replace(warm.warm, hard_run=1)
    lower_mu, retry = (AFTER_HARD_WARM.mu_init, True), (CENTRAL_RETRY.mu_init, True)
    phase1 = (WARM_ATTEMPTS[0].mu_init, True)
    assert attempt_starts(solver, hard, monkeypatch) == [lower_mu, WARM1, WARM2, COLD_RUN, retry, phase1]
    assert solver.backend.ipm_outcomes["warm6:Line_Search_Failed"] == 1


def test_every_attempt_has_the_cells_tolerance():
    mpc = dataclasses.replace(P_IPM.mpc, tol=1e-5)
    solver = MpcSolver(dataclasses.replace(P_IPM, mpc=mpc))
    backend = solver.backend
    assert all(o.tol == 1e-5 for o in (*backend.options.values(), backend.cold_full, backend.phase1_warm,
                                       backend.phase1_cold))
