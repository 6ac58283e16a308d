"""The LDL^T path on the two recorded Table IV solves of tests/fixtures/table4_recorded_solves.npz
(see tests/solver/test_restoration_table4.py), two hard problems the IPM gave to IPOPT.

With the LU's curvature test (``ldlt_curvature``) the LDL^T path reproduces the LU path's statuses
of every attempt and its restoration verdicts. With the inertia test (``ldlt``) the steps differ
where the Hessian is indefinite: every default attempt still fails (so the engine would hand both
to IPOPT as before), but the restoration verdicts change (measured, recorded here): one reason the
option is off by default (docs/engine.md, "The LDL^T path")."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_restoration_table4 import _solve, solvers  # noqa: F401 - the fixture

from mcverify.solver.ipm import COLD, WARM_ATTEMPTS


def _attempts(solver, name: str, kkt: str):
    tol = solver.params.mpc.tol
    opts = [(dataclasses.replace(o, tol=tol, kkt_factorisation=kkt), True) for o in WARM_ATTEMPTS]
    opts.append((dataclasses.replace(COLD, tol=tol, kkt_factorisation=kkt), False))
    return [_solve(solver, name, o, w) for o, w in opts]


def _verdicts(solver, name: str, kkt: str):
    tol = solver.params.mpc.tol
    phase1 = _solve(solver, name, dataclasses.replace(COLD, tol=tol, phase1=True, kkt_factorisation=kkt), False)
    resto = _solve(solver, name, dataclasses.replace(COLD, tol=tol, restoration=True, kkt_factorisation=kkt), False)
    return phase1, resto


@pytest.mark.parametrize("name", ["certified", "rescued"])
def test_ldlt_with_the_curvature_test_reproduces_the_lu_statuses(solvers, name):  # noqa: F811
    solver = solvers(name)
    lu, ldlt = _attempts(solver, name, "lu"), _attempts(solver, name, "ldlt_curvature")
    assert [r.status for r in ldlt] == [r.status for r in lu]
    assert all(r.kkt_ratio_max <= 1e-10 for r in ldlt)
    lu_v, ldlt_v = _verdicts(solver, name, "lu"), _verdicts(solver, name, "ldlt_curvature")
    assert [r.status for r in ldlt_v] == [r.status for r in lu_v]
    if lu_v[1].success:  # the rescue: the same point to solver tolerance
        assert np.max(np.abs(lu_v[1].w - ldlt_v[1].w)) <= 1e-4 * max(1.0, float(np.max(np.abs(lu_v[1].w))))


@pytest.mark.parametrize("name", ["certified", "rescued"])
def test_ldlt_with_the_inertia_test_still_fails_every_default_attempt(solvers, name):  # noqa: F811
    ldlt = _attempts(solvers(name), name, "ldlt")
    assert not any(r.success for r in ldlt)
    assert all(r.kkt_ratio_max <= 1e-10 for r in ldlt)
