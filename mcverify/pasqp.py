"""ctypes binding of ``csrc/pasqp.c``, the parametric active-set QP of :mod:`mcverify.sqp`.

The C source ships with the package and is compiled once per machine into the kernel cache
(:func:`mcverify.kernels.get_runtime_library`), like the TO-CBF-MPC kernels.
"""

from __future__ import annotations

import ctypes
from pathlib import Path

import numpy as np

_I = ctypes.POINTER(ctypes.c_int)
_D = ctypes.POINTER(ctypes.c_double)
_L = ctypes.POINTER(ctypes.c_int64)
_B = ctypes.POINTER(ctypes.c_byte)


class _Struct(ctypes.Structure):
    _fields_ = [
        ("n_w", ctypes.c_int), ("n_g", ctypes.c_int), ("n", ctypes.c_int), ("bw", ctypes.c_int), ("ldab", ctypes.c_int),
        ("n_j", ctypes.c_int), ("j_rows", _I), ("j_cols", _I), ("jcol_ptr", _I), ("jcol_idx", _I),
        ("n_hs", ctypes.c_int), ("hs_row", _I), ("hs_col", _I), ("hs_src", _I),
        ("perm", _I), ("iperm", _I),
        ("row_ptr", _I), ("ent_kind", _I), ("ent_src", _I), ("ent_col", _I), ("ent_pos", _L),
    ]


class _Opts(ctypes.Structure):
    _fields_ = [
        ("tol", ctypes.c_double), ("tol_slope", ctypes.c_double), ("reg_primal", ctypes.c_double),
        ("reg_dual", ctypes.c_double), ("max_passes", ctypes.c_int), ("max_schur", ctypes.c_int),
    ]


class _Stats(ctypes.Structure):
    _fields_ = [("passes", ctypes.c_int), ("factorisations", ctypes.c_int), ("status", ctypes.c_int)]


STATUS = {0: "ok", 1: "singular KKT matrix", 2: "active set not settled", 3: "nonfinite step"}


class PasQp:
    """The C QP solver for one KKT structure (arrays from :class:`mcverify.sqp.Sqp`).

    Not thread-safe (one workspace), deterministic.
    """

    def __init__(self, so_path: str | Path, n_w: int, n_g: int, bw: int, arrays: dict, ent_pos: np.ndarray,
                 tol: float, tol_slope: float, reg_primal: float, reg_dual: float, max_passes: int,
                 max_schur: int) -> None:
        lib = ctypes.CDLL(str(so_path))
        self._solve = lib.pasqp_solve
        self._solve.restype = ctypes.c_int
        self._keep = {k: np.ascontiguousarray(v, dtype=np.int32) for k, v in arrays.items()}
        self._pos = np.ascontiguousarray(ent_pos, dtype=np.int64)
        n = n_w + n_g
        k = self._keep
        self.st = _Struct(
            n_w, n_g, n, bw, 3 * bw + 1, k["j_rows"].size, _ip(k["j_rows"]), _ip(k["j_cols"]),
            _ip(k["jcol_ptr"]), _ip(k["jcol_idx"]), k["hs_row"].size, _ip(k["hs_row"]), _ip(k["hs_col"]),
            _ip(k["hs_src"]), _ip(k["perm"]), _ip(k["iperm"]), _ip(k["row_ptr"]), _ip(k["ent_kind"]),
            _ip(k["ent_src"]), _ip(k["ent_col"]), self._pos.ctypes.data_as(_L),
        )
        self.opts = _Opts(tol, tol_slope, reg_primal, reg_dual, max_passes, max_schur)
        n_dbl, n_int = ctypes.c_int64(), ctypes.c_int64()
        lib.pasqp_work_sizes(ctypes.byref(self.st), ctypes.byref(self.opts), ctypes.byref(n_dbl), ctypes.byref(n_int))
        self._wd = np.zeros(n_dbl.value)
        self._wi = np.zeros(n_int.value, dtype=np.int32)
        self._lib = lib
        self.n_w, self.n_g = n_w, n_g

    def solve(self, js, hess, grad, lo1, up1, lox1, upx1, con, var, lam_scaled, lam_x):
        """Run the QP; con, var (int8), lam_scaled, lam_x are updated in place. Returns
        (d or None, status string, passes, factorisations)."""
        d = np.empty(self.n_w)
        stats = _Stats()
        arrs = [np.ascontiguousarray(a, dtype=np.float64) for a in (js, hess, grad, lo1, up1, lox1, upx1)]
        self._solve(
            ctypes.byref(self.st), ctypes.byref(self.opts), *[a.ctypes.data_as(_D) for a in arrs],
            con.ctypes.data_as(_B), var.ctypes.data_as(_B), lam_scaled.ctypes.data_as(_D), lam_x.ctypes.data_as(_D),
            d.ctypes.data_as(_D), ctypes.byref(stats), self._wd.ctypes.data_as(_D), self._wi.ctypes.data_as(_I),
        )
        status = STATUS.get(stats.status, f"status {stats.status}")
        return (d if stats.status == 0 else None), status, stats.passes, stats.factorisations


def _ip(a: np.ndarray):
    return a.ctypes.data_as(_I)
