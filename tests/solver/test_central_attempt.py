"""``mpc.ipm_central_attempt``: the warm start once more at a central barrier parameter, after the
two warm attempts and the cold one failed and before IPOPT; only for the controllers the policy
names, never for a presumed-infeasible (fast-only) solve; validated like the other policies."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_backends import EGO, LAMBDA0, P_IPM, attempt_starts

from mcverify.campaign import spec as campaign
from mcverify.model import Mpc
from mcverify.solver import backends
from mcverify.solver.ipm import CENTRAL_WARM, IpmResult
from mcverify.solver.mpc import MpcSolver

FRONT = np.array([64.0, 0.0, 25.0 / 3.6])


@pytest.mark.parametrize(("policy", "controller", "used"), [
    ("off", "vlcbf", False), ("off", "mpcdc", False), ("mpcdc", "vlcbf", False), ("mpcdc", "mpcdc", True),
    ("mpcdc", "mpcdc_eps", True), ("all", "vlcbf", True), ("all", "mpcdc", True)])
def test_the_policy_names_the_controllers(policy, controller, used):
    assert backends.uses_central_attempt(Mpc(controller=controller, ipm_central_attempt=policy)) is used
    assert Mpc().ipm_central_attempt == "mpcdc"  # the default since 2026-11-26 (MPC-DC only)


def _attempts(solver: MpcSolver, monkeypatch) -> list[tuple[float, bool]]:
    """(mu_init, warm) of every IPM run of one warm-started full solve whose IPM attempts all fail."""
    warm = solver.solve(EGO, FRONT, 1, LAMBDA0)
    assert warm.success
    return attempt_starts(solver, warm.warm, monkeypatch)


def test_the_central_attempt_comes_after_the_cold_one_and_only_in_a_full_solve(monkeypatch):
    on = MpcSolver(dataclasses.replace(P_IPM, mpc=dataclasses.replace(P_IPM.mpc, ipm_central_attempt="all")))
    assert on.backend.central == dataclasses.replace(CENTRAL_WARM, tol=P_IPM.mpc.tol)
    full = _attempts(on, monkeypatch)
    assert full == [(1e-7, True), (1e-5, True), (0.1, False), (CENTRAL_WARM.mu_init, True)]
    assert on.backend.ipm_outcomes["warm4:Line_Search_Failed"] == 1
    off = MpcSolver(dataclasses.replace(P_IPM, mpc=dataclasses.replace(P_IPM.mpc, ipm_central_attempt="mpcdc")))
    assert off.backend.central is None  # mpcdc: the MPC-DC baselines only
    assert _attempts(off, monkeypatch) == full[:3]


def test_a_presumed_infeasible_solve_gets_no_central_attempt(monkeypatch):
    on = MpcSolver(dataclasses.replace(P_IPM, mpc=dataclasses.replace(P_IPM.mpc, ipm_central_attempt="all")))
    warm = on.solve(EGO, FRONT, 1, LAMBDA0)
    backend = on.backend
    failed = IpmResult(np.zeros(on.layout.n_w), np.zeros(on.layout.n_w), np.zeros(on.layout.n_g),
                       False, "Line_Search_Failed", 30, 30, 0, 0, 0, 1.0, 1.0)
    seen = []
    monkeypatch.setattr(backend.ipm, "solve", lambda p, w0, lx, lg, o: seen.append(o.mu_init) or failed)
    monkeypatch.setattr(backend.reference, "solve", lambda *a, **k: pytest.fail("IPOPT was called"))
    sol = on.solve(EGO, FRONT, 1, LAMBDA0, warm=warm.warm, fast_only=True)
    assert not sol.success and seen == [1e-7, 1e-5, 0.1]


def test_a_bad_policy_is_one_line():
    raw = {"campaign": {"name": "t", "seed": 1, "episodes": 1}, "model": {"mpc": {"ipm_central_attempt": "some"}}}
    with pytest.raises(campaign.CampaignError, match="mpc.ipm_central_attempt: unknown policy 'some'"):
        campaign.campaign_from_dict(raw)
    raw["model"]["mpc"] = {"ipm_central_attempt": "mpcdc", "controller": "mpcdc"}
    assert campaign.campaign_from_dict(raw).cells[0].params.mpc.ipm_central_attempt == "mpcdc"
