"""The restoration phase of the C interior point (csrc/ipm.c, ABI 2) on tiny NLPs.

Each NLP goes the kernels' way (CasADi -> generated C -> gcc -> :class:`Ipm`), as in
tests/solver/test_ipm.py. Checked: a certificate of local infeasibility (status
``Infeasible_Problem_Detected``) at a stationary point of the l1 constraint violation, with the
measured violation and stationarity in the result; a problem whose line search fails and that the
restoration phase rescues; phase 1 alone (feasible point / certificate); IPOPT's verdict and point
on the Waechter-Biegler example; fixing rows kept exact; and nothing changes while the options are
off (the default).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from test_ipm import _compile, _fixing_row, _qp_active_bound, _rosenbrock

from mcverify.solver import kernels
from mcverify.solver.ipm import COLD, Ipm, with_options

INF = np.inf
RESTO = with_options(COLD, restoration=True)
PHASE1 = with_options(COLD, phase1=True)


def _waechter_biegler(x, p):
    """min x0 s.t. x0^2 - x1 + p = 0, x0 - x2 - 1/2 = 0, x1, x2 >= 0 (Waechter & Biegler 2000: with
    p = -1 and the start (-2, 1, 1) a line-search interior point without restoration fails)."""
    return x[0], ca.vertcat(x[0] ** 2 - x[1] + p[0], x[0] - x[2] - 0.5)


PROBLEMS = {"qp": (_qp_active_bound, 2), "fixing_row": (_fixing_row, 2), "rosenbrock": (_rosenbrock, 2),
            "wb": (_waechter_biegler, 3)}
WB_BOUNDS = ([-INF, 0.0, 0.0], [INF, INF, INF], [0.0, 0.0], [0.0, 0.0])


@pytest.fixture(scope="module")
def nlp(tmp_path_factory):
    """name -> (kernel .so, CasADi NLP dict), compiled once per module."""
    root, cache = tmp_path_factory.mktemp("resto-nlps"), {}
    library = kernels.get_runtime_library("ipm").so_path

    def get(name: str, bounds):
        if name not in cache:
            fun, n_x = PROBLEMS[name]
            x, p = ca.SX.sym("x", n_x), ca.SX.sym("p", 1)
            f, g = fun(x, p)
            d = {"x": x, "p": p, "f": f, "g": g}
            cache[name] = (_compile(d, root / name), d)
        so, d = cache[name]
        return Ipm(so, *bounds, library), d

    return get


def _ipopt(d, bounds, x0, p):
    solver = ca.nlpsol("ref", "ipopt", d, {"print_time": False, "ipopt": {"print_level": 0, "sb": "yes"}})
    out = solver(x0=x0, p=p, lbx=bounds[0], ubx=bounds[1], lbg=bounds[2], ubg=bounds[3])
    return solver.stats()["return_status"], np.asarray(out["x"]).ravel()


def test_infeasible_problem_gets_a_certificate_at_the_least_violation_point(nlp):
    """0 <= x <= 1 and x0 + x1 = 3: the l1 violation |x0 + x1 - 3| is smallest (1) at (1, 1)."""
    ipm, _ = nlp("qp", ([0.0, 0.0], [1.0, 1.0], [3.0], [3.0]))
    plain = ipm.solve(np.zeros(1), np.array([0.5, 0.5]), options=COLD)
    assert plain.status == "Line_Search_Failed" and plain.resto_calls == 0 and np.isnan(plain.cert_violation)
    r = ipm.solve(np.zeros(1), np.array([0.5, 0.5]), options=RESTO)
    assert r.status == "Infeasible_Problem_Detected" and r.infeasible and not r.success
    assert r.resto_calls == 1 and 0 < r.resto_iterations <= r.iterations
    assert np.allclose(r.w, [1.0, 1.0], atol=1e-6)
    assert r.cert_violation == pytest.approx(1.0, abs=1e-6)  # the measured l1 violation (row scale 1)
    assert r.max_violation == pytest.approx(1.0, abs=1e-6)
    assert r.cert_stationarity <= RESTO.tol and r.cert_mu <= RESTO.resto_mu_cert


def test_phase1_finds_a_feasible_point_or_certifies(nlp):
    ipm, _ = nlp("qp", ([0.0, 0.0], [1.0, 1.0], [1.5], [1.5]))
    r = ipm.solve(np.zeros(1), np.array([0.1, 0.1]), options=PHASE1)
    assert r.status == "Feasible_Point_Found" and not r.success
    assert r.max_violation <= PHASE1.constr_viol_tol and r.w.sum() == pytest.approx(1.5, abs=1e-7)
    ipm, _ = nlp("qp", ([0.0, 0.0], [1.0, 1.0], [3.0], [3.0]))
    r = ipm.solve(np.zeros(1), np.array([0.1, 0.1]), options=PHASE1)
    assert r.status == "Infeasible_Problem_Detected" and r.cert_violation == pytest.approx(1.0, abs=1e-6)


def test_waechter_biegler_certificate_matches_ipopt(nlp):
    """From (-2, 1, 1) IPOPT reports local infeasibility at (-1, 0, 0), a local minimiser of the l1
    violation (1.5 there, in row 2): the restoration phase ends with the same verdict and point."""
    ipm, d = nlp("wb", WB_BOUNDS)
    x0 = np.array([-2.0, 1.0, 1.0])
    ref_status, ref_x = _ipopt(d, WB_BOUNDS, x0, -1.0)
    assert ref_status == "Infeasible_Problem_Detected"
    assert ipm.solve(np.array([-1.0]), x0.copy(), options=COLD).status == "Line_Search_Failed"
    r = ipm.solve(np.array([-1.0]), x0.copy(), options=RESTO)
    assert r.status == "Infeasible_Problem_Detected"
    assert np.allclose(r.w, ref_x, atol=1e-6) and np.allclose(r.w, [-1.0, 0.0, 0.0], atol=1e-6)
    assert r.cert_violation == pytest.approx(1.5, abs=1e-6)


def test_restoration_rescues_a_failed_line_search(nlp):
    """From (-0.085, 2.437, 2.704) the plain IPM's line search fails; the restoration phase brings it
    to a point from which it converges to the optimum (1, 0, 1/2), as IPOPT does."""
    ipm, d = nlp("wb", WB_BOUNDS)
    x0 = np.array([-0.085, 2.437, 2.704])
    assert ipm.solve(np.array([-1.0]), x0.copy(), options=COLD).status == "Line_Search_Failed"
    r = ipm.solve(np.array([-1.0]), x0.copy(), options=RESTO)
    assert r.status == "Converged" and r.success and r.resto_calls >= 1
    assert np.allclose(r.w, [1.0, 0.0, 0.5], atol=1e-6)
    ref_status, ref_x = _ipopt(d, WB_BOUNDS, x0, -1.0)
    assert ref_status == "Solve_Succeeded" and np.allclose(r.w, ref_x, atol=1e-6)


def test_fixing_rows_stay_exact_in_the_restoration_phase(nlp):
    """x0 = p is a fixing row (no elastic pair): x0 + x1 >= 5 with x1 <= 1 cannot hold for p = 0.3;
    the certificate keeps x0 = 0.3 exactly and puts x1 at its bound."""
    ipm, _ = nlp("fixing_row", ([-INF, -INF], [INF, 1.0], [0.0, 5.0], [0.0, INF]))
    r = ipm.solve(np.array([0.3]), np.array([5.0, 0.0]), options=PHASE1)
    assert r.status == "Infeasible_Problem_Detected"
    assert r.w[0] == 0.3
    assert r.w[1] == pytest.approx(1.0, abs=1e-6) and r.cert_violation == pytest.approx(3.7, abs=1e-5)


def test_options_off_change_nothing(nlp):
    """A solve that never fails its line search is bit for bit the same with restoration on."""
    ipm, _ = nlp("rosenbrock", ([-2.0, -2.0], [2.0, 2.0], [-INF], [0.0]))
    a = ipm.solve(np.array([0.5]), np.array([-1.0, 1.0]), options=COLD)
    b = ipm.solve(np.array([0.5]), np.array([-1.0, 1.0]), options=RESTO)
    assert a.status == b.status == "Converged" and b.resto_calls == 0
    for name in ("w", "lam_x", "lam_g"):
        assert np.array_equal(getattr(a, name), getattr(b, name))
    assert (a.iterations, a.backtracks, a.soc) == (b.iterations, b.backtracks, b.soc)
