"""Phase-1 certificates (the MPC-DC attempt plan): the C phase-1 certificate from every start, IPOPT as scheduled
auditor.

On the VL-CBF problem with a front vehicle too fast to overtake (19 / 18 m/s against the ego's
limit), the VL-CBF plan hands the failed solve to IPOPT; a plan with phase-1 certificates certifies it in C
from the cold guess, calls IPOPT only when the audit schedule picks the problem, and counts audits and
disagreements (a disagreement returns IPOPT's solution).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_backends import EGO, LEVEL, P_IPM

from mcverify.campaign import spec as campaign
from mcverify.control.episode_state import EpisodeState
from mcverify.solver import backends
from mcverify.solver.attempts import MPCDC_PLAN
from mcverify.solver.mpc import MpcSolver
from mcverify.solver.status import SolveOutcome, SolveRoute, SolveStatus

INFEASIBLE_FRONT = np.array([64.0, 0.0, 18.0])  # no overtake within the horizon


def _phase1(every: int) -> MpcSolver:
    params = dataclasses.replace(P_IPM, mpc=dataclasses.replace(P_IPM.mpc, infeasibility_audit_every=every))
    solver = MpcSolver(params)
    solver.backend = backends.IpmBackend(solver.problem, params, plan=MPCDC_PLAN)
    return solver


def test_phase1_certificate_without_ipopt(monkeypatch):
    solver = _phase1(2**31 - 1)
    monkeypatch.setattr(solver.backend, "audit_due", lambda p: False)
    monkeypatch.setattr(solver.backend.reference, "solve", lambda *a, **k: pytest.fail("IPOPT was called"))
    sol = solver.solve(EGO, INFEASIBLE_FRONT, 1, LEVEL)
    assert not sol.success and str(sol.status) == "IPM_Infeasible_Problem_Detected"
    assert sol.status.outcome is SolveOutcome.INFEASIBLE and sol.status.certified_infeasible
    assert not sol.status.audited and not sol.status.fallback
    assert solver.backend.ipm_outcomes["phase1_cold1:Infeasible_Problem_Detected"] == 1  # no warm start: cold only


def test_audited_certificate_where_ipopt_fails_too():
    solver = _phase1(1)  # every certificate audited
    sol = solver.solve(EGO, INFEASIBLE_FRONT, 1, LEVEL)
    assert not sol.success and str(sol.status) == "audited:IPM_Infeasible_Problem_Detected"
    assert sol.status.audited and not sol.status.audit_disagreed and sol.status.certified_infeasible


def test_disagreement_returns_ipopts_solution(monkeypatch):
    """A stand-in IPOPT that solves what phase 1 certified: its result is returned, marked."""
    solver = _phase1(1)
    n_w, n_g = solver.problem.n_w, solver.problem.n_g
    solved = backends.BackendResult(np.full(n_w, 0.5), np.zeros(n_w), np.zeros(n_g),
                                    SolveStatus.ipopt("Solve_Succeeded"), 7, True, 0.0)
    monkeypatch.setattr(solver.backend.reference, "solve", lambda *a, **k: solved)
    sol = solver.solve(EGO, INFEASIBLE_FRONT, 1, LEVEL)
    assert sol.success and str(sol.status) == "audit_disagreed:Solve_Succeeded"
    assert sol.status.audited and sol.status.audit_disagreed and not sol.status.certified_infeasible


def test_audit_schedule_depends_on_the_problem_only():
    backend = _phase1(10).backend
    rng = np.random.default_rng(7)
    ps = rng.normal(size=(3000, 8))
    due = np.array([backend.audit_due(p) for p in ps])
    assert np.array_equal(due, [backend.audit_due(p.copy()) for p in ps])  # same p, same answer
    assert 0.08 <= due.mean() <= 0.12  # about one in ten (binomial sd 0.005)


def test_the_vlcbf_controllers_leave_infeasibility_to_ipopt_and_run_no_phase1():
    solver = MpcSolver(P_IPM)
    assert P_IPM.mpc.controller == "vlcbf" and not solver.backend.plan.phase1_certificates
    sol = solver.solve(EGO, INFEASIBLE_FRONT, 1, LEVEL)
    assert sol.status.fallback and not any(t.startswith("phase1") for t in solver.backend.ipm_outcomes)


def test_planner_counts_audits_and_disagreements():
    stats = EpisodeState(0)
    for route in (SolveRoute.AUDITED, SolveRoute.AUDIT_DISAGREED, SolveRoute.PRIMARY):
        sol = type("Sol", (), {"iterations": 1, "solve_time_s": 0.0, "retried_cold": False,
                               "status": SolveStatus.ipm("Infeasible_Problem_Detected").via(route)})()
        stats.record_solve(sol)
    assert (stats.infeasibility_audits, stats.infeasibility_audit_disagreements) == (2, 1)


def test_campaign_rejects_a_bad_audit_period_and_a_deleted_policy():
    raw = {"campaign": {"name": "t", "seed": 1, "episodes": 1}, "model": {"mpc": {"infeasibility_audit_every": 0}}}
    with pytest.raises(campaign.CampaignError, match="mpc.infeasibility_audit_every: must be an integer >= 1"):
        campaign.campaign_from_dict(raw)
    raw["model"]["mpc"] = {"infeasibility_audit_every": 3}
    assert campaign.campaign_from_dict(raw).cells[0].params.mpc.infeasibility_audit_every == 3
    for deleted in ("infeasibility", "ipm_restoration", "kkt_factorization", "q2_stoppable"):
        raw["model"]["mpc"] = {deleted: "off"}
        with pytest.raises(campaign.CampaignError, match=f"unknown model field 'mpc.{deleted}'"):
            campaign.campaign_from_dict(raw)


def test_the_restoration_phase_runs_in_the_full_cold_attempt_only(monkeypatch):
    solver = MpcSolver(P_IPM)
    backend = backends.IpmBackend(solver.problem, P_IPM, plan=MPCDC_PLAN)
    solver.backend = backend
    assert backend.cold_full.restoration and not any(o.restoration for o in backend.options.values())
    default = MpcSolver(P_IPM).backend
    assert not any(o.restoration for o in (*default.options.values(), default.cold_full))
    seen = []
    real = backend.ipm.solve
    monkeypatch.setattr(backend.ipm, "solve", lambda *a: seen.append(a[-1].restoration) or real(*a))
    monkeypatch.setattr(backend, "certify", lambda *a: None)
    solver.solve(EGO, INFEASIBLE_FRONT, 1, LEVEL, fast_only=True)
    solver.solve(EGO, INFEASIBLE_FRONT, 1, LEVEL)
    assert seen == [False, True]  # presumed: the plain cold attempt; full: with the restoration phase
