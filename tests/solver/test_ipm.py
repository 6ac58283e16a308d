"""The C interior-point method (mcverify.solver.ipm, csrc/ipm.c) on tiny NLPs with known solutions.

Each NLP goes the kernels' way: CasADi generates its C (``nlp_g``, ``nlp_grad_f``, ``nlp_jac_g``,
``nlp_hess_l``), gcc compiles it, and :class:`Ipm` reads its KKT structure and calls it from C.
Checked: the optimum, the multipliers (CasADi's convention: grad f + J' lam_g + lam_x = 0), the
status codes, the initial value embedding, and the ABI check at load.
"""

from __future__ import annotations

import ctypes
import math
import re
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from mcverify.solver import ipm as ipm_mod
from mcverify.solver import kernels, kkt
from mcverify.solver.cfun import CFunction
from mcverify.solver.ipm import COLD, STATUS, WARM_ATTEMPTS, Ipm, IpmAbiError, check_abi, with_options

INF = np.inf


def _qp_active_bound(x, p):  # min (x0 - 2)^2 + (x1 + 1)^2, x0 <= 1, x0 + x1 >= -5
    return (x[0] - 2) ** 2 + (x[1] + 1) ** 2, x[0] + x[1]


def _equality(x, p):  # min x0^2 + 2 x1^2 + x2^2, x0 + x1 + x2 = p
    return x[0] ** 2 + 2 * x[1] ** 2 + x[2] ** 2, x[0] + x[1] + x[2] - p[0]


def _circle(x, p):  # min -x0 - x1, x0^2 + x1^2 <= p
    return -x[0] - x[1], x[0] ** 2 + x[1] ** 2 - p[0]


def _inactive(x, p):  # min (x0 - 1)^2 + (x1 - 1)^2, x0 + x1 <= 10
    return (x[0] - 1) ** 2 + (x[1] - 1) ** 2, x[0] + x[1]


def _fixing_row(x, p):  # x0 = p (a fixing row: one constant Jacobian entry), min (x1 - x0)^2 + x1^2
    return (x[1] - x[0]) ** 2 + x[1] ** 2, ca.vertcat(x[0] - p[0], x[0] + x[1])


def _rosenbrock(x, p):  # min (1 - x0)^2 + 100 (x1 - x0^2)^2, x0^2 + x1^2 <= p
    return (1 - x[0]) ** 2 + 100 * (x[1] - x[0] ** 2) ** 2, x[0] ** 2 + x[1] ** 2 - p[0]


def _sqrt(x, p):  # min sqrt(x0) + x1^2, x0 + x1 >= 1 (not defined for x0 < 0)
    return ca.sqrt(x[0]) + x[1] ** 2, x[0] + x[1]


def _double_well(x, p):  # min x0^4 - x0^2 + x1^2, x0 + x1 >= p (nonconvex near x0 = 0)
    return x[0] ** 4 - x[0] ** 2 + x[1] ** 2, x[0] + x[1]


PROBLEMS = {  # name: (function, n_x)
    "qp_active_bound": (_qp_active_bound, 2), "equality": (_equality, 3), "circle": (_circle, 2),
    "inactive": (_inactive, 2), "fixing_row": (_fixing_row, 2), "rosenbrock": (_rosenbrock, 2), "sqrt": (_sqrt, 2),
    "double_well": (_double_well, 2),
}


@pytest.fixture(scope="module")
def library() -> Path:
    return kernels.get_runtime_library("ipm").so_path


@pytest.fixture(scope="module")
def compiled(tmp_path_factory):
    """name -> (kernel .so, the CasADi NLP); each compiled once (well under a second)."""
    root, cache = tmp_path_factory.mktemp("tiny-nlps"), {}

    def get(name: str):
        if name not in cache:
            fun, n_x = PROBLEMS[name]
            x, p = ca.SX.sym("x", n_x), ca.SX.sym("p", 1)
            f, g = fun(x, p)
            nlp = {"x": x, "p": p, "f": f, "g": g}
            cache[name] = (_compile(nlp, root / name), nlp)
        return cache[name]

    return get


def _compile(nlp: dict, folder: Path) -> Path:
    """The kernel's path (kernels.generate_c and compile_c) for any NLP."""
    folder.mkdir()
    solver = ca.nlpsol("tiny_gen", "ipopt", nlp)
    gen = ca.CodeGenerator(kernels.C_FILE)
    gen.add(solver.oracle())
    for name in solver.get_function():
        gen.add(solver.get_function(name))
    gen.generate(f"{folder}/")
    kernels.compile_c(folder / kernels.C_FILE, folder / kernels.SO_FILE)
    return folder / kernels.SO_FILE


def solve(compiled, library, name, bounds, p, w0, warm=None, options=None):
    so, _ = compiled(name)
    ipm = Ipm(so, *bounds, library)
    lam_x, lam_g = warm if warm is not None else (None, None)
    return ipm, ipm.solve(np.array([p], float), np.array(w0, float), lam_x, lam_g, options or COLD)


def stationarity(so: Path, w: np.ndarray, p: float, lam_x: np.ndarray, lam_g: np.ndarray) -> float:
    """max |grad f + J' lam_g + lam_x| at w (CasADi's sign convention)."""
    grad, jac = CFunction(so, "nlp_grad_f"), CFunction(so, "nlp_jac_g")
    for fun in (grad, jac):
        fun.inputs[0][:], fun.inputs[1][:] = w, p
    rows, cols = jac.sparsity_out[1]
    jt_lam = np.bincount(cols, jac()[1] * lam_g[rows], minlength=w.size)
    return float(np.max(np.abs(grad()[1] + jt_lam + lam_x)))


# ------------------------------------------------------------------------------- known optima


def test_qp_with_an_active_upper_bound(compiled, library):
    bounds = ([-INF, -INF], [1.0, INF], [-5.0], [INF])
    _, r = solve(compiled, library, "qp_active_bound", bounds, 0.0, [0.0, 0.0])
    assert r.success and r.status == "Converged"
    assert np.allclose(r.w, [1.0, -1.0], atol=1e-6)
    assert np.allclose(r.lam_x, [2.0, 0.0], atol=1e-6)  # upper bound active: positive multiplier
    assert abs(r.lam_g[0]) <= 1e-6  # the row is inactive
    assert stationarity(compiled("qp_active_bound")[0], r.w, 0.0, r.lam_x, r.lam_g) <= 1e-6


def test_equality_constrained_qp(compiled, library):
    bounds = ([-INF] * 3, [INF] * 3, [0.0], [0.0])
    _, r = solve(compiled, library, "equality", bounds, 4.0, [0.0, 0.0, 0.0])
    assert r.status == "Converged"
    assert np.allclose(r.w, [1.6, 0.8, 1.6], atol=1e-7)  # 2 x0 = 4 x1 = 2 x2 = -lam_g
    assert r.lam_g[0] == pytest.approx(-3.2, abs=1e-7)
    assert np.all(r.lam_x == 0.0)  # no bounds
    assert r.max_violation <= 1e-9


def test_nonlinear_inequality_active_at_the_optimum(compiled, library):
    bounds = ([-INF, -INF], [INF, INF], [-INF], [0.0])
    _, r = solve(compiled, library, "circle", bounds, 1.0, [0.1, 0.2])
    h = 1.0 / math.sqrt(2.0)
    assert r.status == "Converged"
    assert np.allclose(r.w, [h, h], atol=1e-6)
    assert r.lam_g[0] == pytest.approx(h, abs=1e-6)  # -1 + lam 2 x = 0
    assert stationarity(compiled("circle")[0], r.w, 1.0, r.lam_x, r.lam_g) <= 1e-6


def test_inactive_inequality_has_no_multiplier(compiled, library):
    bounds = ([-INF, -INF], [INF, INF], [-INF], [10.0])
    _, r = solve(compiled, library, "inactive", bounds, 0.0, [5.0, -3.0])
    assert r.status == "Converged"
    assert np.allclose(r.w, [1.0, 1.0], atol=1e-6)
    assert abs(r.lam_g[0]) <= 1e-6


def test_constrained_rosenbrock_matches_ipopt(compiled, library):
    so, nlp = compiled("rosenbrock")
    bounds = ([-2.0, -2.0], [2.0, 2.0], [-INF], [0.0])
    _, r = solve(compiled, library, "rosenbrock", bounds, 0.5, [-1.0, 1.0])
    ref = ca.nlpsol("ref", "ipopt", nlp, {"print_time": False, "ipopt": {"print_level": 0, "sb": "yes"}})(
        x0=[-1.0, 1.0], p=0.5, lbx=bounds[0], ubx=bounds[1], lbg=bounds[2], ubg=bounds[3])
    assert r.status == "Converged"
    assert np.allclose(r.w, np.asarray(ref["x"]).ravel(), atol=1e-6)
    assert np.allclose(r.lam_g, np.asarray(ref["lam_g"]).ravel(), atol=1e-5)
    assert r.w @ r.w == pytest.approx(0.5, abs=1e-7)  # the constraint is active
    assert stationarity(so, r.w, 0.5, r.lam_x, r.lam_g) <= 1e-6


def test_fixing_row_is_applied_exactly(compiled, library):
    """Initial value embedding: the row x0 - p = 0 is solved at the start and never moved by a step."""
    bounds = ([-INF, -INF], [INF, INF], [0.0, -INF], [0.0, 100.0])
    ipm, r = solve(compiled, library, "fixing_row", bounds, 0.3, [5.0, 5.0])
    assert list(ipm.structure.fix_row) == [0] and list(ipm.structure.fix_var) == [0]
    assert r.status == "Converged"
    assert r.w[0] == 0.3  # exactly, not to a tolerance
    assert r.w[1] == pytest.approx(0.15, abs=1e-8)  # 2 (x1 - x0) + 2 x1 = 0


# ------------------------------------------------------------------------------- warm starts


def test_warm_start_from_the_solution_stays_there(compiled, library):
    bounds = ([-INF, -INF], [1.0, INF], [-5.0], [INF])
    ipm, cold = solve(compiled, library, "qp_active_bound", bounds, 0.0, [0.0, 0.0])
    warm = ipm.solve(np.zeros(1), cold.w, cold.lam_x, cold.lam_g, WARM_ATTEMPTS[0])
    assert warm.status == "Converged" and warm.iterations <= 2 < cold.iterations
    assert np.allclose(warm.w, cold.w, atol=1e-7) and np.allclose(warm.lam_x, cold.lam_x, atol=1e-6)


def test_same_inputs_give_the_same_bits(compiled, library):
    bounds = ([-2.0, -2.0], [2.0, 2.0], [-INF], [0.0])
    ipm, a = solve(compiled, library, "rosenbrock", bounds, 0.5, [-1.0, 1.0])
    ipm.solve(np.array([0.7]), np.array([0.3, 0.1]), options=COLD)  # an unrelated solve between
    b = ipm.solve(np.array([0.5]), np.array([-1.0, 1.0]), options=COLD)
    for name in ("w", "lam_x", "lam_g"):
        assert np.array_equal(getattr(a, name), getattr(b, name))
    assert (a.status, a.iterations, a.backtracks, a.soc) == (b.status, b.iterations, b.backtracks, b.soc)


# ---------------------------------------------------------------------------------- failures


def test_infeasible_problem_is_not_converged(compiled, library):
    """0 <= x <= 1 and x0 + x1 >= -5 cannot hold with x0 + x1 = 3: without the restoration phase
    (the default) the IPM has no infeasibility certificate, so it ends on its iteration limit or a
    failed line search."""
    bounds = ([0.0, 0.0], [1.0, 1.0], [3.0], [3.0])
    _, r = solve(compiled, library, "qp_active_bound", bounds, 0.0, [0.5, 0.5])
    assert not r.success
    assert r.status in ("Max_Iterations", "Line_Search_Failed", "Regularisation_Failed")
    assert r.max_violation >= 0.5  # x0 + x1 <= 2 at best


def test_iteration_limit(compiled, library):
    bounds = ([-2.0, -2.0], [2.0, 2.0], [-INF], [0.0])
    _, r = solve(compiled, library, "rosenbrock", bounds, 0.5, [-1.0, 1.0], options=with_options(COLD, max_iter=1))
    assert r.status == "Max_Iterations" and not r.success and r.iterations == 1


def test_infinite_derivative_is_reported(compiled, library):
    """sqrt's derivative at x0 = 0 is inf (no bound keeps x0 > 0 here): status Nonfinite before any step."""
    bounds = ([-INF, -INF], [INF, INF], [1.0], [INF])
    _, r = solve(compiled, library, "sqrt", bounds, 0.0, [0.0, 2.0])
    assert r.status == "Nonfinite" and not r.success and r.iterations == 0


# ------------------------------------------------------------------------------------- ABI


def test_status_table_mirrors_the_header():
    header = (kernels.CSRC_DIR / "ipm.h").read_text()
    for code, name in STATUS.items():
        assert f"IPM_{name.upper()} = {code}," in header
    assert f"IPM_STATUS_COUNT = {len(STATUS)}" in header
    assert f"#define IPM_ABI_VERSION {ipm_mod.ABI_VERSION}\n" in header


def test_kkt_entry_kinds_mirror_the_header():
    header = (kernels.CSRC_DIR / "ipm.h").read_text()
    for name in ("HESSIAN", "PRIMAL_DIAG", "JAC_T", "JAC", "DUAL_DIAG"):
        assert re.search(rf"IPM_ENTRY_{name} = {getattr(kkt, f'KIND_{name}')}\b", header), name


def test_abi_check_passes_on_the_library(library):
    check_abi(ctypes.CDLL(str(library)))


def test_abi_check_rejects_a_wrong_struct_size(library):
    class Stats(ctypes.Structure):  # one field short of ipm_stats
        _fields_ = ipm_mod._Stats._fields_[:-1]

    lib = ctypes.CDLL(str(library))
    with pytest.raises(IpmAbiError, match=r"Stats: 104 bytes with 17 fields in C, 96 bytes with 16 fields") as info:
        check_abi(lib, structs=(ipm_mod._Struct, ipm_mod._Opts, Stats))
    assert "\n" not in str(info.value) and "csrc/ipm.h" in str(info.value)


def test_abi_check_rejects_a_moved_field(library):
    class Opts(ctypes.Structure):  # max_iter and warm swapped with a double: offsets move
        _fields_ = [(name, ctypes.c_double if name == "max_iter" else typ) for name, typ in ipm_mod._Opts._fields_]

    with pytest.raises(IpmAbiError, match=r"Opts"):
        check_abi(ctypes.CDLL(str(library)), structs=(ipm_mod._Struct, Opts, ipm_mod._Stats))


def test_abi_check_rejects_other_status_codes_or_version(library):
    lib = ctypes.CDLL(str(library))
    with pytest.raises(IpmAbiError, match=r"status 3 is 'Regularisation_Failed' in C, 'Singular' in Python"):
        check_abi(lib, status={**STATUS, 3: "Singular"})
    with pytest.raises(IpmAbiError, match=r"status 9 is None in C, 'Unknown' in Python"):
        check_abi(lib, status={**STATUS, 9: "Unknown"})
    with pytest.raises(IpmAbiError, match=r"status 6 is 'Infeasible_Problem_Detected' in C, 'Infeasible' in Python"):
        check_abi(lib, status={**STATUS, 6: "Infeasible"})
    with pytest.raises(IpmAbiError, match=r"ABI version 4 in C, 1 in Python"):
        check_abi(lib, version=1)


def test_library_without_an_abi_description_is_refused(compiled):
    so, _ = compiled("qp_active_bound")  # any shared object without the ipm_abi_* exports
    with pytest.raises(IpmAbiError, match="exports no ABI description"):
        ipm_mod.load_library(so)


def test_the_built_library_folder_holds_its_header(library):
    assert (library.parent / "ipm.h").read_text() == (kernels.CSRC_DIR / "ipm.h").read_text()
