"""A warm-started SQP for the TO-CBF-MPC NLP: exact Hessian, primal-dual active-set QPs, banded KKT.

The problem is whatever :func:`mcverify.ocp.build_nlp` returns, seen through its compiled kernel
(``nlp_g``, ``nlp_grad_f``, ``nlp_jac_g``, ``nlp_hess_l``)::

    min f(w, p)   s.t.   lbg <= g(w, p) <= ubg,   lbx <= w <= ubx.

Multipliers follow CasADi/IPOPT: L = f + lam_g' g + lam_x' w, so an active lower bound has a
multiplier <= 0 and an active upper bound one >= 0.

One SQP iteration linearises at (w, lam) and solves the QP

    min_d  grad_f' d + 1/2 d' H d   s.t.  lbg <= g + J d <= ubg,  lbx <= w + d <= ubx

by a primal-dual active-set strategy: guess the active set (at first from the warm start's
multipliers), solve the equality-constrained QP of that guess as one linear KKT system, then move
constraints the step violates into the set and constraints with wrong-sign multipliers out of it,
until nothing changes. Near a solution the active set hardly changes from one control step to the
next, so this usually takes one or two KKT solves per iteration. The KKT matrix has a fixed
superset pattern (inactive rows become ``lam_i = 0``, variables at a bound become ``d_j = bound -
w_j``), which a reverse Cuthill-McKee ordering makes banded (bandwidth 16 for N = 50), so every
solve is one LAPACK ``dgbsv`` call (tens of microseconds).

Why not a library QP solver: measured on the same QPs, HPIPM through CasADi took 0.8 ms per QP
(7-8 interior-point iterations; it also requires a stage-wise Hessian, and the input-smoothing
term couples neighbouring stages), qrqp 50 ms, DAQP and qpOASES on the condensed (dense, 101
variables) QP 8-18 ms, and condensing alone 10 ms; see results/BENCHMARKS.md.

The initial-state rows are honoured exactly: rows of g with a single, constant Jacobian entry
(``X[:, 0] - x0 == 0``, ``t_0 == 0``) are applied to the linearisation point before the first QP
("initial value embedding"), so the step never moves those variables. See :mod:`mcverify.backends`
for why that makes the node-0 CBF row exact in every QP.

Everything is deterministic: fixed iteration order, no wall-clock dependence, single-threaded
LAPACK on fixed-size arrays.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.linalg import lapack
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import reverse_cuthill_mckee

from mcverify.cfun import CFunction
from mcverify.pasqp import PasQp

# Active-set states of a constraint row or a variable.
FREE, AT_LOWER, AT_UPPER, EQUALITY = 0, -1, 1, 2


@dataclass(frozen=True)
class SqpOptions:
    """Tolerances and limits of :class:`Sqp`.

    max_iter: SQP iterations (QPs) before giving up. max_passes: active-set passes (KKT solves)
    per QP. tol_viol: largest constraint or bound violation (unscaled units) of a converged point.
    tol_du: stationarity of a converged point, scaled as IPOPT scales its dual infeasibility.
    tol_step: largest step (any unit) of the last iteration of a converged point. tol_active:
    violation of a linearised constraint (row-scaled) or bound that puts it into the active set,
    and wrong-sign multiplier (row-scaled) that takes it out. reg_primal: added to the Hessian's
    diagonal (keeps the KKT matrix regular along directions of zero curvature, e.g. a constant
    acceleration offset on stages where it is not bounded).
    """

    max_iter: int = 6
    max_passes: int = 40
    tol_viol: float = 1e-6
    tol_du: float = 1e-6
    tol_step: float = 1e-5
    tol_active: float = 1e-9
    tol_slope: float = 1e-12
    reg_primal: float = 1e-6
    reg_dual: float = 0.0
    max_schur: int = 40


@dataclass(frozen=True)
class SqpResult:
    """What one :meth:`Sqp.solve` returns. Arrays are fresh copies."""

    w: np.ndarray  # (n_w,)
    lam_x: np.ndarray  # (n_w,)
    lam_g: np.ndarray  # (n_g,)
    success: bool
    status: str  # "Converged", "Max_Iterations", "QP_Failed: ...", "Nonfinite"
    iterations: int  # SQP iterations (QPs solved)
    kkt_solves: int  # KKT systems factorised (active-set passes over all QPs)
    max_violation: float
    dual_infeasibility: float


class Sqp:
    """The SQP on one compiled kernel. Not thread-safe (buffers are reused), deterministic.

    so_path: the kernel's shared object; lbx, ubx (n_w,), lbg, ubg (n_g,): the bounds (fixed for
    the solver's life; parameters p change per solve).
    """

    def __init__(
        self,
        so_path: str | Path,
        lbx: np.ndarray,
        ubx: np.ndarray,
        lbg: np.ndarray,
        ubg: np.ndarray,
        options: SqpOptions | None = None,
        qp_library: str | Path | None = None,
    ) -> None:
        self.opts = options or SqpOptions()
        self._g = CFunction(so_path, "nlp_g")
        self._fg = CFunction(so_path, "nlp_grad_f")
        self._jac = CFunction(so_path, "nlp_jac_g")
        self._hess = CFunction(so_path, "nlp_hess_l")
        self.lbx, self.ubx = np.asarray(lbx, float).copy(), np.asarray(ubx, float).copy()
        self.lbg, self.ubg = np.asarray(lbg, float).copy(), np.asarray(ubg, float).copy()
        self.n_w, self.n_g = self.lbx.size, self.lbg.size
        self.n_p = self._g.inputs[1].size
        self._equality = self.lbg == self.ubg
        self._fixed_var = self.lbx == self.ubx
        self._j_rows, self._j_cols = self._jac.sparsity_out[1]
        self._h_rows, self._h_cols = self._hess.sparsity_out[0]  # upper triangle, r <= c
        if np.any(self._h_rows > self._h_cols):
            raise ValueError("nlp_hess_l must return the upper triangle of the Hessian")
        self._fixing_rows, self._fixing_vars, self._fixing_coef = self._find_fixing_rows()
        self._setup_kkt()
        self._cqp = None
        if qp_library is not None:
            o = self.opts
            self._cqp = PasQp(qp_library, self.n_w, self.n_g, self.bandwidth, self._c_arrays, self._c_ent_pos,
                              o.tol_active, o.tol_slope, o.reg_primal, o.reg_dual, o.max_passes, o.max_schur)

    # ------------------------------------------------------------------------------ structure
    def _find_fixing_rows(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Equality rows g_i = a w_j - c(p) with one Jacobian entry, constant in w and p.

        Detected numerically: the entry is the only one of its row and has the same value at three
        pseudo-random points (a fixed seed, so the detection is deterministic).
        """
        counts = np.bincount(self._j_rows, minlength=self.n_g)
        single = np.flatnonzero((counts == 1) & self._equality)
        if single.size == 0:
            return (np.zeros(0, np.int64),) * 2 + (np.zeros(0),)
        nz_of_row = np.full(self.n_g, -1)
        nz_of_row[self._j_rows] = np.arange(self._j_rows.size)
        rng = np.random.default_rng(12345)
        values = []
        for _ in range(3):
            self._jac.inputs[0][:] = rng.uniform(-1.0, 1.0, self.n_w)
            self._jac.inputs[1][:] = rng.uniform(-1.0, 1.0, self.n_p)
            values.append(self._jac()[1][nz_of_row[single]].copy())
        constant = (values[0] == values[1]) & (values[1] == values[2]) & (values[0] != 0.0)
        rows = single[constant]
        return rows, self._j_cols[nz_of_row[rows]], values[0][constant]

    def _setup_kkt(self) -> None:
        """Index maps from the kernel's nonzeros into the banded KKT matrix (built once)."""
        n_w, n_g = self.n_w, self.n_g
        n = n_w + n_g
        hr, hc = self._h_rows, self._h_cols
        off = hr != hc
        # full symmetric Hessian entries, each pointing at its upper-triangle nonzero
        self._hs_src = np.concatenate([np.arange(hr.size), np.flatnonzero(off)])
        self._hs_row = np.concatenate([hr, hc[off]])
        self._hs_col = np.concatenate([hc, hr[off]])
        jr, jc = self._j_rows, self._j_cols
        idx_w, idx_g = np.arange(n_w), np.arange(n_g)
        rows = np.concatenate([self._hs_row, idx_w, jc, n_w + jr, n_w + idx_g])
        cols = np.concatenate([self._hs_col, idx_w, n_w + jr, jc, n_w + idx_g])
        pattern = coo_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n)).tocsr()
        pattern = pattern + pattern.T
        perm = reverse_cuthill_mckee(pattern, symmetric_mode=True)
        inv = np.empty(n, np.int64)
        inv[perm] = np.arange(n)
        pr, pc = inv[rows], inv[cols]
        bw = int(np.max(np.abs(pr - pc)))
        self.bandwidth = bw
        self._perm = perm
        ldab = 3 * bw + 1  # LAPACK dgbsv storage: 2 kl + ku + 1 rows, A[i, j] at ab[kl + ku + i - j, j]
        self._ab = np.zeros((ldab, n), order="F")
        self._ab_flat = self._ab.reshape(-1, order="F")
        pos = (2 * bw + pr - pc) + ldab * pc
        # sum duplicates (a Hessian diagonal entry and the regularisation share a position)
        self._slots, self._slot_of = np.unique(pos, return_inverse=True)
        self._n_h, self._n_j = self._hs_src.size, jr.size
        # the same entries grouped by row, for the C solver (pasqp.c)
        kinds = np.concatenate([
            np.zeros(self._hs_src.size), np.ones(n_w), np.full(jr.size, 2), np.full(jr.size, 3), np.full(n_g, 4),
        ]).astype(np.int32)
        srcs = np.concatenate([np.arange(self._hs_src.size), idx_w, np.arange(jr.size), np.arange(jr.size), idx_g])
        order = np.argsort(rows, kind="stable")
        self._c_arrays = {
            "j_rows": jr, "j_cols": jc,
            "jcol_ptr": np.searchsorted(jc[np.argsort(jc, kind="stable")], np.arange(n_w + 1)),
            "jcol_idx": np.argsort(jc, kind="stable"),
            "hs_row": self._hs_row, "hs_col": self._hs_col, "hs_src": self._hs_src,
            "perm": perm, "iperm": inv,
            "row_ptr": np.searchsorted(rows[order], np.arange(n + 1)),
            "ent_kind": kinds[order], "ent_src": srcs[order], "ent_col": cols[order],
        }
        self._c_ent_pos = pos[order].astype(np.int64)

    # ---------------------------------------------------------------------------------- solve
    def solve(self, p: np.ndarray, w0: np.ndarray, lam_x0: np.ndarray, lam_g0: np.ndarray) -> SqpResult:
        """Run the SQP from the primal-dual point (w0, lam_x0, lam_g0) for parameters p."""
        o = self.opts
        w = np.array(w0, dtype=float)
        lam_x = np.array(lam_x0, dtype=float)
        lam_g = np.array(lam_g0, dtype=float)
        if not (np.all(np.isfinite(w)) and np.all(np.isfinite(lam_x)) and np.all(np.isfinite(lam_g))):
            return self._result(w, lam_x, lam_g, False, "Nonfinite", 0, 0, np.inf, np.inf)
        self._g.inputs[1][:] = p
        self._fg.inputs[1][:] = p
        self._jac.inputs[1][:] = p
        self._hess.inputs[1][:] = p
        self._hess.inputs[2][0] = 1.0
        g0, jac0, _, _ = self._eval_first_order(w)
        con, var = self._initial_active_set(w, g0, self._row_scale(jac0), lam_x, lam_g)
        if self._fixing_rows.size:  # initial value embedding: satisfy the fixing rows exactly
            r = self._fixing_rows
            w[self._fixing_vars] -= (g0[r] - self.lbg[r]) / self._fixing_coef
        kkt_solves = 0
        step = np.inf
        for it in range(o.max_iter + 1):
            g, jac, f, grad = self._eval_first_order(w)
            if not (np.all(np.isfinite(g)) and np.all(np.isfinite(jac)) and np.all(np.isfinite(grad))):
                return self._result(w, lam_x, lam_g, False, "Nonfinite", it, kkt_solves, np.inf, np.inf)
            viol = self._violation(w, g)
            du = self._dual_infeasibility(grad, jac, lam_x, lam_g)
            if it > 0 and viol <= o.tol_viol and du <= o.tol_du:
                return self._result(w, lam_x, lam_g, True, "Converged", it, kkt_solves, viol, du)
            if it == o.max_iter:
                return self._result(w, lam_x, lam_g, False, "Max_Iterations", it, kkt_solves, viol, du)
            hess = self._eval_hessian(w, lam_g)
            if not np.all(np.isfinite(hess)):
                return self._result(w, lam_x, lam_g, False, "Nonfinite", it, kkt_solves, viol, du)
            qp = self._solve_qp(w, g, jac, grad, hess, con, var, lam_x, lam_g)
            kkt_solves += qp[-1]
            if qp[0] is None:
                return self._result(w, lam_x, lam_g, False, f"QP_Failed: {qp[1]}", it, kkt_solves, viol, du)
            d, lam_x, lam_g, con, var, _ = qp
            step = float(np.max(np.abs(d)))
            w = w + d
        raise AssertionError("unreachable")

    # ------------------------------------------------------------------------------ evaluation
    def _eval_g(self, w: np.ndarray) -> np.ndarray:
        self._g.inputs[0][:] = w
        return self._g()[0].copy()

    def _eval_first_order(self, w: np.ndarray):
        self._jac.inputs[0][:] = w
        g, jac = self._jac()
        self._fg.inputs[0][:] = w
        f, grad = self._fg()
        return g.copy(), jac.copy(), float(f[0]), grad.copy()

    def _eval_hessian(self, w: np.ndarray, lam_g: np.ndarray) -> np.ndarray:
        self._hess.inputs[0][:] = w
        self._hess.inputs[3][:] = lam_g
        return self._hess()[0].copy()

    def _violation(self, w: np.ndarray, g: np.ndarray) -> float:
        parts = (self.lbg - g, g - self.ubg, self.lbx - w, w - self.ubx)
        return max(0.0, *(float(np.max(v)) for v in parts))

    def _jt_times(self, jac: np.ndarray, lam_g: np.ndarray) -> np.ndarray:
        return np.bincount(self._j_cols, jac * lam_g[self._j_rows], minlength=self.n_w)

    def _dual_infeasibility(self, grad, jac, lam_x, lam_g) -> float:
        """max |grad f + J' lam_g + lam_x|, scaled by max(1, mean |multiplier| / 100) as IPOPT does."""
        r = grad + self._jt_times(jac, lam_g) + lam_x
        mean_abs = (np.sum(np.abs(lam_g)) + np.sum(np.abs(lam_x))) / (self.n_g + self.n_w)
        return float(np.max(np.abs(r))) / max(1.0, mean_abs / 100.0)

    # ------------------------------------------------------------------------------ active set
    def _initial_active_set(self, w, g, scale, lam_x, lam_g) -> tuple[np.ndarray, np.ndarray]:
        """Guess from the warm start: a bound is active if its multiplier has the sign of that bound
        and is larger than the slack (both row-scaled).

        IPOPT's multipliers of inactive constraints are tiny but not zero (about mu / slack), and
        at its tolerance the active ones keep slacks of ~1e-5 (input bounds) with multipliers of
        ~1e-2, so neither a slack nor a multiplier threshold alone separates them; their ratio does.
        """
        lam_s = lam_g / scale
        con = np.zeros(self.n_g, np.int8)
        con[(lam_s < 0) & (-lam_s >= (g - self.lbg) * scale)] = AT_LOWER
        con[(lam_s > 0) & (lam_s >= (self.ubg - g) * scale)] = AT_UPPER
        con[self._equality] = EQUALITY
        var = np.zeros(self.n_w, np.int8)
        var[(lam_x < 0) & (-lam_x >= w - self.lbx)] = AT_LOWER
        var[(lam_x > 0) & (lam_x >= self.ubx - w)] = AT_UPPER
        var[self._fixed_var] = EQUALITY
        self._drop_implied_bounds(con, var, lam_x)
        return con, var

    def _drop_implied_bounds(self, con: np.ndarray, var: np.ndarray, lam_x: np.ndarray) -> None:
        """Keep one active bound per group of bounds tied together by active rows on fixed variables.

        An IPOPT solution with every DT_i at dt_min has a multiplier on all 50 bounds, and the 49
        rows DT_{i+1} - DT_i = 0 tie them: the bounds are linearly dependent on the rows, their
        multipliers are not unique, and a working set with all of them would release them one at
        a time (50 factorisations) when T grows. The variables linked by active rows whose every
        entry is on a fixed variable form a group; only the bound with the largest multiplier in
        each group stays in the working set (the rows then pin the rest).
        """
        fixed = (var == AT_LOWER) | (var == AT_UPPER)
        act = con != FREE
        row_all_fixed = np.bincount(self._j_rows, ~(fixed | (var == EQUALITY))[self._j_cols], minlength=self.n_g) == 0
        rows = np.flatnonzero(act & row_all_fixed)
        if rows.size == 0:
            return
        parent = np.arange(self.n_w)

        def find(i: int) -> int:
            while parent[i] != i:
                parent[i] = parent[parent[i]]
                i = parent[i]
            return i

        in_rows = np.isin(self._j_rows, rows)
        for r in rows:
            cols = self._j_cols[in_rows & (self._j_rows == r)]
            cols = cols[fixed[cols]]
            for c in cols[1:]:
                a, b = find(int(cols[0])), find(int(c))
                if a != b:
                    parent[b] = a
        members: dict[int, list[int]] = {}
        for j in np.flatnonzero(fixed):
            members.setdefault(find(int(j)), []).append(int(j))
        for group in members.values():
            if len(group) > 1:
                keep = max(group, key=lambda j: (abs(lam_x[j]), -j))
                for j in group:
                    if j != keep:
                        var[j] = FREE

    def _row_scale(self, jac: np.ndarray) -> np.ndarray:
        """1 / max(1, max_j |J_ij|) per row: brings the CBF rows (gradients up to ~1e5 far from
        veh_f, where h^3 is large) to the size of the dynamics rows."""
        mx = np.zeros(self.n_g)
        np.maximum.at(mx, self._j_rows, np.abs(jac))
        return 1.0 / np.maximum(1.0, mx)

    def _solve_qp(self, w, g, jac, grad, hess, con, var, lam_x, lam_g):
        """The QP of one SQP iteration, by the C solver when loaded, else by the Python reference."""
        if self._cqp is None:
            return self._solve_qp_python(w, g, jac, grad, hess, con, var, lam_x, lam_g)
        s = self._row_scale(jac)
        js = jac * s[self._j_rows]
        con, var = con.copy(), var.copy()
        lam_s = lam_g / s
        lam_xc = lam_x.copy()
        d, status, passes, facts = self._cqp.solve(
            js, hess, grad, (self.lbg - g) * s, (self.ubg - g) * s, self.lbx - w, self.ubx - w,
            con, var, lam_s, lam_xc,
        )
        self.last_qp_stats = (passes, facts)
        if d is None:
            return None, status, passes
        return d, lam_xc, lam_s * s, con, var, passes

    def _solve_qp_python(self, w, g, jac, grad, hess, con, var, lam_x, lam_g):
        """Parametric active-set solve of the QP at w, warm-started from (con, var, lam_x, lam_g).

        The online active-set strategy of qpOASES (Ferreau, Bock, Diehl 2008) on the banded KKT
        system: QP(0) is the QP at w with its gradient and bounds changed so that d = 0 with the
        warm multipliers and working set is its solution; QP(tau), 0 <= tau <= 1, interpolates
        the vectors linearly to the actual QP(1). For a fixed working set the solution is affine in
        tau, so one factorisation gives the whole segment; the segment ends where an inactive
        constraint reaches its bound (it joins the working set) or an active inequality's
        multiplier reaches zero (it leaves), and the next segment starts there with one new
        factorisation. Adds and drops thus happen in the order the path meets them. A plain
        primal active-set method (ratio test on the primal step only, drops only at full steps)
        was tried first and wandered off: when a speed bound must join and the acceleration bound
        next to it must leave, adding the speed bound first makes the two nearly dependent, and the
        next steps ran metres along flat directions (the reduced Hessian has eigenvalues down to
        5e-5, the acceleration smoothing) collecting slip-angle bounds.

        Returns (d, lam_x, lam_g, con, var, kkt_solves) or (None, reason, kkt_solves).
        """
        o = self.opts
        tol = o.tol_active
        n_w, n_g = self.n_w, self.n_g
        s = self._row_scale(jac)
        js = jac * s[self._j_rows]  # row-scaled Jacobian nonzeros
        hs = hess[self._hs_src]
        con, var = con.copy(), var.copy()
        # QP(1): bounds of c = s * J d and of d
        lo1, up1 = (self.lbg - g) * s, (self.ubg - g) * s
        lox1, upx1 = self.lbx - w, self.ubx - w
        # warm multipliers restricted to the working set, with the sign of their bound
        lam0 = lam_g / s
        lam0 = np.where(con == AT_LOWER, np.minimum(lam0, 0.0), np.where(con == AT_UPPER, np.maximum(lam0, 0.0), lam0))
        lam0[con == FREE] = 0.0
        lamx0 = np.where(var == AT_LOWER, np.minimum(lam_x, 0.0), np.where(var == AT_UPPER, np.maximum(lam_x, 0.0), lam_x))
        lamx0[var == FREE] = 0.0
        # QP(0): stationary at d = 0 with those multipliers; active bounds through 0, others relaxed to hold 0
        grad0 = -(np.bincount(self._j_cols, js * lam0[self._j_rows], minlength=n_w) + lamx0)
        act0_c, act0_v = con != FREE, var != FREE
        lo0 = np.where(act0_c & (con != AT_UPPER), 0.0, np.minimum(lo1, 0.0))
        up0 = np.where(act0_c & (con != AT_LOWER), 0.0, np.maximum(up1, 0.0))
        lox0 = np.where(act0_v & (var != AT_UPPER), 0.0, np.minimum(lox1, 0.0))
        upx0 = np.where(act0_v & (var != AT_LOWER), 0.0, np.maximum(upx1, 0.0))
        dgrad, dlo, dup, dlox, dupx = grad - grad0, lo1 - lo0, up1 - up0, lox1 - lox0, upx1 - upx0
        tau = 0.0
        # changes made at the current tau: never undone at the same tau (anti-cycling in ties)
        frozen: set[int] = set()
        for npass in range(1, o.max_passes + 1):
            fact = self._kkt_factor(js, hs, con, var)
            if fact is None:
                return None, "singular KKT matrix", npass
            base = self._kkt_rhs(grad0, lo0, up0, lox0, upx0, con, var, fact)
            slope = self._kkt_rhs(dgrad, dlo, dup, dlox, dupx, con, var, fact)
            (d_b, l_b), (d_s, l_s) = self._kkt_backsolve(fact, base, slope)
            if not (np.all(np.isfinite(d_b)) and np.all(np.isfinite(d_s))):
                return None, "nonfinite step", npass
            c_b = np.bincount(self._j_rows, js * d_b[self._j_cols], minlength=n_g)
            c_s = np.bincount(self._j_rows, js * d_s[self._j_cols], minlength=n_g)
            lx_b = self._fixed_multipliers(grad0, hess, js, d_b, l_b, var)
            lx_s = self._fixed_multipliers(dgrad, hess, js, d_s, l_s, var)
            # where does each inequality condition cross zero on [tau, 1]? (value(t) = a + b t >= 0)
            # kinds: 0/1 row lower/upper joins, 2/3 variable lower/upper joins, 4/5 row leaves
            # (multiplier of a lower/upper row reaches 0), 6/7 variable leaves
            free_c, free_v = con == FREE, var == FREE
            conds = (
                (c_b - lo0, c_s - dlo, free_c), (up0 - c_b, dup - c_s, free_c),
                (d_b - lox0, d_s - dlox, free_v), (upx0 - d_b, dupx - d_s, free_v),
                (-l_b, -l_s, con == AT_LOWER), (l_b, l_s, con == AT_UPPER),
                (-lx_b, -lx_s, var == AT_LOWER), (lx_b, lx_s, var == AT_UPPER),
            )
            t_hit, which = 1.0, None
            for kind, (a, b, m) in enumerate(conds):
                cand = m & (b < -o.tol_slope)
                if not cand.any():
                    continue
                with np.errstate(divide="ignore", invalid="ignore"):
                    t = np.where(cand, -a / b, np.inf)
                # a condition already (numerically) at zero at tau and decreasing blocks right here
                t = np.where(cand & (a + b * tau <= tol), tau, t)
                t = np.where(t < tau, np.inf, t)
                offset = 0 if kind in (0, 1, 4, 5) else n_g
                if frozen:
                    for i in frozen:
                        if 0 <= i - offset < t.size:
                            t[i - offset] = np.inf
                k = int(np.argmin(t))
                if t[k] < t_hit or (which is None and t[k] < 1.0):
                    t_hit, which = float(t[k]), (kind, k)
            if which is None:
                tau = 1.0
                d = d_b + d_s
                lam_gn = np.where(con == FREE, 0.0, (l_b + l_s) * s)
                lam_xn = np.where(var == FREE, 0.0, lx_b + lx_s)
                return d, lam_xn, lam_gn, con, var, npass
            if t_hit > tau:
                frozen.clear()
            tau = t_hit
            kind, k = which
            if kind in (0, 1):
                con[k] = AT_LOWER if kind == 0 else AT_UPPER
            elif kind in (2, 3):
                var[k] = AT_LOWER if kind == 2 else AT_UPPER
            elif kind in (4, 5):
                con[k] = FREE
            else:
                var[k] = FREE
            frozen.add(k if kind in (0, 1, 4, 5) else n_g + k)
        return None, "active set not settled", o.max_passes

    def _fixed_multipliers(self, grad, hess, js, d, lam_scaled, var) -> np.ndarray:
        """Bound multipliers of the fixed variables from stationarity (0 on free variables)."""
        stat = grad + self._h_times(hess, d) + np.bincount(self._j_cols, js * lam_scaled[self._j_rows], minlength=self.n_w)
        return np.where(var != FREE, -stat, 0.0)

    def _h_times(self, hess: np.ndarray, d: np.ndarray) -> np.ndarray:
        return np.bincount(self._hs_row, hess[self._hs_src] * d[self._hs_col], minlength=self.n_w)

    def _kkt_factor(self, js, hs, con, var):
        """Banded LU of the KKT matrix of the working set (con, var); None if singular.

        Rows of free variables: H d + J' lam = rhs; rows of fixed variables: d_j = rhs; rows of
        active constraints: J_i d = rhs; rows of inactive ones: lam_i = 0. Active rows whose every
        Jacobian entry sits on a fixed variable are left out (multiplier 0): they are implied by
        the fixings (e.g. Q2 "already behind veh_f", every DT_i at dt_min and the rows
        DT_{i+1} - DT_i = 0 on top) and would make the matrix singular. If it is singular anyway
        (other dependent active rows), it is factorised once more with a tiny dual regularisation,
        which picks one of the multiplier vectors.
        """
        free_w = var == FREE
        act = con != FREE
        free_cols = np.bincount(self._j_rows, free_w[self._j_cols], minlength=self.n_g)
        act = act & (free_cols > 0)
        base = [
            hs * free_w[self._hs_row],  # Hessian rows of free variables
            np.where(free_w, self.opts.reg_primal, 1.0),  # regularisation / fixed-variable rows
            js * free_w[self._j_cols],  # J' in the rows of free variables
            js * act[self._j_rows],  # J in the rows of active constraints
        ]
        bw = self.bandwidth
        for reg_dual in (self.opts.reg_dual, 1e-10):
            weights = np.concatenate([*base, np.where(act, -reg_dual, 1.0)])  # lam_i = 0 if inactive
            values = np.bincount(self._slot_of, weights, minlength=self._slots.size)
            ab = np.zeros(self._ab.shape, order="F")
            ab.reshape(-1, order="F")[self._slots] = values
            lu, piv, info = lapack.dgbtrf(ab, bw, bw, overwrite_ab=True)
            if info == 0:
                return lu, piv, act
        return None

    def _kkt_rhs(self, grad, lo, up, lox, upx, con, var, fact) -> np.ndarray:
        """Right-hand side for gradient ``grad`` and (row-scaled) bounds, in the unpermuted order."""
        act = fact[2]
        n_w = self.n_w
        rhs = np.empty(n_w + self.n_g)
        rhs[:n_w] = np.where(var == FREE, -grad, np.where(var == AT_UPPER, upx, lox))
        rhs[n_w:] = np.where(act, np.where(con == AT_UPPER, up, lo), 0.0)
        return rhs

    def _kkt_backsolve(self, fact, *rhss):
        lu, piv, _ = fact
        bw = self.bandwidth
        b = np.stack([r[self._perm] for r in rhss], axis=1)
        x, info = lapack.dgbtrs(lu, bw, bw, b, piv)
        out = []
        for k in range(len(rhss)):
            sol = np.empty(self.n_w + self.n_g)
            sol[self._perm] = x[:, k]
            out.append((sol[: self.n_w], sol[self.n_w:]))
        return out

    def _result(self, w, lam_x, lam_g, success, status, iterations, kkt_solves, viol, du) -> SqpResult:
        return SqpResult(
            w=np.array(w), lam_x=np.array(lam_x), lam_g=np.array(lam_g), success=bool(success),
            status=status, iterations=int(iterations), kkt_solves=int(kkt_solves),
            max_violation=float(viol), dual_infeasibility=float(du),
        )
