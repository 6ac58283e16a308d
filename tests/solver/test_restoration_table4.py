"""The restoration phase on two recorded Table IV solves (MPC-DC, Scenario A, with veh_o).

tests/fixtures/table4_recorded_solves.npz holds the inputs of two backend solves the engine met in
episode 0 of ``campaigns/table4_fixed_start.toml`` (recorded with
:func:`mcverify.bench.recorded_ipm.record_engine`): the parameter vector, the warm start and the cold
guess, and the engine's answer. In both the three IPM attempts failed and IPOPT answered as the
fallback: "certified" it reported local infeasibility, "rescued" it solved. Checked: the default
attempts still fail as recorded; phase 1 certifies the first from the warm start and from the cold
guess (the start-independent certificate), with a positive measured violation at a stationary
point; the second is solved in C once the restoration phase is on.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from mcverify.campaign.spec import load_campaign
from mcverify.ocp.problem import OcpStructure
from mcverify.solver.ipm import COLD, WARM_ATTEMPTS
from mcverify.solver.mpc import MpcSolver

ROOT = Path(__file__).resolve().parents[2]
DATA = np.load(ROOT / "tests" / "fixtures" / "table4_recorded_solves.npz")
CAMPAIGN = load_campaign(ROOT / "campaigns" / "table4_fixed_start.toml")


@pytest.fixture(scope="module")
def solvers():
    cache = {}

    def get(name: str) -> MpcSolver:
        key = (str(DATA[f"{name}_cell"]), bool(DATA[f"{name}_opp"]))
        if key not in cache:
            params = CAMPAIGN.cell(key[0]).params
            cache[key] = MpcSolver(params, OcpStructure.from_params(params, with_opposing=key[1]))
        return cache[key]

    return get


def _solve(solver: MpcSolver, name: str, options, warm: bool):
    ipm, p = solver.backend.ipm, DATA[f"{name}_p"]
    if warm:
        return ipm.solve(p, DATA[f"{name}_x"], DATA[f"{name}_lam_x"], DATA[f"{name}_lam_g"], options)
    return ipm.solve(p, DATA[f"{name}_guess"], None, None, options)


def _default_attempts(solver: MpcSolver, name: str):
    tol = solver.params.mpc.tol
    opts = [(dataclasses.replace(o, tol=tol), True) for o in WARM_ATTEMPTS]
    opts.append((dataclasses.replace(COLD, tol=tol), False))
    return [_solve(solver, name, o, w) for o, w in opts]


def test_certified_problem_gets_the_start_independent_certificate(solvers):
    solver = solvers("certified")
    assert str(DATA["certified_status"]) == "fallback:Infeasible_Problem_Detected"
    assert not any(r.success for r in _default_attempts(solver, "certified"))
    tol = solver.params.mpc.tol
    for options, warm in ((WARM_ATTEMPTS[0], True), (COLD, False)):
        r = _solve(solver, "certified", dataclasses.replace(options, tol=tol, phase1=True), warm)
        assert r.status == "Infeasible_Problem_Detected", warm
        assert r.cert_stationarity <= tol and r.cert_violation > 1e-3
        assert solver.problem.max_violation(r.w, DATA["certified_p"]) > 1e-5  # the point is infeasible


def test_rescued_problem_is_solved_in_c_with_the_restoration_phase(solvers):
    solver = solvers("rescued")
    assert str(DATA["rescued_status"]) == "fallback:Solve_Succeeded"
    assert not any(r.success for r in _default_attempts(solver, "rescued"))
    tol = solver.params.mpc.tol
    r = _solve(solver, "rescued", dataclasses.replace(COLD, tol=tol, restoration=True), False)
    assert r.success and r.resto_calls >= 1
    assert solver.problem.max_violation(r.w, DATA["rescued_p"]) <= 1e-5
    feasible = _solve(solver, "rescued", dataclasses.replace(WARM_ATTEMPTS[0], tol=tol, phase1=True), True)
    assert feasible.status == "Feasible_Point_Found" and feasible.max_violation <= 1e-7
