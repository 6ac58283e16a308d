"""A lean interior-point method for the TO-CBF-MPC NLP: ctypes binding of ``csrc/ipm.c``.

The algorithm is IPOPT's primal-dual barrier method with its filter line search and second-order
corrections (see the C source for what is left out). It runs entirely in C: the banded KKT system
of :class:`mcverify.solver.kkt.KktStructure` is factorised by a banded LU, and the NLP's functions
are the kernel's generated C, called through function pointers, so an iteration costs several
times less than an IPOPT iteration through CasADi on the same kernel (results/BENCHMARKS.md). The
C library is compiled once per machine into the kernel cache
(:func:`mcverify.solver.kernels.get_runtime_library`).

The ABI (the three structs below, the status codes, the exported functions) is declared in
``csrc/ipm.h``; :func:`load_library` compares the library's own description of it with this module's
ctypes structs and :data:`STATUS` and refuses a library that disagrees (:class:`IpmAbiError`).

Options follow IPOPT's names; :data:`WARM_ATTEMPTS` and :data:`COLD` are the settings the
backend uses (chosen by measurement on recorded Table II closed loops, see their docstrings).
"""

from __future__ import annotations

import ctypes
import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mcverify.solver.cfun import CFunction
from mcverify.solver.kkt import KktStructure

_I = ctypes.POINTER(ctypes.c_int)
_D = ctypes.POINTER(ctypes.c_double)
_L = ctypes.POINTER(ctypes.c_int64)
_FUN = ctypes.c_void_p

#: ``IPM_ABI_VERSION`` of ``csrc/ipm.h`` this binding is written for.
ABI_VERSION = 4
#: The status codes of ``csrc/ipm.h`` (``enum ipm_status``) -> status strings, the one table of them
#: on this side (checked against the library's ``ipm_status_name`` at load).
STATUS = {
    0: "Converged", 1: "Max_Iterations", 2: "Line_Search_Failed", 3: "Regularisation_Failed",
    4: "Nonfinite", 5: "Evaluation_Error", 6: "Infeasible_Problem_Detected", 7: "Restoration_Failed",
    8: "Feasible_Point_Found",
}
#: Statuses only the restoration phase returns (``IpmOptions.restoration`` or ``phase1``): a
#: certificate of local infeasibility, undecided, a feasible point (phase 1 only).
INFEASIBLE, RESTORATION_FAILED, FEASIBLE_POINT_FOUND = 6, 7, 8
CONVERGED = 0
_KERNEL_FUNCTIONS = ("nlp_g", "nlp_grad_f", "nlp_jac_g", "nlp_hess_l")


@dataclass(frozen=True)
class IpmOptions:
    """tol: scaled KKT error of a converged point (IPOPT's ``tol``); constr_viol_tol: largest
    unscaled constraint violation of a converged point; mu_init, mu_min: barrier parameter at the
    start and its floor; bound_push: relative distance a start is pushed inside its bounds;
    mult_push: smallest bound multiplier at the start; bound_relax: bounds are relaxed by this
    relative amount (IPOPT's ``bound_relax_factor``); max_iter; verbose: one line per iteration
    on stderr; theta_far, mu_far, push_far: a warm start whose largest scaled violation exceeds
    theta_far starts at mu_far with pushes push_far.

    Restoration phase (off by default: the behaviour of ABI 1 is kept bit for bit): restoration,
    a failed line search starts IPOPT's l1 feasibility problem (csrc/ipm.c, "restoration phase")
    instead of ending the solve; phase1, solve only that problem from the start (status
    ``Feasible_Point_Found``, ``Infeasible_Problem_Detected`` or ``Restoration_Failed``);
    resto_max_iter: iterations of one restoration phase at most; resto_rho: the l1 penalty
    (IPOPT's 1000); resto_mu_cert: a certificate of local infeasibility needs the restoration's
    barrier parameter at most this (and its scaled KKT error at most tol).

    The KKT system is factorised by the banded LU with partial pivoting and the inertia-free curvature
    test."""

    tol: float = 1e-6
    constr_viol_tol: float = 1e-7
    mu_init: float = 1e-7
    mu_min: float = 1e-11
    bound_push: float = 1e-6
    mult_push: float = 1e-6
    bound_relax: float = 1e-8
    max_iter: int = 25
    verbose: bool = False
    theta_far: float = float("inf")
    mu_far: float = 1e-5
    push_far: float = 1e-4
    restoration: bool = False
    phase1: bool = False
    resto_max_iter: int = 100
    resto_rho: float = 1000.0
    resto_mu_cert: float = 1e-6


#: Warm starts: first the IPOPT reference's own warm-start settings (mu_init 1e-7, pushes 1e-6),
#: which keep the previous primal-dual point nearly as is; if that fails, once more from a more
#: central start (mu_init 1e-5, bound push 1e-4); then (in the backend) a cold start. Why two: a
#: large jump of the measured front vehicle leaves the warm point glued to bounds the Newton step
#: must cross, and at mu 1e-7 the fraction-to-the-boundary rule then allows only tiny steps. The
#: measurements behind the settings: docs/decisions.md.
WARM_ATTEMPTS: tuple[IpmOptions, ...] = (
    IpmOptions(mu_init=1e-7, bound_push=1e-6, mult_push=1e-6, max_iter=30),
    IpmOptions(mu_init=1e-5, bound_push=1e-4, mult_push=1e-6, max_iter=30),
)
#: The central warm attempt (MPC-DC, :mod:`mcverify.solver.attempts`): the warm start once more, after the cold
#: attempt failed, at mu_init 1e-2 with the bound push of the cold start's tenth. Where the warm
#: attempts crawl (a new measurement moved the goal row by metres, the point stays glued to its
#: bounds at mu 1e-7 to 1e-5) and the cold one fails its line search, a barrier this large frees the
#: point and keeps the warm start's shape (docs/engine.md, "A central attempt before the rescue").
CENTRAL_WARM = IpmOptions(mu_init=1e-2, bound_push=1e-3, mult_push=1e-6, max_iter=60)
#: The central retry (MPC-DC): the warm start once more after the central attempt
#: failed, at mu_init 3e-2 and up to 100 iterations, before IPOPT's rescue (docs/engine.md, "A central
#: retry before the rescue").
CENTRAL_RETRY = IpmOptions(mu_init=3e-2, bound_push=1e-3, mult_push=1e-6, max_iter=100)
#: The first attempt after a hard solve (MPC-DC): the warm start at
#: mu_init 3e-3 with bound push 3e-3 and bound multipliers of at least 3e-2. On recorded MPC-DC solves after a
#: hard one, the central attempt spends its first iterations on steps of 1e-5 to 1e-3 (the pushed point sits
#: at bounds the Newton step must cross, with multipliers of 1e-6); these settings converge more often and in
#: about 30 instead of 50 iterations per solve (docs/engine.md, "The lower-mu attempt after a hard solve").
AFTER_HARD_WARM = IpmOptions(mu_init=3e-3, bound_push=3e-3, mult_push=3e-2, max_iter=60)
#: Cold starts (no multipliers): IPOPT's defaults (mu_init 0.1, bound_push 0.01).
COLD = IpmOptions(mu_init=0.1, bound_push=1e-2, mult_push=1e-2, max_iter=150)


# Mirrors of ipm_struct, ipm_opts, ipm_stats (csrc/ipm.h), field by field.
class _Struct(ctypes.Structure):
    _fields_ = [
        ("n_w", ctypes.c_int), ("n_g", ctypes.c_int), ("n", ctypes.c_int), ("bw", ctypes.c_int),
        ("ldab", ctypes.c_int), ("n_j", ctypes.c_int), ("j_rows", _I), ("j_cols", _I),
        ("n_h", ctypes.c_int), ("h_rows", _I), ("h_cols", _I),
        ("n_hs", ctypes.c_int), ("hs_row", _I), ("hs_col", _I), ("hs_src", _I),
        ("perm", _I), ("n_ent", ctypes.c_int), ("ent_kind", _I), ("ent_src", _I), ("ent_row", _I), ("ent_pos", _L),
        ("f_g", _FUN), ("f_grad_f", _FUN), ("f_jac_g", _FUN), ("f_hess_l", _FUN), ("work_sizes", _L),
        ("n_fix", ctypes.c_int), ("fix_row", _I), ("fix_var", _I), ("fix_coef", _D),
    ]


class _Opts(ctypes.Structure):
    _fields_ = [
        ("tol", ctypes.c_double), ("constr_viol_tol", ctypes.c_double), ("mu_init", ctypes.c_double),
        ("mu_min", ctypes.c_double), ("bound_push", ctypes.c_double), ("mult_push", ctypes.c_double),
        ("bound_relax", ctypes.c_double), ("max_iter", ctypes.c_int), ("warm", ctypes.c_int),
        ("verbose", ctypes.c_int), ("theta_far", ctypes.c_double), ("mu_far", ctypes.c_double),
        ("push_far", ctypes.c_double), ("restoration", ctypes.c_int), ("phase1", ctypes.c_int),
        ("resto_max_iter", ctypes.c_int), ("resto_rho", ctypes.c_double), ("resto_mu_cert", ctypes.c_double),
    ]


class _Stats(ctypes.Structure):
    _fields_ = [
        ("iterations", ctypes.c_int), ("status", ctypes.c_int), ("factorisations", ctypes.c_int),
        ("regularised", ctypes.c_int), ("backtracks", ctypes.c_int), ("soc", ctypes.c_int), ("far", ctypes.c_int),
        ("inf_pr", ctypes.c_double), ("inf_du", ctypes.c_double), ("mu", ctypes.c_double),
        ("theta_start", ctypes.c_double), ("first_alpha", ctypes.c_double),
        ("resto_calls", ctypes.c_int), ("resto_iterations", ctypes.c_int), ("cert_violation", ctypes.c_double),
        ("cert_stationarity", ctypes.c_double), ("cert_mu", ctypes.c_double),
    ]


class IpmAbiError(RuntimeError):
    """The compiled library and this binding disagree about ``csrc/ipm.h`` (one-line message)."""


_ABI_STRUCTS = (_Struct, _Opts, _Stats)


def abi_layout(structs=_ABI_STRUCTS) -> list[int]:
    """What ``ipm_abi_layout`` writes, from the ctypes side: per struct its size, field count and
    field offsets (declaration order)."""
    out: list[int] = []
    for cls in structs:
        out += [ctypes.sizeof(cls), len(cls._fields_), *(getattr(cls, name).offset for name, _ in cls._fields_)]
    return out


def check_abi(lib: ctypes.CDLL, structs=_ABI_STRUCTS, status: dict[int, str] | None = None,
              version: int = ABI_VERSION) -> None:
    """Raise :class:`IpmAbiError` unless the library's ABI version, struct layouts and status names
    are those of this binding (``structs``, ``status`` default to the ones :class:`Ipm` uses)."""
    status = STATUS if status is None else status
    where = f"{getattr(lib, '_name', lib)}: the ipm library and mcverify/solver/ipm.py disagree about csrc/ipm.h"
    try:
        lib.ipm_abi_version.restype = ctypes.c_int
        lib.ipm_abi_layout.restype = ctypes.c_int
        lib.ipm_status_name.restype = ctypes.c_char_p
    except AttributeError as exc:
        raise IpmAbiError(f"{where}: the library exports no ABI description ({exc})") from None
    if lib.ipm_abi_version() != version:
        raise IpmAbiError(f"{where}: ABI version {lib.ipm_abi_version()} in C, {version} in Python")
    expected = abi_layout(structs)
    n = lib.ipm_abi_layout(None, 0)
    got = (ctypes.c_int64 * n)()
    lib.ipm_abi_layout(got, n)
    if list(got) != expected:
        raise IpmAbiError(f"{where}: {_first_layout_difference(list(got), structs)}")
    for code in range(len(status) + 1):
        name = lib.ipm_status_name(code)
        c_name = None if name is None else name.decode()
        if c_name != status.get(code):
            raise IpmAbiError(f"{where}: status {code} is {c_name!r} in C, {status.get(code)!r} in Python")


def _first_layout_difference(got: list[int], structs) -> str:
    """Where the C layout first differs from the ctypes one, in words."""
    k = 0
    for cls in structs:
        size, count = got[k:k + 2] if k + 2 <= len(got) else (None, None)
        if size != ctypes.sizeof(cls) or count != len(cls._fields_):
            return (f"{cls.__name__}: {size} bytes with {count} fields in C, {ctypes.sizeof(cls)} bytes with "
                    f"{len(cls._fields_)} fields in Python")
        for i, (name, _) in enumerate(cls._fields_):
            if got[k + 2 + i] != getattr(cls, name).offset:
                return f"{cls.__name__}.{name}: offset {got[k + 2 + i]} in C, {getattr(cls, name).offset} in Python"
        k += 2 + count
    return f"layout tables of {len(got)} and {len(abi_layout(structs))} values"


def load_library(library_so: str | Path) -> ctypes.CDLL:
    """The compiled ``csrc/ipm.c``, its ABI checked (:func:`check_abi`)."""
    lib = ctypes.CDLL(str(library_so))
    check_abi(lib)
    lib.ipm_solve.restype = ctypes.c_int
    return lib


@dataclass(frozen=True)
class IpmResult:
    """One :meth:`Ipm.solve`: the point, multipliers (CasADi convention), status and counters.

    max_violation: largest unscaled constraint or bound violation at the returned point;
    dual_infeasibility: scaled (as IPOPT scales it); factorisations, regularised (iterations
    whose Hessian needed a primal regularisation), backtracks, soc (second-order corrections).
    """

    w: np.ndarray
    lam_x: np.ndarray
    lam_g: np.ndarray
    success: bool
    status: str
    iterations: int
    factorisations: int
    regularised: int
    backtracks: int
    soc: int
    max_violation: float
    dual_infeasibility: float
    far_start: bool = False  # the start was far from feasible (theta_start > theta_far): mu_far, push_far used
    theta_start: float = float("nan")  # largest scaled constraint violation at the (embedded) start
    first_alpha: float = float("nan")  # primal step length of the first iteration (negative: corrected step)
    resto_calls: int = 0  # restoration phases (their iterations are counted in iterations too)
    resto_iterations: int = 0
    # at the end of the last restoration phase (nan: none): the l1 norm of the scaled constraint
    # violation (a certificate's measured violation), the scaled KKT error of the l1 feasibility
    # problem (its stationarity) and its barrier parameter
    cert_violation: float = float("nan")
    cert_stationarity: float = float("nan")
    cert_mu: float = float("nan")

    @property
    def infeasible(self) -> bool:
        """A certificate of local infeasibility (status ``Infeasible_Problem_Detected``)."""
        return self.status == STATUS[INFEASIBLE]


class Ipm:
    """The C interior-point method on one compiled kernel. Not thread-safe (one workspace),
    deterministic (no threads, fixed loop orders, no wall-clock dependence).

    kernel_so: the kernel's shared object; lbx, ubx (n_w,), lbg, ubg (n_g,): the bounds (fixed for
    the object's life); library_so: the compiled ``csrc/ipm.c``.
    """

    def __init__(self, kernel_so: str | Path, lbx, ubx, lbg, ubg, library_so: str | Path) -> None:
        self.lbx, self.ubx = (np.ascontiguousarray(a, dtype=np.float64) for a in (lbx, ubx))
        self.lbg, self.ubg = (np.ascontiguousarray(a, dtype=np.float64) for a in (lbg, ubg))
        self.structure = kkt = KktStructure.of_kernel(kernel_so, self.lbg == self.ubg)
        self.n_w, self.n_g = kkt.n_w, kkt.n_g
        if (self.lbx.size, self.lbg.size) != (self.n_w, self.n_g):
            raise ValueError(f"bounds of sizes {self.lbx.size}, {self.lbg.size} for a kernel with "
                             f"{self.n_w} variables and {self.n_g} constraints")
        # the C solver calls the kernel's functions itself, with its own work vectors
        functions = [CFunction(kernel_so, name) for name in _KERNEL_FUNCTIONS]
        funs = [f.address for f in functions]
        sizes = [size for f in functions for size in f.work_sizes]
        ints = {name: np.ascontiguousarray(getattr(kkt, name), dtype=np.int32) for name in (
            "j_rows", "j_cols", "h_rows", "h_cols", "hs_row", "hs_col", "hs_src", "perm", "ent_kind", "ent_src",
            "ent_row", "fix_row", "fix_var")}
        self._keep = (ints, np.ascontiguousarray(kkt.ent_pos, dtype=np.int64), np.asarray(sizes, dtype=np.int64),
                      np.ascontiguousarray(kkt.fix_coef, dtype=np.float64))
        pos, work_sizes, coef = self._keep[1:]
        bw = kkt.bandwidth
        self._st = _Struct(
            self.n_w, self.n_g, kkt.n, bw, 3 * bw + 1,
            ints["j_rows"].size, _ip(ints["j_rows"]), _ip(ints["j_cols"]),
            ints["h_rows"].size, _ip(ints["h_rows"]), _ip(ints["h_cols"]),
            ints["hs_row"].size, _ip(ints["hs_row"]), _ip(ints["hs_col"]), _ip(ints["hs_src"]), _ip(ints["perm"]),
            ints["ent_kind"].size, _ip(ints["ent_kind"]), _ip(ints["ent_src"]), _ip(ints["ent_row"]),
            pos.ctypes.data_as(_L), *funs, work_sizes.ctypes.data_as(_L),
            ints["fix_row"].size, _ip(ints["fix_row"]), _ip(ints["fix_var"]), coef.ctypes.data_as(_D),
        )
        lib = load_library(library_so)
        n_dbl, n_int = ctypes.c_int64(), ctypes.c_int64()
        lib.ipm_work_sizes(ctypes.byref(self._st), ctypes.byref(n_dbl), ctypes.byref(n_int))
        self._wd = np.zeros(n_dbl.value)
        self._wi = np.zeros(n_int.value // 2 + 16, dtype=np.int64).view(np.int32)  # 8-byte aligned
        self._solve = lib.ipm_solve
        self._libs = (lib, functions)  # keep both loaded while the pointers into them live

    def solve(self, p: np.ndarray, w0: np.ndarray, lam_x0: np.ndarray | None = None,
              lam_g0: np.ndarray | None = None, options: IpmOptions | None = None) -> IpmResult:
        """Warm start from (w0, lam_x0, lam_g0), or cold from the primal guess w0 (multipliers None).

        p (n_p,): parameters; w0 (n_w,); lam_x0 (n_w,), lam_g0 (n_g,) in CasADi's sign convention.
        """
        o = options or (WARM_ATTEMPTS[0] if lam_x0 is not None else COLD)
        warm = lam_x0 is not None and lam_g0 is not None
        copts = _Opts(o.tol, o.constr_viol_tol, o.mu_init, o.mu_min, o.bound_push, o.mult_push, o.bound_relax,
                      o.max_iter, int(warm), int(o.verbose), o.theta_far, o.mu_far, o.push_far,
                      int(o.restoration), int(o.phase1), o.resto_max_iter, o.resto_rho, o.resto_mu_cert)
        x = np.array(w0, dtype=np.float64).reshape(-1)
        lx = np.array(lam_x0 if warm else np.zeros(self.n_w), dtype=np.float64).reshape(-1)
        lg = np.array(lam_g0 if warm else np.zeros(self.n_g), dtype=np.float64).reshape(-1)
        pp = np.ascontiguousarray(p, dtype=np.float64).reshape(-1)
        if x.size != self.n_w or lx.size != self.n_w or lg.size != self.n_g or pp.size != self.structure.n_p:
            raise ValueError("Ipm.solve: wrong sizes of p, w0 or the multipliers")
        st = _Stats()
        self._solve(
            ctypes.byref(self._st), ctypes.byref(copts), pp.ctypes.data_as(_D),
            *[b.ctypes.data_as(_D) for b in (self.lbx, self.ubx, self.lbg, self.ubg)],
            x.ctypes.data_as(_D), lx.ctypes.data_as(_D), lg.ctypes.data_as(_D), ctypes.byref(st),
            self._wd.ctypes.data_as(_D), self._wi.ctypes.data_as(_I),
        )
        return IpmResult(
            w=x, lam_x=lx, lam_g=lg, success=st.status == CONVERGED,
            status=STATUS.get(st.status, f"status {st.status}"),
            iterations=int(st.iterations), factorisations=int(st.factorisations), regularised=int(st.regularised),
            backtracks=int(st.backtracks), soc=int(st.soc), max_violation=float(st.inf_pr),
            dual_infeasibility=float(st.inf_du), far_start=bool(st.far), theta_start=float(st.theta_start),
            first_alpha=float(st.first_alpha), resto_calls=int(st.resto_calls),
            resto_iterations=int(st.resto_iterations), cert_violation=float(st.cert_violation),
            cert_stationarity=float(st.cert_stationarity), cert_mu=float(st.cert_mu),
        )


def with_options(base: IpmOptions, **changes) -> IpmOptions:
    """``base`` with some fields changed (benchmarks and tests)."""
    return dataclasses.replace(base, **changes)


def _ip(a: np.ndarray):
    return a.ctypes.data_as(_I)
