"""The banded KKT structure of a compiled TO-CBF-MPC kernel, derived from its sparsity alone.

For the NLP ``min f(w, p) s.t. lbg <= g(w, p) <= ubg, lbx <= w <= ubx`` of
:func:`mcverify.ocp.problem.build_nlp`, a Newton step of an interior-point method solves

    [ H + Sigma_x   J^T ] [dx]   [r_x]
    [ J             -D  ] [dy] = [r_y]       (n = n_w + n_g unknowns)

whose pattern is fixed: the Lagrangian Hessian's (``nlp_hess_l``, upper triangle in the kernel),
a diagonal, the constraint Jacobian's (``nlp_jac_g``) and its transpose. Nothing here knows the
layout of w or g: the structure is read from the kernel's sparsity patterns, so it follows
whatever rows and variables ``build_nlp`` writes (e.g. the lead's opposing-vehicle rows).

* A reverse Cuthill-McKee ordering of that pattern makes the matrix banded: the stage-wise
  structure of the OCP (every row couples one stage to the next; the input-smoothing term couples
  neighbouring inputs) gives bandwidth 16 for N = 50 (n = 762). A banded LU costs
  O(n bw^2), about 85 us here; a general sparse LU (SuperLU through scipy) took 1.4 ms, MUMPS
  inside IPOPT about 0.5 ms of each 1.3-1.8 ms IPOPT iteration.
* "Fixing rows": equality rows with a single Jacobian entry whose value is the same at any
  (w, p) are the initial-state rows (``X[:, 0] - x0 == 0``, ``t_0 == 0``); a solver applies them
  to its starting point (initial value embedding), see :mod:`mcverify.solver.backends` for what that
  buys for the node-0 CBF row.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import reverse_cuthill_mckee

from mcverify.solver.cfun import CFunction

#: Kinds of KKT entries (the C solver fills each from its source): ``enum ipm_entry_kind`` of csrc/ipm.h.
KIND_HESSIAN, KIND_PRIMAL_DIAG, KIND_JAC_T, KIND_JAC, KIND_DUAL_DIAG = 0, 1, 2, 3, 4


@dataclass(frozen=True)
class KktStructure:
    """Index maps of the banded KKT system of one kernel (all int arrays, 0-based).

    j_rows, j_cols (nnz_J,): the Jacobian's nonzeros in the kernel's (CCS) output order.
    h_rows, h_cols (nnz_H,): the Hessian's upper-triangle nonzeros in output order.
    hs_row, hs_col, hs_src (nnz_Hs,): the full symmetric Hessian, each entry pointing at its
    upper-triangle nonzero. perm (n,): band position k holds unknown perm[k]; bandwidth: the
    half-bandwidth after the ordering. ent_kind, ent_src, ent_row (n_ent,): every KKT entry with
    its kind (KIND_*) and source index (into hs_* for the Hessian, into j_* for J and J^T, the
    variable or row for the diagonals); ent_pos: its flat position in LAPACK band storage
    (column-major, 3 bw + 1 rows, A[i, j] at row 2 bw + i - j). fix_row, fix_var, fix_coef: the
    fixing rows, g_i = fix_coef * w[fix_var] - c(p).
    """

    n_w: int
    n_g: int
    n_p: int
    bandwidth: int
    j_rows: np.ndarray
    j_cols: np.ndarray
    h_rows: np.ndarray
    h_cols: np.ndarray
    hs_row: np.ndarray
    hs_col: np.ndarray
    hs_src: np.ndarray
    perm: np.ndarray
    ent_kind: np.ndarray
    ent_src: np.ndarray
    ent_row: np.ndarray
    ent_pos: np.ndarray
    fix_row: np.ndarray
    fix_var: np.ndarray
    fix_coef: np.ndarray

    @property
    def n(self) -> int:
        return self.n_w + self.n_g

    @classmethod
    def of_kernel(cls, so_path: str | Path, equality: np.ndarray) -> KktStructure:
        """Read the patterns from the kernel's ``nlp_jac_g`` and ``nlp_hess_l``.

        equality (n_g,) bool: which rows are equalities (lbg == ubg); fixing rows are among them.
        """
        jac = CFunction(so_path, "nlp_jac_g")
        hess = CFunction(so_path, "nlp_hess_l")
        n_w, n_p = jac.inputs[0].size, jac.inputs[1].size
        n_g = jac.outputs[0].size
        jr, jc = jac.sparsity_out[1]
        hr, hc = hess.sparsity_out[0]
        if np.any(hr > hc):
            raise ValueError("nlp_hess_l must return the upper triangle of the Hessian")
        off = hr != hc
        hs_src = np.concatenate([np.arange(hr.size), np.flatnonzero(off)])
        hs_row = np.concatenate([hr, hc[off]])
        hs_col = np.concatenate([hc, hr[off]])
        n = n_w + n_g
        idx_w, idx_g = np.arange(n_w), np.arange(n_g)
        rows = np.concatenate([hs_row, idx_w, jc, n_w + jr, n_w + idx_g])
        cols = np.concatenate([hs_col, idx_w, n_w + jr, jc, n_w + idx_g])
        kinds = np.concatenate([
            np.full(hs_src.size, KIND_HESSIAN), np.full(n_w, KIND_PRIMAL_DIAG), np.full(jr.size, KIND_JAC_T),
            np.full(jr.size, KIND_JAC), np.full(n_g, KIND_DUAL_DIAG),
        ])
        srcs = np.concatenate([np.arange(hs_src.size), idx_w, np.arange(jr.size), np.arange(jr.size), idx_g])
        pattern = coo_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n)).tocsr()
        perm = reverse_cuthill_mckee(pattern + pattern.T, symmetric_mode=True).astype(np.int64)
        inv = np.empty(n, np.int64)
        inv[perm] = np.arange(n)
        pr, pc = inv[rows], inv[cols]
        bw = int(np.max(np.abs(pr - pc)))
        pos = (2 * bw + pr - pc) + (3 * bw + 1) * pc
        fix_row, fix_var, fix_coef = _fixing_rows(jac, np.asarray(equality, bool), n_w, n_p, n_g)
        return cls(
            n_w=n_w, n_g=n_g, n_p=n_p, bandwidth=bw, j_rows=jr, j_cols=jc, h_rows=hr, h_cols=hc,
            hs_row=hs_row, hs_col=hs_col, hs_src=hs_src, perm=perm, ent_kind=kinds, ent_src=srcs,
            ent_row=rows, ent_pos=pos.astype(np.int64), fix_row=fix_row, fix_var=fix_var, fix_coef=fix_coef,
        )


def _fixing_rows(jac: CFunction, equality: np.ndarray, n_w: int, n_p: int, n_g: int):
    """Equality rows with one Jacobian entry, the same at three pseudo-random points (fixed seed)."""
    j_rows, j_cols = jac.sparsity_out[1]
    counts = np.bincount(j_rows, minlength=n_g)
    single = np.flatnonzero((counts == 1) & equality)
    if single.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    nz_of_row = np.full(n_g, -1)
    nz_of_row[j_rows] = np.arange(j_rows.size)
    rng = np.random.default_rng(12345)
    values = []
    for _ in range(3):
        jac.inputs[0][:] = rng.uniform(-1.0, 1.0, n_w)
        jac.inputs[1][:] = rng.uniform(-1.0, 1.0, n_p)
        values.append(jac()[1][nz_of_row[single]].copy())
    constant = (values[0] == values[1]) & (values[1] == values[2]) & (values[0] != 0.0)
    rows = single[constant]
    return rows, j_cols[nz_of_row[rows]], values[0][constant]
