"""``mpc.ipm_central_first``: after a hard solve (the two warm IPM attempts failed and another attempt or
IPOPT answered), the next full solve of the same problem starts with the central warm attempt; the
flag travels with the warm start (per episode, so chunking and workers cannot change it); only the
controllers the policy names; never in a presumed-infeasible (fast-only) solve."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_backends import EGO, LAMBDA0, P_IPM, attempt_starts

from mcverify.campaign import spec as campaign
from mcverify.model import Mpc
from mcverify.solver import backends
from mcverify.solver.ipm import CENTRAL_WARM
from mcverify.solver.mpc import MpcSolver, WarmStart

FRONT = np.array([64.0, 0.0, 25.0 / 3.6])
#: The VL-CBF controller without the central attempt at the end (ipm_central_attempt = mpcdc), so that a failed
#: solve's attempts are the two warm ones and the cold one.
P_NO_CENTRAL = dataclasses.replace(P_IPM, mpc=dataclasses.replace(P_IPM.mpc, ipm_central_attempt="mpcdc"))


@pytest.mark.parametrize(("policy", "controller", "used"), [
    ("off", "vlcbf", False), ("off", "mpcdc", False), ("mpcdc", "vlcbf", False), ("mpcdc", "mpcdc", True),
    ("mpcdc", "mpcdc_eps", True), ("all", "vlcbf", True)])
def test_the_policy_names_the_controllers(policy, controller, used):
    assert backends.uses_central_first(Mpc(controller=controller, ipm_central_first=policy)) is used
    assert Mpc().ipm_central_first == "mpcdc"  # the default since 2026-11-28 (MPC-DC only)


def _solver(policy: str = "all") -> MpcSolver:
    return MpcSolver(dataclasses.replace(P_IPM, mpc=dataclasses.replace(P_NO_CENTRAL.mpc, ipm_central_first=policy,
                                                                        ipm_after_hard_attempt="central",
                                                                        ipm_after_hard_solves=1)))


def _mu_inits(solver: MpcSolver, warm: WarmStart, monkeypatch, fast_only: bool = False) -> list[tuple[float, bool]]:
    return attempt_starts(solver, warm, monkeypatch, fast_only)


def test_a_solve_after_a_hard_one_starts_with_the_central_attempt(monkeypatch):
    on = _solver()
    cold = on.solve(EGO, FRONT, 1, LAMBDA0)  # no warm start: the cold attempt answers, a hard solve
    assert cold.success and cold.warm.hard_run == 1
    easy = on.solve(EGO, FRONT, 1, LAMBDA0, warm=dataclasses.replace(cold.warm, hard_run=0))
    assert easy.success and easy.warm.hard_run == 0  # warm attempt 1 solves the same problem again
    usual = [(1e-7, True), (1e-5, True), (0.1, False)]
    assert _mu_inits(on, easy.warm, monkeypatch) == usual
    assert _mu_inits(on, cold.warm, monkeypatch) == [(CENTRAL_WARM.mu_init, True), *usual]
    assert on.backend.ipm_outcomes["warm4:Line_Search_Failed"] == 1  # the central attempt keeps its name
    assert _mu_inits(on, cold.warm, monkeypatch, fast_only=True) == usual  # a presumed solve: never
    assert _mu_inits(_solver("off"), cold.warm, monkeypatch) == usual


def test_a_solve_the_central_attempt_answers_stays_hard():
    on = _solver()
    cold = on.solve(EGO, FRONT, 1, LAMBDA0)
    again = on.solve(EGO, FRONT, 1, LAMBDA0, warm=cold.warm)
    assert again.success and again.warm.hard_run == 2  # the central attempt converged: not one of the warm attempts
    assert on.backend.ipm_outcomes["warm4:Converged"] == 1


def test_a_bad_policy_is_one_line():
    raw = {"campaign": {"name": "t", "seed": 1, "episodes": 1}, "model": {"mpc": {"ipm_central_first": "yes"}}}
    with pytest.raises(campaign.CampaignError, match="mpc.ipm_central_first: unknown policy 'yes'"):
        campaign.campaign_from_dict(raw)


def test_the_central_retry_comes_last_before_ipopt_in_a_full_solve(monkeypatch):
    """mpc.ipm_central_retry: after every other attempt (the central one first or fourth), the warm start at
    mu_init 3e-2 (tag warm5); never in a presumed solve; only for the controllers the policy names."""
    from mcverify.solver.ipm import CENTRAL_RETRY
    params = dataclasses.replace(P_IPM, mpc=dataclasses.replace(P_IPM.mpc, ipm_central_retry="all",
                                                                ipm_central_attempt="all"))
    on = MpcSolver(params)
    cold = on.solve(EGO, FRONT, 1, LAMBDA0)
    easy = dataclasses.replace(cold.warm, hard_run=0)
    usual = [(1e-7, True), (1e-5, True), (0.1, False)]
    retry = (CENTRAL_RETRY.mu_init, True)
    assert _mu_inits(on, easy, monkeypatch) == [*usual, (CENTRAL_WARM.mu_init, True), retry]
    assert on.backend.ipm_outcomes["warm5:Line_Search_Failed"] == 1
    assert _mu_inits(on, easy, monkeypatch, fast_only=True) == usual
    assert backends.uses_policy("mpcdc", Mpc(controller="mpcdc_eps")) and not backends.uses_policy(
        "mpcdc", Mpc(controller="vlcbf"))
    assert Mpc().ipm_central_retry == "mpcdc"  # the default since 2026-11-28 (MPC-DC only)


def test_the_after_hard_attempt_can_be_the_lower_mu_one(monkeypatch):
    """mpc.ipm_after_hard_attempt = lower_mu: the first attempt after a hard solve is AFTER_HARD_WARM (tag warm6),
    then the usual ones; an easy warm start and a presumed solve are untouched; a solve it answers stays hard."""
    from mcverify.solver.ipm import AFTER_HARD_WARM
    params = dataclasses.replace(P_IPM, mpc=dataclasses.replace(P_NO_CENTRAL.mpc, ipm_central_first="all",
                                                                ipm_after_hard_solves=1))
    assert params.mpc.ipm_after_hard_attempt == "lower_mu"  # the default since 2026-11-28
    on = MpcSolver(params)
    cold = on.solve(EGO, FRONT, 1, LAMBDA0)
    usual = [(1e-7, True), (1e-5, True), (0.1, False)]
    assert _mu_inits(on, cold.warm, monkeypatch) == [(AFTER_HARD_WARM.mu_init, True), *usual]
    assert on.backend.ipm_outcomes["warm6:Line_Search_Failed"] == 1
    assert _mu_inits(on, dataclasses.replace(cold.warm, hard_run=0), monkeypatch) == usual
    assert _mu_inits(on, cold.warm, monkeypatch, fast_only=True) == usual
    fresh = MpcSolver(params)
    again = fresh.solve(EGO, FRONT, 1, LAMBDA0, warm=fresh.solve(EGO, FRONT, 1, LAMBDA0).warm)
    assert again.success and again.warm.hard_run == 2 and fresh.backend.ipm_outcomes["warm6:Converged"] == 1
    assert (AFTER_HARD_WARM.mu_init, AFTER_HARD_WARM.bound_push, AFTER_HARD_WARM.mult_push) == (3e-3, 3e-3, 3e-2)


def test_the_after_hard_attempt_can_wait_for_two_hard_solves_in_a_row(monkeypatch):
    """mpc.ipm_after_hard_solves = 2 (the default is 1): one hard solve leaves the usual order, two in a row put the
    after-hard attempt first; the count travels with the warm start and an easy solve resets it."""
    from mcverify.solver.ipm import AFTER_HARD_WARM
    assert Mpc().ipm_after_hard_solves == 1
    on = MpcSolver(dataclasses.replace(P_IPM, mpc=dataclasses.replace(P_NO_CENTRAL.mpc, ipm_central_first="all",
                                                                      ipm_after_hard_solves=2)))
    cold = on.solve(EGO, FRONT, 1, LAMBDA0)  # the cold attempt answers: the first hard solve
    assert cold.success and cold.warm.hard_run == 1
    usual = [(1e-7, True), (1e-5, True), (0.1, False)]
    assert _mu_inits(on, cold.warm, monkeypatch) == usual
    assert _mu_inits(on, dataclasses.replace(cold.warm, hard_run=2), monkeypatch) == [
        (AFTER_HARD_WARM.mu_init, True), *usual]
    easy = on.solve(EGO, FRONT, 1, LAMBDA0, warm=cold.warm)  # warm attempt 1 solves it again
    assert easy.success and easy.warm.hard_run == 0 and on.backend.ipm_outcomes["warm1:Converged"] == 1


def test_a_bad_after_hard_solves_is_one_line():
    raw = {"campaign": {"name": "t", "seed": 1, "episodes": 1}, "model": {"mpc": {"ipm_after_hard_solves": 0}}}
    with pytest.raises(campaign.CampaignError, match="mpc.ipm_after_hard_solves: must be an integer >= 1"):
        campaign.campaign_from_dict(raw)


def test_a_bad_after_hard_attempt_is_one_line():
    raw = {"campaign": {"name": "t", "seed": 1, "episodes": 1}, "model": {"mpc": {"ipm_after_hard_attempt": "x"}}}
    with pytest.raises(campaign.CampaignError,
                       match="mpc.ipm_after_hard_attempt: unknown attempt 'x'; valid: central, lower_mu"):
        campaign.campaign_from_dict(raw)


@pytest.mark.parametrize(("policy", "controller", "used"), [
    ("ipopt", "mpcdc", False), ("phase1", "vlcbf", True), ("phase1_mpcdc", "vlcbf", False),
    ("phase1_mpcdc", "mpcdc", True), ("phase1_mpcdc", "mpcdc_eps", True)])
def test_phase1_mpcdc_certifies_with_phase1_for_the_baselines_only(policy, controller, used):
    mpc = Mpc(controller=controller, infeasibility=policy)
    assert backends.uses_phase1(mpc) is used
    params = dataclasses.replace(P_IPM, mpc=dataclasses.replace(P_IPM.mpc, controller=controller, infeasibility=policy))
    assert MpcSolver(params).backend.infeasibility == ("phase1" if used else "ipopt")
