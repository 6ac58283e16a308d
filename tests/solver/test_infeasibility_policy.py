"""``mpc.infeasibility = "phase1"``: the C phase-1 certificate from every start, IPOPT as scheduled auditor.

On the VL-CBF problem with a front vehicle too fast to overtake (19 / 18 m/s against the ego's
limit), the default policy hands the failed solve to IPOPT; "phase1" certifies it in C from the
cold guess, calls IPOPT only when the audit schedule picks the problem, and counts audits and
disagreements (a disagreement returns IPOPT's solution).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_backends import EGO, LAMBDA0, P_IPM

from mcverify.campaign import spec as campaign
from mcverify.control.planner import EpisodeState
from mcverify.solver import backends
from mcverify.solver.mpc import MpcSolver
from mcverify.solver.status import SolveOutcome, SolveRoute, SolveStatus

INFEASIBLE_FRONT = np.array([64.0, 0.0, 18.0])  # no overtake within the horizon


def _phase1(every: int) -> MpcSolver:
    mpc = dataclasses.replace(P_IPM.mpc, infeasibility="phase1", infeasibility_audit_every=every)
    return MpcSolver(dataclasses.replace(P_IPM, mpc=mpc))


def test_phase1_certificate_without_ipopt(monkeypatch):
    solver = _phase1(2**31 - 1)
    monkeypatch.setattr(solver.backend, "audit_due", lambda p: False)
    monkeypatch.setattr(solver.backend.reference, "solve", lambda *a, **k: pytest.fail("IPOPT was called"))
    sol = solver.solve(EGO, INFEASIBLE_FRONT, 1, LAMBDA0)
    assert not sol.success and str(sol.status) == "IPM_Infeasible_Problem_Detected"
    assert sol.status.outcome is SolveOutcome.INFEASIBLE and sol.status.certified_infeasible
    assert not sol.status.audited and not sol.status.fallback
    assert solver.backend.ipm_outcomes["phase1_cold1:Infeasible_Problem_Detected"] == 1  # no warm start: cold only


def test_audited_certificate_where_ipopt_fails_too():
    solver = _phase1(1)  # every certificate audited
    sol = solver.solve(EGO, INFEASIBLE_FRONT, 1, LAMBDA0)
    assert not sol.success and str(sol.status) == "audited:IPM_Infeasible_Problem_Detected"
    assert sol.status.audited and not sol.status.audit_disagreed and sol.status.certified_infeasible


def test_disagreement_returns_ipopts_solution(monkeypatch):
    """A stand-in IPOPT that solves what phase 1 certified: its result is returned, marked."""
    solver = _phase1(1)
    n_w, n_g = solver.problem.n_w, solver.problem.n_g
    solved = backends.BackendResult(np.full(n_w, 0.5), np.zeros(n_w), np.zeros(n_g),
                                    SolveStatus.ipopt("Solve_Succeeded"), 7, True, 0.0)
    monkeypatch.setattr(solver.backend.reference, "solve", lambda *a, **k: solved)
    sol = solver.solve(EGO, INFEASIBLE_FRONT, 1, LAMBDA0)
    assert sol.success and str(sol.status) == "audit_disagreed:Solve_Succeeded"
    assert sol.status.audited and sol.status.audit_disagreed and not sol.status.certified_infeasible


def test_audit_schedule_depends_on_the_problem_only():
    backend = _phase1(10).backend
    rng = np.random.default_rng(7)
    ps = rng.normal(size=(3000, 8))
    due = np.array([backend.audit_due(p) for p in ps])
    assert np.array_equal(due, [backend.audit_due(p.copy()) for p in ps])  # same p, same answer
    assert 0.08 <= due.mean() <= 0.12  # about one in ten (binomial sd 0.005)


def test_default_policy_is_ipopt_for_the_vlcbf_controllers_and_runs_no_phase1():
    solver = MpcSolver(P_IPM)
    assert P_IPM.mpc.infeasibility == "phase1_mpcdc" and P_IPM.mpc.controller == "vlcbf"  # the default since 2026-11-28
    sol = solver.solve(EGO, INFEASIBLE_FRONT, 1, LAMBDA0)
    assert sol.status.fallback and not any(t.startswith("phase1") for t in solver.backend.ipm_outcomes)


def test_planner_counts_audits_and_disagreements():
    stats = EpisodeState(0)
    for route in (SolveRoute.AUDITED, SolveRoute.AUDIT_DISAGREED, SolveRoute.PRIMARY):
        sol = type("Sol", (), {"iterations": 1, "solve_time_s": 0.0, "retried_cold": False,
                               "status": SolveStatus.ipm("Infeasible_Problem_Detected").via(route)})()
        stats.record_solve(sol)
    assert (stats.infeasibility_audits, stats.infeasibility_audit_disagreements) == (2, 1)


@pytest.mark.parametrize(("key", "value", "match"), [
    ("infeasibility", "ask", "unknown policy 'ask'"), ("infeasibility_audit_every", 0, "must be an integer >= 1")])
def test_campaign_rejects_a_bad_policy(key, value, match):
    raw = {"campaign": {"name": "t", "seed": 1, "episodes": 1}, "model": {"mpc": {key: value}}}
    with pytest.raises(campaign.CampaignError, match=match):
        campaign.campaign_from_dict(raw)
    raw["model"]["mpc"] = {"infeasibility": "phase1", "infeasibility_audit_every": 3}
    assert campaign.campaign_from_dict(raw).cells[0].params.mpc.infeasibility == "phase1"
    assert backends.REGISTRY["ipm"] is backends.IpmBackend


def test_ipm_restoration_turns_on_the_restoration_phase_in_the_full_cold_attempt(monkeypatch):
    on = dataclasses.replace(P_IPM, mpc=dataclasses.replace(P_IPM.mpc, ipm_restoration="all"))
    backend = MpcSolver(on).backend
    assert backend.cold_full.restoration and not any(o.restoration for o in (*backend.warm_attempts, backend.cold))
    default = MpcSolver(P_IPM).backend
    assert not any(o.restoration for o in (*default.warm_attempts, default.cold, default.cold_full))
    seen = []
    real = backend.ipm.solve
    monkeypatch.setattr(backend.ipm, "solve", lambda *a: seen.append(a[-1].restoration) or real(*a))
    solver = MpcSolver(on)
    solver.backend = backend
    solver.solve(EGO, INFEASIBLE_FRONT, 1, LAMBDA0, fast_only=True)
    solver.solve(EGO, INFEASIBLE_FRONT, 1, LAMBDA0)
    assert seen == [False, True]  # presumed: the plain cold attempt; full: with the restoration phase
    raw = {"campaign": {"name": "t", "seed": 1, "episodes": 1}, "model": {"mpc": {"ipm_restoration": "yes"}}}
    with pytest.raises(campaign.CampaignError, match="mpc.ipm_restoration: unknown policy 'yes'; valid: off, mpcdc"):
        campaign.campaign_from_dict(raw)


@pytest.mark.parametrize(("value", "policy"), [(True, "all"), (False, "off"), ("mpcdc", "mpcdc")])
def test_ipm_restoration_reads_its_old_true_false_as_policies(value, policy):
    """Runs stored before the field took policies wrote true/false; they read as all/off."""
    raw = {"campaign": {"name": "t", "seed": 1, "episodes": 1}, "model": {"mpc": {"ipm_restoration": value}}}
    assert campaign.campaign_from_dict(raw).cells[0].params.mpc.ipm_restoration == policy


def test_ipm_restoration_mpcdc_reaches_the_baselines_only():
    for controller, restored in (("mpcdc", True), ("mpcdc_eps", True), ("vlcbf", False)):
        mpc = dataclasses.replace(P_IPM.mpc, ipm_restoration="mpcdc", controller=controller)
        assert backends.uses_restoration(mpc) is restored, controller


def test_kkt_factorization_reaches_every_ipm_run_and_is_validated():
    on = dataclasses.replace(P_IPM, mpc=dataclasses.replace(P_IPM.mpc, kkt_factorization="ldlt"))
    backend = MpcSolver(on).backend
    runs = (*backend.warm_attempts, backend.cold, backend.cold_full, backend.phase1_warm, backend.phase1_cold)
    assert all(o.kkt_factorisation == "ldlt" for o in runs)
    default = MpcSolver(P_IPM).backend
    assert all(o.kkt_factorisation == "lu" for o in (*default.warm_attempts, default.cold, default.cold_full))
    plan = MpcSolver(on).solve(EGO, INFEASIBLE_FRONT, 1, LAMBDA0)
    assert plan is not None
    raw = {"campaign": {"name": "t", "seed": 1, "episodes": 1}, "model": {"mpc": {"kkt_factorization": "qr"}}}
    with pytest.raises(campaign.CampaignError, match="mpc.kkt_factorization: unknown factorization"):
        campaign.campaign_from_dict(raw)
