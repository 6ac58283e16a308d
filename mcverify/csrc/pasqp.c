/*
 * pasqp.c - parametric active-set QP on a banded KKT system, for the SQP of mcverify/sqp.py.
 *
 * This is the C version of Sqp._solve_qp_python (same algorithm, same conventions; see the Python
 * docstrings for the why). The only algorithmic difference is how the KKT systems are solved:
 * one banded LU of a base matrix K0, and every working-set change since then (each one replaces
 * a row of the fixed-size KKT matrix) is handled by the Sherman-Morrison-Woodbury formula with a
 * small dense Schur complement, so a change costs two band back-substitutions instead of a
 * factorisation. The base is refactorised when the Schur complement reaches max_schur rows or
 * becomes ill-conditioned.
 *
 * KKT matrix (n = n_w + n_g, unknowns [d; lam~], lam~ = row-scaled multipliers):
 *   row j < n_w, variable free:    H_j. d + (J~^T)_j. lam~ + reg_primal d_j = rhs_j
 *   row j < n_w, variable fixed:   d_j = rhs_j
 *   row n_w+i, row effectively active (active and at least one free variable in it):
 *                                  J~_i. d - reg_dual lam~_i = rhs_i
 *   row n_w+i, otherwise:          lam~_i = 0
 * Every entry of a row depends only on that row's own flag (free / effectively active), so a
 * change of working set replaces whole rows.
 *
 * All arrays are in the original (unpermuted) order except the band storage, which holds the
 * reverse-Cuthill-McKee-permuted matrix in LAPACK dgbtrf layout (ldab = 3 bw + 1).
 * Deterministic: fixed loop orders, no threads, no allocation (workspace from the caller).
 */
#include <math.h>
#include <stdint.h>
#include <string.h>

#define FREE 0
#define AT_LOWER (-1)
#define AT_UPPER 1
#define EQUALITY 2

typedef struct {
  int n_w, n_g, n, bw, ldab;
  int n_j;                 /* Jacobian nonzeros */
  const int *j_rows, *j_cols;
  const int *jcol_ptr, *jcol_idx; /* Jacobian nonzeros by column (CSC over n_w columns) */
  int n_hs;                /* full symmetric Hessian entries */
  const int *hs_row, *hs_col, *hs_src;
  const int *perm, *iperm; /* perm[k]: original index at band position k; iperm: inverse */
  const int *row_ptr;      /* KKT entries grouped by original row (n + 1) */
  const int *ent_kind;     /* 0 H, 1 primal diagonal, 2 J~^T, 3 J~, 4 dual diagonal */
  const int *ent_src;      /* index into hess (via hs_src) / js */
  const int *ent_col;      /* original column */
  const int64_t *ent_pos;  /* flat band position of the entry (column-major, ldab rows) */
} qp_struct;

typedef struct {
  double tol, tol_slope, reg_primal, reg_dual;
  int max_passes, max_schur;
} qp_opts;

typedef struct {
  int passes, factorisations, status; /* status 0 ok, 1 singular, 2 not settled, 3 nonfinite */
} qp_stats;

/* ------------------------------------------------------------------------------ band LU ---- */

/* LU with partial pivoting of an n x n band matrix (kl = ku = bw), LAPACK dgbtf2 semantics. */
static int band_lu(double *ab, int n, int bw, int ldab, int *ipiv) {
  const int kl = bw, kv = 2 * bw; /* kv = ku + kl: row of the diagonal in ab */
  int ju = 0;
  /* zero the fill-in rows (LAPACK does this for the first columns) */
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < kl; ++i) ab[i + (int64_t)ldab * j] = 0.0;
  for (int j = 0; j < n; ++j) {
    int km = kl < n - 1 - j ? kl : n - 1 - j;
    double *col = ab + (int64_t)ldab * j + kv; /* col[i] = A[j + i, j] */
    int jp = 0;
    double amax = fabs(col[0]);
    for (int i = 1; i <= km; ++i)
      if (fabs(col[i]) > amax) { amax = fabs(col[i]); jp = i; }
    ipiv[j] = j + jp;
    if (col[jp] == 0.0) return j + 1;
    int jlast = j + bw + jp; /* the swapped-in row reaches ku = bw columns past its diagonal */
    if (jlast > n - 1) jlast = n - 1;
    if (jlast > ju) ju = jlast;
    if (jp != 0) { /* swap rows j and j + jp in columns j..ju */
      for (int c = j; c <= ju; ++c) {
        double *a = ab + (int64_t)ldab * c + kv + j - c;
        double t = a[0]; a[0] = a[jp]; a[jp] = t;
      }
    }
    if (km > 0) {
      double inv = 1.0 / col[0];
      for (int i = 1; i <= km; ++i) col[i] *= inv;
      for (int c = j + 1; c <= ju; ++c) {
        double *a = ab + (int64_t)ldab * c + kv + j - c; /* a[i] = A[j + i, c] */
        double f = a[0];
        if (f != 0.0)
          for (int i = 1; i <= km; ++i) a[i] -= col[i] * f;
      }
    }
  }
  return 0;
}

/* Solve with the band LU, in place, on a vector in band (permuted) order. */
static void band_solve(const double *ab, int n, int bw, int ldab, const int *ipiv, double *b) {
  const int kl = bw, kv = 2 * bw;
  for (int j = 0; j < n - 1; ++j) {
    int km = kl < n - 1 - j ? kl : n - 1 - j;
    int l = ipiv[j];
    if (l != j) { double t = b[l]; b[l] = b[j]; b[j] = t; }
    double bj = b[j];
    if (bj != 0.0) {
      const double *col = ab + (int64_t)ldab * j + kv;
      for (int i = 1; i <= km; ++i) b[j + i] -= col[i] * bj;
    }
  }
  for (int j = n - 1; j >= 0; --j) {
    const double *col = ab + (int64_t)ldab * j + kv; /* col[i - j] = U[i, j] */
    b[j] /= col[0];
    double bj = b[j];
    if (bj != 0.0) {
      int i0 = j - kv; if (i0 < 0) i0 = 0;
      for (int i = i0; i < j; ++i) b[i] -= col[i - j] * bj;
    }
  }
}

/* ------------------------------------------------------------------------------ helpers ---- */

typedef struct {
  const qp_struct *st;
  const qp_opts *o;
  const double *js, *hess;
  const signed char *con, *var;
  const int *nfree;
  double reg_dual;
} row_ctx;

/* the row flag: free variable / effectively active row */
static int row_flag(const row_ctx *c, int r) {
  const qp_struct *st = c->st;
  if (r < st->n_w) return c->var[r] == FREE;
  int i = r - st->n_w;
  return c->con[i] != FREE && c->nfree[i] > 0;
}

static double entry_value(const row_ctx *c, int e, int flag) {
  const qp_struct *st = c->st;
  switch (st->ent_kind[e]) {
    case 0: return flag ? c->hess[st->hs_src[st->ent_src[e]]] : 0.0;
    case 1: return flag ? c->o->reg_primal : 1.0;
    case 2: return flag ? c->js[st->ent_src[e]] : 0.0;
    case 3: return flag ? c->js[st->ent_src[e]] : 0.0;
    default: return flag ? -c->reg_dual : 1.0;
  }
}

static void assemble(const row_ctx *c, const signed char *flags, double *ab) {
  const qp_struct *st = c->st;
  memset(ab, 0, sizeof(double) * (size_t)st->ldab * (size_t)st->n);
  for (int r = 0; r < st->n; ++r)
    for (int e = st->row_ptr[r]; e < st->row_ptr[r + 1]; ++e)
      ab[st->ent_pos[e]] += entry_value(c, e, flags[r]);
}

/* x (original order) = K0^-1 b (original order), tmp: n doubles */
static void base_solve(const qp_struct *st, const double *ab, const int *ipiv, const double *b, double *x,
                       double *tmp) {
  for (int k = 0; k < st->n; ++k) tmp[k] = b[st->perm[k]];
  band_solve(ab, st->n, st->bw, st->ldab, ipiv, tmp);
  for (int k = 0; k < st->n; ++k) x[st->perm[k]] = tmp[k];
}

/* dense LU with partial pivoting of the m x m matrix S (row-major, leading dim ld); 0 if ok */
static int dense_lu(double *S, int m, int ld, int *piv, double rcond_min) {
  double dmax = 0.0, dmin = INFINITY;
  for (int k = 0; k < m; ++k) {
    int p = k; double amax = fabs(S[k * ld + k]);
    for (int i = k + 1; i < m; ++i) if (fabs(S[i * ld + k]) > amax) { amax = fabs(S[i * ld + k]); p = i; }
    piv[k] = p;
    if (amax == 0.0) return 1;
    if (p != k) for (int c = 0; c < m; ++c) { double t = S[k * ld + c]; S[k * ld + c] = S[p * ld + c]; S[p * ld + c] = t; }
    double inv = 1.0 / S[k * ld + k];
    for (int i = k + 1; i < m; ++i) {
      double f = (S[i * ld + k] *= inv);
      if (f != 0.0) for (int c = k + 1; c < m; ++c) S[i * ld + c] -= f * S[k * ld + c];
    }
    if (amax > dmax) dmax = amax;
    if (amax < dmin) dmin = amax;
  }
  return (m > 0 && dmin < rcond_min * dmax) ? 2 : 0;
}

static void dense_solve(const double *S, int m, int ld, const int *piv, double *t) {
  for (int k = 0; k < m; ++k) {
    int p = piv[k];
    if (p != k) { double x = t[k]; t[k] = t[p]; t[p] = x; }
    for (int i = k + 1; i < m; ++i) t[i] -= S[i * ld + k] * t[k];
  }
  for (int k = m - 1; k >= 0; --k) {
    for (int c = k + 1; c < m; ++c) t[k] -= S[k * ld + c] * t[c];
    t[k] /= S[k * ld + k];
  }
}


/* y = K x with the current row flags (original order) */
static void kkt_matvec(const row_ctx *c, const signed char *flags, const double *x, double *y) {
  const qp_struct *st = c->st;
  for (int r = 0; r < st->n; ++r) {
    double acc = 0.0;
    for (int e = st->row_ptr[r]; e < st->row_ptr[r + 1]; ++e) acc += entry_value(c, e, flags[r]) * x[st->ent_col[e]];
    y[r] = acc;
  }
}

/* ------------------------------------------------------------------------------ the solver --- */

/*
 * Workspace sizes (doubles / ints), see pasqp_work_sizes.
 * Inputs: js (n_j, row-scaled J), hess (triu nonzeros), grad (n_w), lo1/up1 (n_g, row-scaled
 * bounds of J~ d), lox1/upx1 (n_w). In/out: con (n_g), var (n_w) working set; lam (n_g, scaled
 * multipliers), lam_x (n_w). Out: d (n_w), stats.
 */
void pasqp_work_sizes(const qp_struct *st, const qp_opts *o, int64_t *n_dbl, int64_t *n_int) {
  int64_t n = st->n, m = o->max_schur;
  *n_dbl = (int64_t)st->ldab * n      /* ab */
           + 12 * n                   /* rhs/solution vectors */
           + 16 * (int64_t)st->n_w + 16 * (int64_t)st->n_g
           + m * n                    /* Y */
           + m * m + 2 * m;           /* S, t */
  *n_int = 3 * n + st->n_g + 4 * m + o->max_passes + 32;
}

int pasqp_solve(const qp_struct *st, const qp_opts *o, const double *js, const double *hess,
                const double *grad, const double *lo1, const double *up1, const double *lox1,
                const double *upx1, signed char *con, signed char *var, double *lam, double *lam_x,
                double *d, qp_stats *stats, double *wd, int *wi) {
  const int n_w = st->n_w, n_g = st->n_g, n = st->n, M = o->max_schur;
  /* ---- workspace ---- */
  double *ab = wd; wd += (int64_t)st->ldab * n;
  double *rb = wd; wd += n;   /* rhs base */
  double *rs = wd; wd += n;   /* rhs slope */
  double *xb = wd; wd += n;   /* solution base [d; lam~] */
  double *xs = wd; wd += n;
  double *tmp = wd; wd += n;
  double *ek = wd; wd += n;
  double *yb = wd; wd += n;
  double *ys = wd; wd += n;
  wd += 4 * n;
  double *grad0 = wd; wd += n_w;
  double *dgrad = wd; wd += n_w;
  double *lox0 = wd; wd += n_w;
  double *upx0 = wd; wd += n_w;
  double *dlox = wd; wd += n_w;
  double *dupx = wd; wd += n_w;
  double *lx_b = wd; wd += n_w;
  double *lx_s = wd; wd += n_w;
  double *hd = wd; wd += n_w;
  wd += 7 * n_w;
  double *lo0 = wd; wd += n_g;
  double *up0 = wd; wd += n_g;
  double *dlo = wd; wd += n_g;
  double *dup = wd; wd += n_g;
  double *c_b = wd; wd += n_g;
  double *c_s = wd; wd += n_g;
  double *lam0 = wd; wd += n_g;
  wd += 9 * n_g;
  double *Y = wd; wd += (int64_t)M * n;
  double *S = wd; wd += (int64_t)M * M;
  double *t1 = wd; wd += M;
  wd += M;
  int *ipiv = wi; wi += n;
  int *nfree = wi; wi += n_g;
  int *chg = wi; wi += M;      /* changed rows (original index) since the base factorisation */
  int *spiv = wi; wi += M;
  int *frozen = wi; wi += o->max_passes + 8;
  int *slot = wi; wi += M;     /* Y column of chg[a] */
  int *mark = wi; wi += n;     /* position of row r in chg, or -1 */
  signed char *flags0 = (signed char *)wi; wi += (n + 3) / 4 + 1; /* base row flags */
  signed char *flags = (signed char *)wi; wi += (n + 3) / 4 + 1;  /* current row flags */
  (void)M;

  stats->passes = 0; stats->factorisations = 0; stats->status = 0;
  const double tol = o->tol, tsl = o->tol_slope;

  /* ---- QP(0): warm multipliers restricted to the working set, sign-clipped ---- */
  for (int i = 0; i < n_g; ++i) {
    double l = lam[i];
    if (con[i] == FREE) l = 0.0;
    else if (con[i] == AT_LOWER && l > 0.0) l = 0.0;
    else if (con[i] == AT_UPPER && l < 0.0) l = 0.0;
    lam0[i] = l;
  }
  for (int j = 0; j < n_w; ++j) {
    double l = lam_x[j];
    if (var[j] == FREE) l = 0.0;
    else if (var[j] == AT_LOWER && l > 0.0) l = 0.0;
    else if (var[j] == AT_UPPER && l < 0.0) l = 0.0;
    grad0[j] = -l;
  }
  for (int e = 0; e < st->n_j; ++e) grad0[st->j_cols[e]] -= js[e] * lam0[st->j_rows[e]];
  for (int j = 0; j < n_w; ++j) dgrad[j] = grad[j] - grad0[j];
  for (int i = 0; i < n_g; ++i) {
    int a = con[i] != FREE;
    lo0[i] = (a && con[i] != AT_UPPER) ? 0.0 : fmin(lo1[i], 0.0);
    up0[i] = (a && con[i] != AT_LOWER) ? 0.0 : fmax(up1[i], 0.0);
    dlo[i] = lo1[i] - lo0[i]; dup[i] = up1[i] - up0[i];
    if (isinf(lo1[i])) dlo[i] = 0.0;
    if (isinf(up1[i])) dup[i] = 0.0;
  }
  for (int j = 0; j < n_w; ++j) {
    int a = var[j] != FREE;
    lox0[j] = (a && var[j] != AT_UPPER) ? 0.0 : fmin(lox1[j], 0.0);
    upx0[j] = (a && var[j] != AT_LOWER) ? 0.0 : fmax(upx1[j], 0.0);
    dlox[j] = lox1[j] - lox0[j]; dupx[j] = upx1[j] - upx0[j];
    if (isinf(lox1[j])) dlox[j] = 0.0;
    if (isinf(upx1[j])) dupx[j] = 0.0;
  }
  for (int i = 0; i < n_g; ++i) nfree[i] = 0;
  for (int e = 0; e < st->n_j; ++e) if (var[st->j_cols[e]] == FREE) nfree[st->j_rows[e]]++;

  for (int r = 0; r < n; ++r) mark[r] = -1;
  row_ctx ctx = {st, o, js, hess, con, var, nfree, o->reg_dual};
  int have_base = 0, m = 0, nfrozen = 0;
  double tau = 0.0;

  for (int pass = 1; pass <= o->max_passes; ++pass) {
    stats->passes = pass;
    for (int r = 0; r < n; ++r) flags[r] = (signed char)row_flag(&ctx, r);
    /* ---- changed rows relative to the base (their K0^-1 e_r columns are cached) ---- */
    int refactor = !have_base;
    if (!refactor) {
      int m2 = 0;
      for (int a = 0; a < m; ++a) { /* keep the rows that are still changed, in order */
        int r = chg[a];
        if (flags[r] != flags0[r]) { chg[m2] = r; slot[m2] = slot[a]; m2++; }
        else mark[r] = -1;
      }
      m = m2;
      for (int a = 0; a < m; ++a) mark[chg[a]] = a;
      for (int r = 0; r < n && !refactor; ++r) {
        if (flags[r] == flags0[r] || mark[r] >= 0) continue;
        if (m == M) { refactor = 1; break; }
        /* a free slot: the smallest slot index not used by chg[0..m-1] */
        int sl = 0;
        for (;; ++sl) { int taken = 0; for (int a = 0; a < m; ++a) if (slot[a] == sl) { taken = 1; break; } if (!taken) break; }
        memset(ek, 0, sizeof(double) * n);
        ek[r] = 1.0;
        base_solve(st, ab, ipiv, ek, Y + (int64_t)sl * n, tmp);
        chg[m] = r; slot[m] = sl; mark[r] = m; m++;
      }
    }
    for (int attempt = 0; attempt < 2; ++attempt) {
      if (refactor) {
        ctx.reg_dual = o->reg_dual;
        int info = 1;
        for (int k = 0; k < 2 && info != 0; ++k) {
          if (k == 1) ctx.reg_dual = 1e-10;
          assemble(&ctx, flags, ab);
          info = band_lu(ab, n, st->bw, st->ldab, ipiv);
          stats->factorisations++;
        }
        if (info != 0) { stats->status = 1; return 1; }
        memcpy(flags0, flags, (size_t)n);
        for (int a = 0; a < m; ++a) mark[chg[a]] = -1;
        have_base = 1; m = 0;
        break;
      }
      /* Schur complement S = I + Delta^T Y of the m changed rows */
      for (int a = 0; a < m; ++a) {
        int r = chg[a];
        for (int b = 0; b < m; ++b) {
          const double *yb_ = Y + (int64_t)slot[b] * n;
          double sv = (a == b) ? 1.0 : 0.0;
          for (int e = st->row_ptr[r]; e < st->row_ptr[r + 1]; ++e) {
            double delta = entry_value(&ctx, e, flags[r]) - entry_value(&ctx, e, flags0[r]);
            if (delta != 0.0) sv += delta * yb_[st->ent_col[e]];
          }
          S[a * M + b] = sv;
        }
      }
      if (dense_lu(S, m, M, spiv, 1e-10) == 0) break;
      refactor = 1;
    }
    /* ---- right-hand sides (base and slope) ---- */
    for (int j = 0; j < n_w; ++j) {
      if (var[j] == FREE) { rb[j] = -grad0[j]; rs[j] = -dgrad[j]; }
      else if (var[j] == AT_UPPER) { rb[j] = upx0[j]; rs[j] = dupx[j]; }
      else { rb[j] = lox0[j]; rs[j] = dlox[j]; }
    }
    for (int i = 0; i < n_g; ++i) {
      int r = n_w + i;
      if (!flags[r]) { rb[r] = 0.0; rs[r] = 0.0; }
      else if (con[i] == AT_UPPER) { rb[r] = up0[i]; rs[r] = dup[i]; }
      else { rb[r] = lo0[i]; rs[r] = dlo[i]; }
    }
    /* ---- x = y - Y S^-1 (Delta^T y) for both right-hand sides, plus one step of iterative
       refinement against the current matrix (the Woodbury update loses digits when the
       changed rows are many or K0 is ill-conditioned) ---- */
    int inaccurate = 0;
    for (int rhs_k = 0; rhs_k < 2 && !inaccurate; ++rhs_k) {
      const double *bvec = rhs_k ? rs : rb;
      double *x = rhs_k ? xs : xb;
      double *y = rhs_k ? ys : yb;
      /* Woodbury solve, then (only if the residual is not small) one step of iterative
         refinement against the current matrix */
      for (int it = 0; it < 2; ++it) {
        const double *src = bvec;
        if (it == 1) src = ek; /* the residual computed below */
        base_solve(st, ab, ipiv, src, y, tmp);
        for (int a = 0; a < m; ++a) {
          int r = chg[a];
          double sb = 0.0;
          for (int e = st->row_ptr[r]; e < st->row_ptr[r + 1]; ++e) {
            double delta = entry_value(&ctx, e, flags[r]) - entry_value(&ctx, e, flags0[r]);
            if (delta != 0.0) sb += delta * y[st->ent_col[e]];
          }
          t1[a] = sb;
        }
        if (m > 0) dense_solve(S, m, M, spiv, t1);
        for (int a = 0; a < m; ++a) {
          const double *ya = Y + (int64_t)slot[a] * n;
          double u = t1[a];
          for (int k = 0; k < n; ++k) y[k] -= ya[k] * u;
        }
        if (it == 0) memcpy(x, y, sizeof(double) * n);
        else for (int k = 0; k < n; ++k) x[k] += y[k];
        if (m == 0) break; /* a direct solve with a fresh factorisation */
        kkt_matvec(&ctx, flags, x, ek);
        double rmax = 0.0, bmax = 0.0, xmax = 0.0;
        for (int k = 0; k < n; ++k) {
          ek[k] = bvec[k] - ek[k];
          rmax = fmax(rmax, fabs(ek[k]));
          bmax = fmax(bmax, fabs(bvec[k]));
          xmax = fmax(xmax, fabs(x[k]));
        }
        if (rmax <= 1e-12 * (bmax + xmax) + 1e-15) break; /* accurate enough as is */
        if (it == 1 && !(rmax <= 1e-9 * (bmax + xmax) + 1e-14)) inaccurate = 1;
      }
    }
    if (inaccurate) { /* start this pass again from a fresh factorisation */
      for (int a = 0; a < m; ++a) mark[chg[a]] = -1;
      m = 0; have_base = 0; pass--; stats->passes--;
      continue;
    }
    for (int k = 0; k < n; ++k)
      if (!isfinite(xb[k]) || !isfinite(xs[k])) { stats->status = 3; return 3; }
    const double *d_b = xb, *d_s = xs, *l_b = xb + n_w, *l_s = xs + n_w;
    /* ---- c = J~ d, multipliers of fixed variables from stationarity ---- */
    for (int i = 0; i < n_g; ++i) { c_b[i] = 0.0; c_s[i] = 0.0; }
    for (int e = 0; e < st->n_j; ++e) {
      c_b[st->j_rows[e]] += js[e] * d_b[st->j_cols[e]];
      c_s[st->j_rows[e]] += js[e] * d_s[st->j_cols[e]];
    }
    for (int pass2 = 0; pass2 < 2; ++pass2) {
      const double *dv = pass2 ? d_s : d_b, *lv = pass2 ? l_s : l_b, *gv = pass2 ? dgrad : grad0;
      double *out = pass2 ? lx_s : lx_b;
      for (int j = 0; j < n_w; ++j) hd[j] = gv[j];
      for (int e = 0; e < st->n_hs; ++e) hd[st->hs_row[e]] += hess[st->hs_src[e]] * dv[st->hs_col[e]];
      for (int e = 0; e < st->n_j; ++e) hd[st->j_cols[e]] += js[e] * lv[st->j_rows[e]];
      for (int j = 0; j < n_w; ++j) out[j] = (var[j] != FREE) ? -hd[j] : 0.0;
    }
    /* ---- ratio tests: the first condition a + b t >= 0 to reach zero on [tau, 1] ---- */
    double t_hit = 1.0;
    int which_kind = -1, which_k = -1;
    for (int kind = 0; kind < 8; ++kind) {
      int cnt = (kind == 0 || kind == 1 || kind == 4 || kind == 5) ? n_g : n_w;
      int off = (kind == 0 || kind == 1 || kind == 4 || kind == 5) ? 0 : n_g;
      for (int k = 0; k < cnt; ++k) {
        double a, b;
        int in;
        switch (kind) {
          case 0: in = con[k] == FREE; a = c_b[k] - lo0[k]; b = c_s[k] - dlo[k]; break;
          case 1: in = con[k] == FREE; a = up0[k] - c_b[k]; b = dup[k] - c_s[k]; break;
          case 2: in = var[k] == FREE; a = d_b[k] - lox0[k]; b = d_s[k] - dlox[k]; break;
          case 3: in = var[k] == FREE; a = upx0[k] - d_b[k]; b = dupx[k] - d_s[k]; break;
          case 4: in = con[k] == AT_LOWER; a = -l_b[k]; b = -l_s[k]; break;
          case 5: in = con[k] == AT_UPPER; a = l_b[k]; b = l_s[k]; break;
          case 6: in = var[k] == AT_LOWER; a = -lx_b[k]; b = -lx_s[k]; break;
          default: in = var[k] == AT_UPPER; a = lx_b[k]; b = lx_s[k]; break;
        }
        if (!in || !(b < -tsl)) continue;
        if (!isfinite(a)) continue; /* an infinite bound never blocks */
        double t = (a + b * tau <= tol) ? tau : -a / b;
        if (!(t >= tau)) continue;
        int skip = 0;
        for (int f = 0; f < nfrozen; ++f) if (frozen[f] == off + k) { skip = 1; break; }
        if (skip) continue;
        if (t < t_hit || (which_kind < 0 && t < 1.0)) { t_hit = t; which_kind = kind; which_k = k; }
      }
    }
    if (which_kind < 0) {
      for (int j = 0; j < n_w; ++j) {
        d[j] = d_b[j] + d_s[j];
        lam_x[j] = (var[j] == FREE) ? 0.0 : lx_b[j] + lx_s[j];
      }
      for (int i = 0; i < n_g; ++i) lam[i] = (con[i] == FREE) ? 0.0 : l_b[i] + l_s[i];
      stats->status = 0;
      return 0;
    }
    if (t_hit > tau) nfrozen = 0;
    tau = t_hit;
    int k = which_k, key;
    switch (which_kind) {
      case 0: case 1: con[k] = which_kind == 0 ? AT_LOWER : AT_UPPER; key = k; break;
      case 4: case 5: con[k] = FREE; key = k; break;
      case 2: case 3: case 6: default: {
        signed char nv = which_kind == 2 ? AT_LOWER : which_kind == 3 ? AT_UPPER : FREE;
        int was_free = var[k] == FREE, now_free = nv == FREE;
        var[k] = nv;
        if (was_free != now_free)
          for (int q = st->jcol_ptr[k]; q < st->jcol_ptr[k + 1]; ++q)
            nfree[st->j_rows[st->jcol_idx[q]]] += now_free ? 1 : -1;
        key = n_g + k;
        break;
      }
    }
    if (nfrozen < o->max_passes + 8) frozen[nfrozen++] = key;
  }
  stats->status = 2;
  return 2;
}
