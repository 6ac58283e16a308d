"""The banded LDL^T of csrc/ipm.c (``ipm_band_test_solve``) against the banded LU on constructed
symmetric band matrices: the solutions agree, the inertia is the eigenvalues' signs, a zero pivot is
reported as a breakdown, and the refinement removes the quasi-definite regularisation."""

from __future__ import annotations

import ctypes

import numpy as np
import pytest

from mcverify.solver import kernels

_D, _I = ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_int)


@pytest.fixture(scope="module")
def lib():
    lib = ctypes.CDLL(str(kernels.get_runtime_library("ipm").so_path))
    lib.ipm_band_test_solve.restype = ctypes.c_int
    return lib


def band_solve(lib, A: np.ndarray, bw: int, b: np.ndarray, ldlt: bool, dual: np.ndarray, delta: float):
    """(return code, x, inertia (pos, neg), refinements, backward error) of the C band solvers."""
    n, ldab = A.shape[0], 3 * bw + 1
    ab = np.zeros((n, ldab))
    for j in range(n):
        for i in range(max(0, j - bw), min(n, j + bw + 1)):
            ab[j, 2 * bw + i - j] = A[i, j]
    x, inertia = np.zeros(n), np.zeros(2, np.int32)
    refinements, ratio = ctypes.c_int(), ctypes.c_double()
    work, iwork = np.zeros(ldab * n + 3 * n), np.zeros(n, np.int32)
    dual = np.ascontiguousarray(dual, np.int32)
    b = np.ascontiguousarray(b, float)
    rc = lib.ipm_band_test_solve(n, bw, int(ldlt), ab.ctypes.data_as(_D), dual.ctypes.data_as(_I),
                                 ctypes.c_double(delta), b.ctypes.data_as(_D), x.ctypes.data_as(_D),
                                 inertia.ctypes.data_as(_I), ctypes.byref(refinements), ctypes.byref(ratio),
                                 work.ctypes.data_as(_D), iwork.ctypes.data_as(_I))
    return rc, x, tuple(int(v) for v in inertia), refinements.value, ratio.value


def kkt_like(rng, n_w: int, n_g: int, bw: int, convex: bool = True):
    """A symmetric matrix [[H, J^T], [J, -D]] with its unknowns shuffled into a band of half-width bw
    (H positive definite when convex, D > 0), and which unknowns are constraint rows."""
    n = n_w + n_g
    dual = np.zeros(n, bool)
    dual[rng.choice(n, n_g, replace=False)] = True
    A = np.zeros((n, n))
    for i in range(n):
        for j in range(max(0, i - bw), i):
            if dual[i] and dual[j]:
                continue  # the constraint block is diagonal
            if rng.random() < 0.5:
                A[i, j] = A[j, i] = rng.normal()
    w = np.flatnonzero(~dual)
    H = A[np.ix_(w, w)]
    shift = np.abs(H).sum(1) + rng.uniform(0.5, 2.0, w.size)  # diagonally dominant: positive definite
    A[w, w] = shift if convex else rng.normal(size=w.size)
    g = np.flatnonzero(dual)
    A[g, g] = -rng.uniform(0.1, 2.0, g.size)
    return A, dual


@pytest.mark.parametrize("seed", range(5))
def test_ldlt_solution_equals_the_lu_solution_on_quasi_definite_band_matrices(lib, seed):
    rng = np.random.default_rng(seed)
    A, dual = kkt_like(rng, 40, 30, 6)
    b = rng.normal(size=A.shape[0])
    rc_lu, x_lu, *_ = band_solve(lib, A, 6, b, False, dual, 0.0)
    rc, x, inertia, _, ratio = band_solve(lib, A, 6, b, True, dual, 1e-9)
    assert rc_lu == 0 and rc == 0
    assert np.max(np.abs(x - x_lu)) <= 1e-10 * np.max(np.abs(x_lu))
    assert np.max(np.abs(A @ x - b)) <= 1e-12 * (np.abs(A).sum(1).max() * np.max(np.abs(x)) + np.max(np.abs(b)))
    assert ratio <= 1e-12
    assert inertia == (40, 30)  # quasi-definite: n_w positive, n_g negative pivots


@pytest.mark.parametrize("seed", range(5))
def test_inertia_is_the_eigenvalue_signs_of_an_indefinite_matrix(lib, seed):
    rng = np.random.default_rng(100 + seed)
    A, dual = kkt_like(rng, 25, 15, 5, convex=False)
    b = rng.normal(size=A.shape[0])
    rc, x, inertia, _, _ = band_solve(lib, A, 5, b, True, dual, 1e-9)
    assert rc == 0
    reg = A + 1e-9 * np.diag(np.where(dual, -1.0, 1.0))  # the matrix factorised
    eig = np.linalg.eigvalsh(reg)
    assert inertia == (int(np.sum(eig > 0)), int(np.sum(eig < 0)))
    assert np.allclose(A @ x, b, atol=1e-8 * np.max(np.abs(b)))


def test_zero_pivot_is_a_breakdown_not_garbage(lib):
    # [[0, 1], [1, 0]] in band order without regularisation: the first pivot is exactly 0
    A = np.array([[0.0, 1.0], [1.0, 0.0]])
    rc, *_ = band_solve(lib, A, 1, np.ones(2), True, np.array([0, 1]), 0.0)
    assert rc == 1  # 1-based column of the zero pivot
    # the LU pivots past it; the regularised LDL^T factorises and the refinement recovers A's solution
    assert band_solve(lib, A, 1, np.array([1.0, 2.0]), False, np.array([0, 1]), 0.0)[0] == 0
    rc, x, inertia, refinements, _ = band_solve(lib, A, 1, np.array([1.0, 2.0]), True, np.array([0, 1]), 1e-9)
    assert rc == 0 and inertia == (1, 1) and refinements >= 1
    assert np.allclose(x, [2.0, 1.0], rtol=0, atol=1e-14)


def test_refinement_removes_the_regularisation(lib):
    # an equality-constrained QP's KKT matrix: no dual diagonal, so the LDL^T needs delta
    rng = np.random.default_rng(7)
    A, dual = kkt_like(rng, 30, 12, 4)
    A[dual, dual] = 0.0
    b = rng.normal(size=A.shape[0])
    x_exact = np.linalg.solve(A, b)
    rc, x, inertia, refinements, _ = band_solve(lib, A, 4, b, True, dual, 1e-6)
    assert rc == 0 and inertia == (30, 12)
    assert refinements >= 1
    assert np.max(np.abs(x - x_exact)) <= 1e-10 * np.max(np.abs(x_exact))


def test_singular_matrix_fails_the_refinement_or_breaks_down(lib):
    A = np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, -1.0]])  # rank 2
    rc, *_ = band_solve(lib, A, 1, np.array([1.0, 0.0, 1.0]), True, np.array([0, 0, 1]), 1e-9)
    assert rc != 0


def dgbtf2_solve(A: np.ndarray, bw: int, b: np.ndarray) -> np.ndarray:
    """LAPACK's dgbtf2 + dgbtrs in numpy, every row update over the whole lower band (no extents), in
    the operation order of the C band LU: products and differences rounded one by one, as in C built
    without FMA."""
    n, kl, kv = A.shape[0], bw, 2 * bw
    ab = np.zeros((n, 3 * bw + 1))  # ab[c, kv + r - c] = A[r, c]
    for c in range(n):
        for r in range(max(0, c - bw), min(n, c + bw + 1)):
            ab[c, kv + r - c] = A[r, c]
    ipiv, ju = np.zeros(n, int), 0
    for j in range(n):
        km = min(kl, n - 1 - j)
        col = ab[j, kv:kv + km + 1]
        jp, amax = 0, abs(col[0])
        for i in range(1, km + 1):
            if abs(col[i]) > amax:
                amax, jp = abs(col[i]), i
        ipiv[j] = j + jp
        ju = max(ju, min(j + bw + jp, n - 1))
        if jp:
            for c in range(j, ju + 1):
                o = kv + j - c
                ab[c, o], ab[c, o + jp] = ab[c, o + jp], ab[c, o]
        if km:
            col[1:] *= 1.0 / col[0]
            for c in range(j + 1, ju + 1):
                o = kv + j - c
                if ab[c, o] != 0.0:
                    ab[c, o + 1:o + km + 1] -= col[1:] * ab[c, o]
    x = b.copy()
    for j in range(n - 1):
        km = min(kl, n - 1 - j)
        x[j], x[ipiv[j]] = x[ipiv[j]], x[j]
        if x[j] != 0.0:
            x[j + 1:j + km + 1] -= ab[j, kv + 1:kv + km + 1] * x[j]
    for j in range(n - 1, -1, -1):
        x[j] /= ab[j, kv]
        if x[j] != 0.0:
            i0 = max(0, j - kv)
            x[i0:j] -= ab[j, kv - (j - i0):kv] * x[j]
    return x


@pytest.mark.parametrize("seed", range(4))
def test_band_lu_with_column_extents_is_dgbtf2_bit_for_bit(lib, seed):
    """The C LU restricts each column's update to its structural extent (fill_extents); on indefinite
    KKT-like matrices with zeros inside the band (so rows are swapped and extents vary) its solution
    is the same bits as dgbtf2's over the whole band."""
    rng = np.random.default_rng(300 + seed)
    A, dual = kkt_like(rng, 30, 20, 6, convex=False)
    b = rng.normal(size=A.shape[0])
    rc, x, *_ = band_solve(lib, A, 6, b, False, dual, 0.0)
    ref = dgbtf2_solve(A, 6, b)
    assert rc == 0
    assert np.array_equal(x, ref)
    assert np.allclose(A @ x, b, atol=1e-8 * np.max(np.abs(b)))
