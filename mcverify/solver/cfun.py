"""Call CasADi-generated C functions directly (ctypes), without CasADi's Python call layer.

Why: a ``casadi.Function`` call from Python costs far more in argument conversion and DM
building than the compiled work it runs (figures in ``docs/decisions.md``), more than the whole
numerical work of an interior-point iteration. A :class:`CFunction` binds the generated entry
point once, with input and output buffers preallocated as numpy arrays, so a call is one ctypes
call (a few microseconds).

The generated API (CasADi code generation, any version >= 3.5)::

    int  NAME(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem);
    int  NAME_work(casadi_int* sz_arg, casadi_int* sz_res, casadi_int* sz_iw, casadi_int* sz_w);
    void NAME_incref(void);

with ``casadi_real`` = double and ``casadi_int`` = long long (checked at load). Outputs are the
nonzeros of each output's sparsity, in CasADi's column-major (CCS) order; :attr:`CFunction.sparsity_out`
gives (rows, cols) of every nonzero.
"""

from __future__ import annotations

import ctypes
from pathlib import Path

import casadi as ca
import numpy as np

_INT = ctypes.c_longlong
_DBL_P = ctypes.POINTER(ctypes.c_double)


class CFunction:
    """One generated CasADi function of a shared object, callable with numpy buffers.

    ``inputs[i]`` (float64, length = nnz of input i) are written by the caller (``np.copyto`` or
    item assignment) before :meth:`__call__`; ``outputs[i]`` hold the nonzeros afterwards. The
    buffers are owned by this object and reused: copy an output before the next call if it must
    survive it. Not thread-safe (one work vector per object), deterministic.
    """

    def __init__(self, so_path: str | Path, name: str) -> None:
        so_path = str(so_path)
        self.name = name
        meta = ca.external(name, so_path)  # only for the sparsity patterns and sizes
        self.sparsity_in = [_triplet(meta.sparsity_in(i)) for i in range(meta.n_in())]
        self.sparsity_out = [_triplet(meta.sparsity_out(i)) for i in range(meta.n_out())]
        self.shape_out = [meta.sparsity_out(i).shape for i in range(meta.n_out())]
        lib = ctypes.CDLL(so_path)
        if getattr(lib, f"{_prefix(name)}casadi_int_size", None) is not None:
            size = getattr(lib, f"{_prefix(name)}casadi_int_size")()
            if size != ctypes.sizeof(_INT):
                raise RuntimeError(f"{so_path}: casadi_int has {size} bytes, expected {ctypes.sizeof(_INT)}")
        self._fun = getattr(lib, name)
        self._fun.restype = ctypes.c_int
        self._fun.argtypes = [ctypes.POINTER(_DBL_P), ctypes.POINTER(_DBL_P), ctypes.POINTER(_INT), _DBL_P,
                              ctypes.c_int]
        work = getattr(lib, f"{name}_work")
        work.restype = ctypes.c_int
        sizes = [_INT() for _ in range(4)]
        if work(*[ctypes.byref(s) for s in sizes]) != 0:
            raise RuntimeError(f"{so_path}: {name}_work failed")
        sz_arg, sz_res, sz_iw, sz_w = (int(s.value) for s in sizes)
        #: What ``NAME_work`` reports: (sz_arg, sz_res, sz_iw, sz_w), for callers with their own work vectors.
        self.work_sizes = (sz_arg, sz_res, sz_iw, sz_w)
        #: The entry point's address, for C code that calls it through a function pointer.
        self.address = ctypes.cast(self._fun, ctypes.c_void_p).value
        incref = getattr(lib, f"{name}_incref", None)
        if incref is not None:
            incref.restype = None
            incref()
        self.inputs = [np.zeros(len(r)) for r, _ in self.sparsity_in]
        self.outputs = [np.zeros(len(r)) for r, _ in self.sparsity_out]
        self._arg = (_DBL_P * max(sz_arg, len(self.inputs)))()
        self._res = (_DBL_P * max(sz_res, len(self.outputs)))()
        for i, buf in enumerate(self.inputs):
            self._arg[i] = buf.ctypes.data_as(_DBL_P)
        for i, buf in enumerate(self.outputs):
            self._res[i] = buf.ctypes.data_as(_DBL_P)
        self._iw = (_INT * max(sz_iw, 1))()
        self._w = (ctypes.c_double * max(sz_w, 1))()
        self._lib = lib  # keep the library loaded as long as the buffers point into it

    def __call__(self) -> list[np.ndarray]:
        """Evaluate on the current :attr:`inputs`; returns :attr:`outputs` (the same arrays)."""
        if self._fun(self._arg, self._res, self._iw, self._w, 0) != 0:
            raise RuntimeError(f"{self.name}: evaluation failed")
        return self.outputs


def _prefix(name: str) -> str:
    """The codegen prefix of the shared helpers (``nlp_casadi_int_size`` for ``nlp_*`` functions)."""
    return name.split("_")[0] + "_"


def _triplet(sp: ca.Sparsity) -> tuple[np.ndarray, np.ndarray]:
    rows, cols = sp.get_triplet()
    return np.asarray(rows, dtype=np.int64), np.asarray(cols, dtype=np.int64)
