/*
 * ipm.c - a lean primal-dual interior-point method for the TO-CBF-MPC NLP (mcverify/solver/ipm.py;
 * the ABI, status codes and constants are in ipm.h).
 *
 * The algorithm is IPOPT's (Waechter & Biegler 2006): slacks for the inequality rows, log barriers
 * on every finite bound, the primal-dual Newton step from the augmented system
 *
 *     [ W + Sigma_x + dw I    J^T ] [dx]   [ -grad phi_mu - J^T y            ]
 *     [ J                    -D   ] [dy] = [ -c (+ q / Sigma_s on slack rows) ]
 *
 * (D = 1/Sigma_s on inequality rows, dc on equality rows), fraction-to-the-boundary step rules,
 * IPOPT's filter line search on (theta = |c|_1, phi = barrier objective) with up to
 * IPM_MAX_SOC second-order corrections at the first trial step, and the monotone barrier update.
 * Left out: the acceptable-level exit and the objective scaling. The restoration phase (IPOPT's
 * l1 elastic feasibility problem) runs only when ipm_opts.restoration or phase1 asks for it (see
 * "restoration phase" below); otherwise a failed line search ends the solve. What makes it fast is the linear algebra and the absence of
 * layers: the KKT matrix has a fixed pattern that a reverse Cuthill-McKee ordering makes banded,
 * factorised by a banded LU with partial pivoting, and the NLP's functions are the CasADi-generated
 * C of the kernel, called through function pointers. Inertia is not available from an LU; the step
 * is instead accepted only if it has positive curvature, dx'(W + Sigma_x + dw)dx + ds' Sigma_s ds >=
 * IPM_CURVATURE_MIN |(dx, ds)|^2 (the inertia-free test of Chiang & Zavala 2016), otherwise dw
 * grows as in IPOPT.
 *
 * Rows of g are scaled by min(1, IPM_SCALING_MAX_GRADIENT / max_j |J_ij|) at the starting point
 * (IPOPT's gradient-based scaling); the objective is not scaled. Multipliers come back unscaled in
 * CasADi's convention (L = f + lam_g' g + lam_x' x).
 *
 * Deterministic (fixed orders, no threads); no allocation (workspace from the caller). The results
 * depend on the exact order of the floating-point operations: a refactoring must keep it (compare
 * recorded solves bit for bit: python -m mcverify.bench.ipm_builds --baseline-rev REV), and the build
 * must not allow contraction into FMAs or reassociation (mcverify.solver.kernels.RUNTIME_CFLAGS).
 */
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>
#include <stdio.h>

#include "ipm.h"

/* ----------------------------------------------------------------------------- band LU ---- */

/* LAPACK's dgbtf2 (partial pivoting) on the band, with the rank-1 update of column j restricted to the
   rows j + 1 .. j + mcol[j] (fill_extents: no row below can hold a nonzero of column j, with or
   without the row swaps, since a pivot row is one of them). The updates skipped subtract an exact
   zero (column j's entry, +-0, times f): they leave every nonzero as it is, so the factor is the
   same bits, up to the sign of an exact zero (-0 - (-0) = +0), which no pivot test and no nonzero
   of a solution depends on. The fill rows of ab (the first bw of each column) must be zero on entry
   (assemble_kkt zeroes the whole band), as dgbtf2 would zero them itself. */
static int band_lu(double *ab, int n, int bw, int ldab, const int *mcol, int *ipiv) {
  const int kl = bw, kv = 2 * bw;
  int ju = 0;
  for (int j = 0; j < n; ++j) {
    int km = kl < n - 1 - j ? kl : n - 1 - j;
    const int m = mcol[j] < km ? mcol[j] : km;
    double *col = ab + (int64_t)ldab * j + kv;
    int jp = 0;
    double amax = fabs(col[0]);
    /* rows below j + m hold exact zeros, which never beat amax: the same pivot as over all km rows */
    for (int i = 1; i <= m; ++i)
      if (fabs(col[i]) > amax) { amax = fabs(col[i]); jp = i; }
    ipiv[j] = j + jp;
    if (col[jp] == 0.0) return j + 1;
    int jlast = j + bw + jp;
    if (jlast > n - 1) jlast = n - 1;
    if (jlast > ju) ju = jlast;
    if (jp != 0)
      for (int c = j; c <= ju; ++c) {
        double *a = ab + (int64_t)ldab * c + kv + j - c;
        double t = a[0]; a[0] = a[jp]; a[jp] = t;
      }
    if (km > 0) {
      double inv = 1.0 / col[0];
      for (int i = 1; i <= km; ++i) col[i] *= inv;
      for (int c = j + 1; c <= ju; ++c) {
        double *a = ab + (int64_t)ldab * c + kv + j - c;
        double f = a[0];
        if (f != 0.0)
          for (int i = 1; i <= m; ++i) a[i] -= col[i] * f;
      }
    }
  }
  return 0;
}

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
    const double *col = ab + (int64_t)ldab * j + kv;
    b[j] /= col[0];
    double bj = b[j];
    if (bj != 0.0) {
      int i0 = j - kv; if (i0 < 0) i0 = 0;
      for (int i = i0; i < j; ++i) b[i] -= col[i - j] * bj;
    }
  }
}

/* ---------------------------------------------------------------------- band extents -- */
/* mcol (n): column j of the LU's factor is zero below row j + mcol[j] (fill_extents); its loops stop
   there. With the reverse Cuthill-McKee ordering of the KKT matrix the mean extent is 12.6-15 for a
   half-bandwidth of 17-21 (Table IV kernels). */

/* mcol[j] in: the largest i with A[j + i, j] a (structural) nonzero (0: none); out: the same for
   the factor. Eliminating column j fills columns j + 1 .. j + mcol[j] down to row j + mcol[j],
   so the factor's last row of a column is the running maximum of j + mcol[j]. */
static void fill_extents(int *mcol, int n) {
  int last = -1;
  for (int j = 0; j < n; ++j) {
    int lj = j + mcol[j];
    if (last > lj) lj = last;
    mcol[j] = lj - j;
    last = lj;
  }
}

/* The position in lower band storage (ldl = bw + 1) of the LAPACK band position pos (ldab = 3 bw
   + 1, A[i, j] at row 2 bw + i - j), or -1 for an entry above the diagonal. */
static int64_t lower_position(int64_t pos, int bw, int ldab) {
  int64_t c = pos / ldab, d = pos % ldab - 2 * bw;
  return d < 0 ? -1 : d + (int64_t)(bw + 1) * c;
}

/* ----------------------------------------------------------------------------- evaluation -- */

typedef struct {
  const double **arg;
  double **res;
  casadi_int_t *iw;
  double *w;
} evalctx;

/* One call of a generated function: inputs a0..a3, outputs r0, r1 (0: not needed). Nonzero: error. */
static int call(const evalctx *e, casadi_fun f, const double *a0, const double *a1, const double *a2,
                const double *a3, double *r0, double *r1) {
  e->arg[0] = a0; e->arg[1] = a1; e->arg[2] = a2; e->arg[3] = a3;
  e->res[0] = r0; e->res[1] = r1;
  return f(e->arg, e->res, e->iw, e->w, 0);
}

/* --------------------------------------------------------------------------- solver state -- */

/* Views into the caller's workspace and the problem data of one ipm_solve. */
typedef struct {
  const ipm_struct *st;
  const ipm_opts *o;
  const double *p, *lbx, *ubx, *lbg, *ubg;
  int nw, ng, n;
  evalctx E;
  /* KKT system (n): band storage, right-hand side, solution, scratch */
  double *ab, *rhs, *sol, *tmp, *soc_buf;
  int *ipiv;
  int64_t *lpos; /* (n_ent) lower band position of each KKT entry, -1 above the diagonal */
  int *mcol;     /* (n) the factor's column extents (fill_extents) */
  /* per variable (n_w): iterate, relaxed bounds, bound multipliers, gradient, steps, trial point,
     barrier diagonal, J^T y, H dx (also scratch of the trial gradient), corrected step */
  double *x, *lx, *ux, *zl, *zu, *grad, *dx, *dzl, *dzu, *xt, *sigx, *jty, *hdx, *dx_soc;
  /* per row (n_g): scaled relaxed bounds, row scales, scaled g, slacks, scaled multipliers, slack
     multipliers, steps, residual c, barrier diagonal, trial g and slack, corrected slack step */
  double *lg, *ug, *dc, *g, *s, *y, *vl, *vu, *ds, *dy, *dvl, *dvu, *cres, *sigs, *gt, *st_, *ds_soc;
  double *jac, *jraw, *hess; /* scaled and raw Jacobian nonzeros, Hessian upper triangle */
  /* restoration phase (resto != 0): the l1 feasibility problem
       min rho sum(pe + ne) + zeta/2 sum dr2 (x - xr)^2  s.t.  c(x, s) - pe + ne = 0, pe, ne >= 0
     on every row but the fixing ones (fixed[i]); per variable: reference point and squared
     proximity scaling; per row: elastic variables, their multipliers, steps, trial values and
     barrier diagonals */
  int resto;
  double rho, zeta;
  const int *fixed;
  double *xr, *dr2;
  double *pe, *ne, *zp, *zn, *dpe, *dne, *dzp, *dzn, *pet, *net, *sigp, *sign_;
  double *dpe_keep, *dne_keep; /* the Newton step's dpe, dne while second-order corrections are tried */
} ipm_ws;

/* A row with elastic variables in the restoration phase (all but the fixing rows). */
#define ELASTIC(i) (S->resto && !S->fixed[i])

/* An equality row (lbg == ubg). A macro on the locals lbg, ubg (not S->lbg) so that the loops keep
   the bounds' pointers in registers across the calls of log and pow. */
#define IS_EQ(i) (lbg[i] == ubg[i])

/* Largest work size of the four generated functions, for each of the four kinds (arg, res, iw, w). */
static int64_t max_work_size(const ipm_struct *st, int kind) {
  int64_t m = 0;
  for (int k = 0; k < 4; ++k)
    if (st->work_sizes[4 * k + kind] > m) m = st->work_sizes[4 * k + kind];
  return m;
}

void ipm_work_sizes(const ipm_struct *st, int64_t *n_dbl, int64_t *n_int) {
  int64_t n = st->n, nw = st->n_w, ng = st->n_g;
  int64_t amax = max_work_size(st, 0), rmax = max_work_size(st, 1);
  int64_t iwmax = max_work_size(st, 2), wmax = max_work_size(st, 3);
  *n_dbl = (int64_t)st->ldab * n + 6 * n + 24 * nw + 32 * ng + 2 * st->n_j + st->n_h + wmax + 64;
  *n_int = (n + 2) + 2 * (iwmax + 8) + 2 * (amax + 8) + 2 * (rmax + 8) + (ng + 2) + 2 * (int64_t)st->n_ent + n + 66;
}

/* Carve the workspace (layout of ipm_work_sizes; the unnamed gaps are spare). */
static void carve_workspace(ipm_ws *S, double *wd, int *wi) {
  const ipm_struct *st = S->st;
  const int nw = S->nw, ng = S->ng, n = S->n;
  S->ab = wd; wd += (int64_t)st->ldab * n;
  S->rhs = wd; wd += n;
  S->sol = wd; wd += n;
  S->tmp = wd; wd += n;
  S->soc_buf = wd; wd += n;
  wd += 2 * n;
  double **per_var[] = {&S->lx, &S->ux, &S->zl, &S->zu, &S->grad, &S->dx, &S->dzl, &S->dzu, &S->xt, &S->sigx,
                        &S->jty, &S->hdx, &S->dx_soc, &S->xr, &S->dr2};
  for (size_t k = 0; k < sizeof per_var / sizeof per_var[0]; ++k) { *per_var[k] = wd; wd += nw; }
  wd += 9 * nw;
  double **per_row[] = {&S->lg, &S->ug, &S->dc, &S->g, &S->s, &S->y, &S->vl, &S->vu, &S->ds, &S->dy, &S->dvl,
                        &S->dvu, &S->cres, &S->sigs, &S->gt, &S->st_, &S->ds_soc,
                        &S->pe, &S->ne, &S->zp, &S->zn, &S->dpe, &S->dne, &S->dzp, &S->dzn, &S->pet, &S->net,
                        &S->sigp, &S->sign_, &S->dpe_keep, &S->dne_keep};
  for (size_t k = 0; k < sizeof per_row / sizeof per_row[0]; ++k) { *per_row[k] = wd; wd += ng; }
  wd += 1 * ng;
  S->jac = wd; wd += st->n_j;
  S->jraw = wd; wd += st->n_j;
  S->hess = wd; wd += st->n_h;
  S->E.w = wd;
  S->ipiv = wi; wi += n + (n & 1); /* keep 8-byte alignment for what follows */
  S->E.iw = (casadi_int_t *)wi;
  wi += 2 * (max_work_size(st, 2) + 8);
  S->E.arg = (const double **)wi; wi += 2 * (max_work_size(st, 0) + 8);
  S->E.res = (double **)wi; wi += 2 * (max_work_size(st, 1) + 8);
  int *fixed = wi;
  for (int i = 0; i < ng; ++i) fixed[i] = 0;
  for (int k = 0; k < st->n_fix; ++k) fixed[st->fix_row[k]] = 1;
  S->fixed = fixed;
  wi += ng + 2 + (ng & 1); /* 8-byte alignment */
  S->lpos = (int64_t *)wi;
  wi += 2 * st->n_ent;
  S->mcol = wi;
  { /* once per solve (both factorisations use the extents): the integer divisions are not free */
    for (int k = 0; k < n; ++k) S->mcol[k] = 0;
    for (int e = 0; e < st->n_ent; ++e) {
      int64_t q = S->lpos[e] = lower_position(st->ent_pos[e], st->bw, st->ldab);
      if (q < 0) continue;
      int c = (int)(q / (st->bw + 1)), d = (int)(q % (st->bw + 1));
      if (d > S->mcol[c]) S->mcol[c] = d;
    }
    fill_extents(S->mcol, n);
  }
}

static void init_stats(ipm_stats *stats, const ipm_opts *o) {
  stats->iterations = 0; stats->status = IPM_CONVERGED; stats->factorisations = 0; stats->regularised = 0;
  stats->backtracks = 0; stats->soc = 0; stats->far = 0; stats->theta_start = 0.0; stats->first_alpha = 0.0;
  stats->inf_pr = INFINITY; stats->inf_du = INFINITY; stats->mu = o->mu_init;
  stats->resto_calls = 0; stats->resto_iterations = 0;
  stats->cert_violation = NAN; stats->cert_stationarity = NAN; stats->cert_mu = NAN;
}

/* ---------------------------------------------------------------------------- the start -- */

/* Bounds relaxed by bound_relax (IPOPT's bound_relax_factor). */
static void relax_variable_bounds(ipm_ws *S) {
  const double *lbx = S->lbx, *ubx = S->ubx;
  const double relax = S->o->bound_relax;
  for (int j = 0; j < S->nw; ++j) {
    S->lx[j] = isfinite(lbx[j]) ? lbx[j] - relax * fmax(1.0, fabs(lbx[j])) : -INFINITY;
    S->ux[j] = isfinite(ubx[j]) ? ubx[j] + relax * fmax(1.0, fabs(ubx[j])) : INFINITY;
  }
}

/* Initial value embedding: each fixing row g_i = a x_j - c(p) is solved for x_j exactly, by
   evaluating g with x_j = 0 (g_i = -c(p)). */
static int embed_initial_value(ipm_ws *S) {
  const ipm_struct *st = S->st;
  for (int k = 0; k < st->n_fix; ++k) S->x[st->fix_var[k]] = 0.0;
  if (call(&S->E, st->f_g, S->x, S->p, 0, 0, S->g, 0)) return IPM_EVALUATION_ERROR;
  for (int k = 0; k < st->n_fix; ++k) {
    int i = st->fix_row[k], j = st->fix_var[k];
    S->x[j] = (S->lbg[i] - S->g[i]) / st->fix_coef[k];
  }
  return IPM_CONVERGED;
}

/* Row scales from the Jacobian at the (embedded) start, and the largest scaled violation there. */
static int scale_rows(ipm_ws *S, double *theta_start) {
  const ipm_struct *st = S->st;
  const int nw = S->nw, ng = S->ng;
  double *dc = S->dc, *g = S->g, *x = S->x;
  if (call(&S->E, st->f_jac_g, x, S->p, 0, 0, g, S->jraw)) return IPM_EVALUATION_ERROR;
  for (int i = 0; i < ng; ++i) dc[i] = 0.0;
  for (int e = 0; e < st->n_j; ++e) {
    double a = fabs(S->jraw[e]);
    if (a > dc[st->j_rows[e]]) dc[st->j_rows[e]] = a;
  }
  for (int i = 0; i < ng; ++i) dc[i] = dc[i] > IPM_SCALING_MAX_GRADIENT ? IPM_SCALING_MAX_GRADIENT / dc[i] : 1.0;
  double theta = 0.0;
  for (int i = 0; i < ng; ++i) {
    double v = fmax(S->lbg[i] - g[i], g[i] - S->ubg[i]);
    if (v > 0.0) theta = fmax(theta, v * dc[i]);
  }
  for (int j = 0; j < nw; ++j) theta = fmax(theta, fmax(S->lbx[j] - x[j], x[j] - S->ubx[j]));
  *theta_start = theta;
  return IPM_CONVERGED;
}

/* v pushed at least push * max(1, |bound|) inside [l, u] (each push at most half the interval). */
static double push_inside(double v, double l, double u, double push) {
  double push_l = isfinite(l) ? push * fmax(1.0, fabs(l)) : 0.0;
  double push_u = isfinite(u) ? push * fmax(1.0, fabs(u)) : 0.0;
  if (isfinite(l) && isfinite(u)) {
    double half = 0.5 * (u - l);
    if (push_l > half) push_l = half;
    if (push_u > half) push_u = half;
  }
  if (isfinite(l) && v < l + push_l) v = l + push_l;
  if (isfinite(u) && v > u - push_u) v = u - push_u;
  return v;
}

/* Scaled row bounds; inequality rows relaxed like the variable bounds, equality rows kept exact. */
static void relax_row_bounds(ipm_ws *S) {
  const double relax = S->o->bound_relax;
  for (int i = 0; i < S->ng; ++i) {
    double lb = S->lbg[i], ub = S->ubg[i];
    double l = lb * S->dc[i], u = ub * S->dc[i];
    if (lb == ub) { S->lg[i] = l; S->ug[i] = u; }
    else {
      S->lg[i] = isfinite(lb) ? l - relax * fmax(1.0, fabs(l)) : -INFINITY;
      S->ug[i] = isfinite(ub) ? u + relax * fmax(1.0, fabs(u)) : INFINITY;
    }
  }
}

/* Primal start: x pushed inside its relaxed bounds, slacks at the scaled g pushed inside theirs. */
static int primal_start(ipm_ws *S, double push) {
  const double *lbg = S->lbg, *ubg = S->ubg;
  for (int j = 0; j < S->nw; ++j) S->x[j] = push_inside(S->x[j], S->lx[j], S->ux[j], push);
  if (call(&S->E, S->st->f_g, S->x, S->p, 0, 0, S->g, 0)) return IPM_EVALUATION_ERROR;
  relax_row_bounds(S);
  for (int i = 0; i < S->ng; ++i) {
    double gi = S->g[i] * S->dc[i];
    if (IS_EQ(i)) { S->s[i] = S->lg[i]; continue; }
    S->s[i] = push_inside(gi, S->lg[i], S->ug[i], push);
  }
  return IPM_CONVERGED;
}

/* Dual start: the caller's multipliers (warm; scaled, split by sign into the bound multipliers),
   else 0 for y and 1 for the bound multipliers; each bound multiplier at least mult_push. */
static void dual_start(ipm_ws *S, const double *lam_x, const double *lam_g) {
  const double *lbg = S->lbg, *ubg = S->ubg;
  const int warm = S->o->warm;
  const double mult_push = S->o->mult_push;
  for (int i = 0; i < S->ng; ++i) {
    double *y = S->y, *vl = S->vl, *vu = S->vu;
    y[i] = warm ? lam_g[i] / S->dc[i] : 0.0;
    vl[i] = vu[i] = 0.0;
    if (IS_EQ(i)) continue;
    /* on slack rows y = vU - vL */
    if (isfinite(S->lg[i])) vl[i] = fmax(warm ? fmax(-y[i], 0.0) : 1.0, mult_push);
    if (isfinite(S->ug[i])) vu[i] = fmax(warm ? fmax(y[i], 0.0) : 1.0, mult_push);
  }
  for (int j = 0; j < S->nw; ++j) {
    double *zl = S->zl, *zu = S->zu;
    zl[j] = zu[j] = 0.0;
    if (isfinite(S->lx[j])) zl[j] = fmax(warm ? fmax(-lam_x[j], 0.0) : 1.0, mult_push);
    if (isfinite(S->ux[j])) zu[j] = fmax(warm ? fmax(lam_x[j], 0.0) : 1.0, mult_push);
  }
}

/* ------------------------------------------------------------------------ KKT residuals -- */

/* f, grad f, g and J at x; g and J scaled by the row scales. */
static int evaluate(ipm_ws *S, double *fval) {
  const ipm_struct *st = S->st;
  if (call(&S->E, st->f_grad_f, S->x, S->p, 0, 0, fval, S->grad)) return IPM_EVALUATION_ERROR;
  if (call(&S->E, st->f_jac_g, S->x, S->p, 0, 0, S->g, S->jraw)) return IPM_EVALUATION_ERROR;
  for (int e = 0; e < st->n_j; ++e) S->jac[e] = S->jraw[e] * S->dc[st->j_rows[e]];
  for (int i = 0; i < S->ng; ++i) S->g[i] *= S->dc[i];
  return IPM_CONVERGED;
}

/* The optimality errors of the current iterate (IPOPT's, with its dual scaling sd, sc). */
typedef struct {
  double inf_du, inf_pr, inf_co, viol_unscaled;
  double sd, sc; /* scaling of the dual and complementarity errors */
} kkt_errors;

/* J^T y, the residual c (cres), and the errors at mu = 0. */
static kkt_errors residuals(ipm_ws *S) {
  const double *lbg = S->lbg, *ubg = S->ubg;
  const ipm_struct *st = S->st;
  const int nw = S->nw, ng = S->ng;
  const double *x = S->x, *lx = S->lx, *ux = S->ux, *zl = S->zl, *zu = S->zu, *lbx = S->lbx, *ubx = S->ubx;
  const double *g = S->g, *s = S->s, *y = S->y, *vl = S->vl, *vu = S->vu, *lg = S->lg, *ug = S->ug;
  const double *grad = S->grad, *jac = S->jac, *dc = S->dc;
  double *jty = S->jty, *cres = S->cres;
  for (int j = 0; j < nw; ++j) jty[j] = 0.0;
  for (int e = 0; e < st->n_j; ++e) jty[st->j_cols[e]] += jac[e] * y[st->j_rows[e]];
  double inf_du = 0.0, inf_pr = 0.0, inf_co = 0.0, viol_unscaled = 0.0;
  double ysum = 0.0, zsum = 0.0, cnt_y = ng, cnt_z = 0;
  for (int j = 0; j < nw; ++j) {
    double r = grad[j] + jty[j] - zl[j] + zu[j];
    inf_du = fmax(inf_du, fabs(r));
    zsum += zl[j] + zu[j]; cnt_z += 2;
    if (isfinite(lx[j])) inf_co = fmax(inf_co, fabs((x[j] - lx[j]) * zl[j] - 0.0));
    if (isfinite(ux[j])) inf_co = fmax(inf_co, fabs((ux[j] - x[j]) * zu[j]));
    double vlow = isfinite(lbx[j]) ? lbx[j] - x[j] : 0.0, vupp = isfinite(ubx[j]) ? x[j] - ubx[j] : 0.0;
    viol_unscaled = fmax(viol_unscaled, fmax(vlow, vupp));
  }
  for (int i = 0; i < ng; ++i) {
    ysum += fabs(y[i]);
    if (IS_EQ(i)) { cres[i] = g[i] - lg[i]; }
    else {
      cres[i] = g[i] - s[i];
      double r = -y[i] - vl[i] + vu[i];
      inf_du = fmax(inf_du, fabs(r));
      zsum += vl[i] + vu[i]; cnt_z += 2;
      if (isfinite(lg[i])) inf_co = fmax(inf_co, fabs((s[i] - lg[i]) * vl[i]));
      if (isfinite(ug[i])) inf_co = fmax(inf_co, fabs((ug[i] - s[i]) * vu[i]));
    }
    if (ELASTIC(i)) { /* c - pe + ne; stationarity in pe, ne: rho -+ y - z = 0 */
      cres[i] += S->ne[i] - S->pe[i];
      inf_du = fmax(inf_du, fmax(fabs(S->rho - y[i] - S->zp[i]), fabs(S->rho + y[i] - S->zn[i])));
      zsum += S->zp[i] + S->zn[i]; cnt_z += 2;
      inf_co = fmax(inf_co, fmax(S->pe[i] * S->zp[i], S->ne[i] * S->zn[i]));
    }
    inf_pr = fmax(inf_pr, fabs(cres[i]));
    double graw = g[i] / dc[i];
    viol_unscaled = fmax(viol_unscaled, fmax(lbg[i] - graw, graw - ubg[i]));
  }
  kkt_errors err = {inf_du, inf_pr, inf_co, viol_unscaled, 0.0, 0.0};
  err.sd = fmax(IPM_S_MAX, (ysum + zsum) / (cnt_y + cnt_z)) / IPM_S_MAX;
  err.sc = fmax(IPM_S_MAX, zsum / (cnt_z > 0 ? cnt_z : 1)) / IPM_S_MAX;
  return err;
}

/* Largest complementarity error |slack * multiplier - mu| (the barrier problem's). */
static double complementarity_error(const ipm_ws *S, double mu) {
  const double *lbg = S->lbg, *ubg = S->ubg;
  const int nw = S->nw, ng = S->ng;
  const double *x = S->x, *lx = S->lx, *ux = S->ux, *s = S->s, *lg = S->lg, *ug = S->ug;
  const double *zl = S->zl, *zu = S->zu, *vl = S->vl, *vu = S->vu;
  double co_mu = 0.0;
  for (int j = 0; j < nw; ++j) {
    if (isfinite(lx[j])) co_mu = fmax(co_mu, fabs((x[j] - lx[j]) * zl[j] - mu));
    if (isfinite(ux[j])) co_mu = fmax(co_mu, fabs((ux[j] - x[j]) * zu[j] - mu));
  }
  for (int i = 0; i < ng; ++i) {
    if (IS_EQ(i)) continue;
    if (isfinite(lg[i])) co_mu = fmax(co_mu, fabs((s[i] - lg[i]) * vl[i] - mu));
    if (isfinite(ug[i])) co_mu = fmax(co_mu, fabs((ug[i] - s[i]) * vu[i] - mu));
  }
  if (S->resto)
    for (int i = 0; i < ng; ++i)
      if (ELASTIC(i)) co_mu = fmax(co_mu, fmax(fabs(S->pe[i] * S->zp[i] - mu), fabs(S->ne[i] * S->zn[i] - mu)));
  return co_mu;
}

/* Monotone barrier update: decrease mu while the barrier problem is solved to kappa_eps mu
   (possibly several times, IPOPT's rule). */
static double update_barrier(const ipm_ws *S, double mu, const kkt_errors *err) {
  for (int k = 0; k < IPM_MAX_MU_UPDATES; ++k) {
    double co_mu = complementarity_error(S, mu);
    double err_mu = fmax(err->inf_du / err->sd, fmax(err->inf_pr, co_mu / err->sc));
    if (err_mu > IPM_KAPPA_EPSILON * mu || mu <= S->o->mu_min) break;
    double mnew = fmin(IPM_KAPPA_MU * mu, pow(mu, IPM_THETA_MU));
    mu = fmax(S->o->mu_min, mnew);
  }
  return mu;
}

/* -------------------------------------------------------------------------- Newton step -- */

/* Sigma_x and Sigma_s: the barrier terms' diagonals, multiplier / slack. */
static void barrier_diagonals(ipm_ws *S) {
  const double *lbg = S->lbg, *ubg = S->ubg;
  const double *x = S->x, *lx = S->lx, *ux = S->ux, *s = S->s, *lg = S->lg, *ug = S->ug;
  for (int j = 0; j < S->nw; ++j) {
    double sg = 0.0;
    if (isfinite(lx[j])) sg += S->zl[j] / (x[j] - lx[j]);
    if (isfinite(ux[j])) sg += S->zu[j] / (ux[j] - x[j]);
    S->sigx[j] = sg;
  }
  for (int i = 0; i < S->ng; ++i) {
    double sg = 0.0;
    if (!IS_EQ(i)) {
      if (isfinite(lg[i])) sg += S->vl[i] / (s[i] - lg[i]);
      if (isfinite(ug[i])) sg += S->vu[i] / (ug[i] - s[i]);
    }
    S->sigs[i] = sg;
    if (ELASTIC(i)) { S->sigp[i] = S->zp[i] / S->pe[i]; S->sign_[i] = S->zn[i] / S->ne[i]; }
  }
}

/* The value of KKT entry e, regularised by dw (primal) and dcr (constraints). */
static double kkt_entry(const ipm_ws *S, int e, double dw, double dcr) {
  const double *lbg = S->lbg, *ubg = S->ubg;
  const ipm_struct *st = S->st;
  int r = st->ent_row[e];
  double v;
  switch (st->ent_kind[e]) {
    case IPM_ENTRY_HESSIAN: v = S->hess[st->hs_src[st->ent_src[e]]]; break;
    case IPM_ENTRY_PRIMAL_DIAG:
      v = S->sigx[r] + dw;
      if (S->resto) v += S->zeta * S->dr2[r];
      break;
    case IPM_ENTRY_JAC_T: case IPM_ENTRY_JAC: v = S->jac[st->ent_src[e]]; break;
    default: { /* IPM_ENTRY_DUAL_DIAG */
      int i = r - S->nw;
      v = IS_EQ(i) ? -dcr : -1.0 / (S->sigs[i] + dw) - dcr;
      /* the elastic variables eliminated: their inverse barrier diagonals join the row's */
      if (ELASTIC(i)) v -= 1.0 / (S->sigp[i] + dw) + 1.0 / (S->sign_[i] + dw);
    }
  }
  return v;
}

/* The augmented matrix in band storage, regularised by dw (primal) and dcr (constraints). */
static void assemble_kkt(ipm_ws *S, double dw, double dcr) {
  const ipm_struct *st = S->st;
  memset(S->ab, 0, sizeof(double) * (size_t)st->ldab * (size_t)S->n);
  for (int e = 0; e < st->n_ent; ++e) S->ab[st->ent_pos[e]] += kkt_entry(S, e, dw, dcr);
}


/* y + mu / (s - lg) - mu / (ug - s) of an inequality row: its slack's barrier gradient term. */
static double slack_q(const ipm_ws *S, int i, double mu) {
  double q = S->y[i];
  if (isfinite(S->lg[i])) q += mu / (S->s[i] - S->lg[i]);
  if (isfinite(S->ug[i])) q -= mu / (S->ug[i] - S->s[i]);
  return q;
}

/* Elastic rows: the barrier gradients of pe (rho - y - mu/pe) and ne (rho + y - mu/ne) over their
   diagonals, what eliminating dpe, dne adds to the row's right-hand side. */
static double elastic_rhs(const ipm_ws *S, int i, double mu, double dw) {
  double gp = S->rho - S->y[i] - mu / S->pe[i], gn = S->rho + S->y[i] - mu / S->ne[i];
  return -gp / (S->sigp[i] + dw) + gn / (S->sign_[i] + dw);
}

/* The elastic steps implied by the row steps dyv (dpe = (dy - gp) / (sigp + dw), dne = -(dy + gn) /
   (sign + dw)), into S->dpe, S->dne. */
static void elastic_steps(ipm_ws *S, const double *dyv, double mu, double dw) {
  for (int i = 0; i < S->ng; ++i) {
    S->dpe[i] = S->dne[i] = 0.0;
    if (!ELASTIC(i)) continue;
    double gp = S->rho - S->y[i] - mu / S->pe[i], gn = S->rho + S->y[i] - mu / S->ne[i];
    S->dpe[i] = (dyv[i] - gp) / (S->sigp[i] + dw);
    S->dne[i] = -(dyv[i] + gn) / (S->sign_[i] + dw);
  }
}

/* Right-hand side of the augmented system (slacks eliminated). */
static void newton_rhs(ipm_ws *S, double mu, double dw) {
  const double *lbg = S->lbg, *ubg = S->ubg;
  const double *x = S->x, *lx = S->lx, *ux = S->ux;
  const int nw = S->nw;
  for (int j = 0; j < nw; ++j) {
    double r = -S->grad[j] - S->jty[j];
    if (isfinite(lx[j])) r += mu / (x[j] - lx[j]);
    if (isfinite(ux[j])) r -= mu / (ux[j] - x[j]);
    S->rhs[j] = r;
  }
  for (int i = 0; i < S->ng; ++i) {
    if (IS_EQ(i)) S->rhs[nw + i] = -S->cres[i];
    else S->rhs[nw + i] = -S->cres[i] + slack_q(S, i, mu) / (S->sigs[i] + dw);
    if (ELASTIC(i)) S->rhs[nw + i] += elastic_rhs(S, i, mu, dw);
  }
}

/* Solve the factorised system for b (n, original order) into out (n), through the band order. */
static void solve_permuted(ipm_ws *S, const double *b, double *band_buf, double *out) {
  const ipm_struct *st = S->st;
  for (int k = 0; k < S->n; ++k) band_buf[k] = b[st->perm[k]];
  band_solve(S->ab, S->n, st->bw, st->ldab, S->ipiv, band_buf);
  for (int k = 0; k < S->n; ++k) out[st->perm[k]] = band_buf[k];
}

/* Primal step dx from a solution of the augmented system, and the slack step ds it implies. */
static void unpack_step(ipm_ws *S, const double *solution, double mu, double dw, double *dxv, double *dsv) {
  const double *lbg = S->lbg, *ubg = S->ubg;
  const ipm_struct *st = S->st;
  const int nw = S->nw;
  for (int j = 0; j < nw; ++j) dxv[j] = solution[j];
  /* a fixing row has one variable and zero residual: its step is exactly 0 (not round-off) */
  for (int k = 0; k < st->n_fix; ++k) dxv[st->fix_var[k]] = 0.0;
  for (int i = 0; i < S->ng; ++i) {
    if (IS_EQ(i)) { dsv[i] = 0.0; continue; }
    dsv[i] = (solution[nw + i] + slack_q(S, i, mu)) / (S->sigs[i] + dw);
  }
}

/* The inertia-free test: does (dx, ds) have positive curvature? */
static int curvature_ok(ipm_ws *S, double dw) {
  const double *lbg = S->lbg, *ubg = S->ubg;
  const ipm_struct *st = S->st;
  const double *dx = S->dx, *ds = S->ds;
  for (int j = 0; j < S->nw; ++j) S->hdx[j] = 0.0;
  for (int e = 0; e < st->n_hs; ++e) S->hdx[st->hs_row[e]] += S->hess[st->hs_src[e]] * dx[st->hs_col[e]];
  double curv = 0.0, nrm = 0.0;
  for (int j = 0; j < S->nw; ++j) { curv += dx[j] * (S->hdx[j] + (S->sigx[j] + dw) * dx[j]); nrm += dx[j] * dx[j]; }
  for (int i = 0; i < S->ng; ++i)
    if (!IS_EQ(i)) { curv += (S->sigs[i] + dw) * ds[i] * ds[i]; nrm += ds[i] * ds[i]; }
  if (S->resto) {
    for (int j = 0; j < S->nw; ++j) curv += S->zeta * S->dr2[j] * dx[j] * dx[j];
    for (int i = 0; i < S->ng; ++i)
      if (ELASTIC(i)) {
        curv += (S->sigp[i] + dw) * S->dpe[i] * S->dpe[i] + (S->sign_[i] + dw) * S->dne[i] * S->dne[i];
        nrm += S->dpe[i] * S->dpe[i] + S->dne[i] * S->dne[i];
      }
  }
  return isfinite(curv) && curv >= IPM_CURVATURE_MIN * nrm;
}

/* The next primal regularisation after a failed factorisation or curvature test. */
static double next_dw(double dw, double dw_last) {
  if (dw != 0.0) return IPM_KAPPA_W_PLUS * dw;
  return dw_last == 0.0 ? IPM_DELTA_W_FIRST : fmax(IPM_DELTA_W_MIN, dw_last / IPM_KAPPA_W_MINUS);
}

/* Newton step (dx, dy, ds) with the smallest regularisation dw (in *dw) that passes. Leaves the
   factorisation in ab for the second-order corrections. */
static int newton_step(ipm_ws *S, double mu, double dw_last, double *dw_out, ipm_stats *stats) {
  const ipm_struct *st = S->st;
  double dw = 0.0, dcr = 0.0;
  for (int attempt = 0; attempt < IPM_MAX_REGULARISATIONS; ++attempt) {
    assemble_kkt(S, dw, dcr);
    int info = band_lu(S->ab, S->n, st->bw, st->ldab, S->mcol, S->ipiv);
    stats->factorisations++;
    if (info != 0) {
      /* singular: regularise the constraints as well as the primal block */
      dcr = IPM_DELTA_C * pow(mu, IPM_KAPPA_C);
      dw = next_dw(dw, dw_last);
      continue;
    }
    newton_rhs(S, mu, dw);
    solve_permuted(S, S->rhs, S->tmp, S->sol);
    for (int i = 0; i < S->ng; ++i) S->dy[i] = S->sol[S->nw + i];
    unpack_step(S, S->sol, mu, dw, S->dx, S->ds);
    if (S->resto) elastic_steps(S, S->dy, mu, dw);
    if (curvature_ok(S, dw)) { *dw_out = dw; return IPM_CONVERGED; }
    dw = next_dw(dw, dw_last);
  }
  return IPM_REGULARISATION_FAILED;
}

/* Steps of the bound multipliers implied by (dx, ds). */
static void bound_multiplier_steps(ipm_ws *S, double mu) {
  const double *lbg = S->lbg, *ubg = S->ubg;
  const double *x = S->x, *lx = S->lx, *ux = S->ux, *zl = S->zl, *zu = S->zu, *dx = S->dx;
  const double *s = S->s, *lg = S->lg, *ug = S->ug, *vl = S->vl, *vu = S->vu, *ds = S->ds;
  for (int j = 0; j < S->nw; ++j) {
    S->dzl[j] = isfinite(lx[j]) ? mu / (x[j] - lx[j]) - zl[j] - zl[j] / (x[j] - lx[j]) * dx[j] : 0.0;
    S->dzu[j] = isfinite(ux[j]) ? mu / (ux[j] - x[j]) - zu[j] + zu[j] / (ux[j] - x[j]) * dx[j] : 0.0;
  }
  for (int i = 0; i < S->ng; ++i) {
    S->dvl[i] = S->dvu[i] = 0.0;
    if (IS_EQ(i)) continue;
    if (isfinite(lg[i])) S->dvl[i] = mu / (s[i] - lg[i]) - vl[i] - vl[i] / (s[i] - lg[i]) * ds[i];
    if (isfinite(ug[i])) S->dvu[i] = mu / (ug[i] - s[i]) - vu[i] + vu[i] / (ug[i] - s[i]) * ds[i];
  }
  if (S->resto)
    for (int i = 0; i < S->ng; ++i) {
      S->dzp[i] = S->dzn[i] = 0.0;
      if (!ELASTIC(i)) continue;
      S->dzp[i] = mu / S->pe[i] - S->zp[i] - S->sigp[i] * S->dpe[i];
      S->dzn[i] = mu / S->ne[i] - S->zn[i] - S->sign_[i] * S->dne[i];
    }
}

/* ----------------------------------------------------------------- fraction to the boundary -- */

/* Largest primal step length <= 1 that keeps x and s a fraction tau inside their bounds. */
static double primal_step_max(const ipm_ws *S, const double *dxv, const double *dsv, double tau) {
  const double *lbg = S->lbg, *ubg = S->ubg;
  const double *x = S->x, *lx = S->lx, *ux = S->ux, *s = S->s, *lg = S->lg, *ug = S->ug;
  const int nw = S->nw, ng = S->ng;
  double a = 1.0;
  for (int j = 0; j < nw; ++j) {
    if (isfinite(lx[j]) && dxv[j] < 0.0) a = fmin(a, -tau * (x[j] - lx[j]) / dxv[j]);
    if (isfinite(ux[j]) && dxv[j] > 0.0) a = fmin(a, tau * (ux[j] - x[j]) / dxv[j]);
  }
  for (int i = 0; i < ng; ++i) {
    if (IS_EQ(i)) continue;
    if (isfinite(lg[i]) && dsv[i] < 0.0) a = fmin(a, -tau * (s[i] - lg[i]) / dsv[i]);
    if (isfinite(ug[i]) && dsv[i] > 0.0) a = fmin(a, tau * (ug[i] - s[i]) / dsv[i]);
  }
  if (S->resto) /* dpe, dne: the step's (the Newton step's or a second-order correction's) */
    for (int i = 0; i < ng; ++i) {
      if (!ELASTIC(i)) continue;
      if (S->dpe[i] < 0.0) a = fmin(a, -tau * S->pe[i] / S->dpe[i]);
      if (S->dne[i] < 0.0) a = fmin(a, -tau * S->ne[i] / S->dne[i]);
    }
  return a;
}

/* Largest dual step length <= 1 that keeps the bound multipliers a fraction tau above 0. */
static double dual_step_max(const ipm_ws *S, double tau) {
  const double *lbg = S->lbg, *ubg = S->ubg;
  const int nw = S->nw, ng = S->ng;
  const double *zl = S->zl, *zu = S->zu, *dzl = S->dzl, *dzu = S->dzu;
  const double *vl = S->vl, *vu = S->vu, *dvl = S->dvl, *dvu = S->dvu;
  double a = 1.0;
  for (int j = 0; j < nw; ++j) {
    if (dzl[j] < 0.0) a = fmin(a, -tau * zl[j] / dzl[j]);
    if (dzu[j] < 0.0) a = fmin(a, -tau * zu[j] / dzu[j]);
  }
  for (int i = 0; i < ng; ++i) {
    if (IS_EQ(i)) continue;
    if (dvl[i] < 0.0) a = fmin(a, -tau * vl[i] / dvl[i]);
    if (dvu[i] < 0.0) a = fmin(a, -tau * vu[i] / dvu[i]);
  }
  if (S->resto)
    for (int i = 0; i < ng; ++i) {
      if (!ELASTIC(i)) continue;
      if (S->dzp[i] < 0.0) a = fmin(a, -tau * S->zp[i] / S->dzp[i]);
      if (S->dzn[i] < 0.0) a = fmin(a, -tau * S->zn[i] / S->dzn[i]);
    }
  return a;
}

/* ------------------------------------------------------------------------- line search -- */

typedef struct {
  double theta[IPM_MAX_FILTER], phi[IPM_MAX_FILTER];
  int n;
  double mu;        /* barrier parameter the filter belongs to (reset when mu changes) */
  double theta_max; /* no trial point above this infeasibility */
} filter_t;

/* The current point's merit: theta = |c|_1 (scaled rows), phi = barrier objective, and phi's
   directional derivative along (dx, ds). */
typedef struct { double theta0, phi0, dphi; } merit_t;

static merit_t current_merit(const ipm_ws *S, double fval, double mu) {
  const double *lbg = S->lbg, *ubg = S->ubg;
  const double *x = S->x, *lx = S->lx, *ux = S->ux, *s = S->s, *lg = S->lg, *ug = S->ug;
  const int nw = S->nw, ng = S->ng;
  const double *cres = S->cres, *grad = S->grad, *dx = S->dx, *ds = S->ds;
  merit_t m = {0.0, fval, 0.0};
  for (int i = 0; i < ng; ++i) m.theta0 += fabs(cres[i]);
  for (int j = 0; j < nw; ++j) {
    double gj = grad[j];
    if (isfinite(lx[j])) { m.phi0 -= mu * log(x[j] - lx[j]); gj -= mu / (x[j] - lx[j]); }
    if (isfinite(ux[j])) { m.phi0 -= mu * log(ux[j] - x[j]); gj += mu / (ux[j] - x[j]); }
    m.dphi += gj * dx[j];
  }
  for (int i = 0; i < ng; ++i) {
    if (IS_EQ(i)) continue;
    double gs = 0.0;
    if (isfinite(lg[i])) { m.phi0 -= mu * log(s[i] - lg[i]); gs -= mu / (s[i] - lg[i]); }
    if (isfinite(ug[i])) { m.phi0 -= mu * log(ug[i] - s[i]); gs += mu / (ug[i] - s[i]); }
    m.dphi += gs * ds[i];
  }
  if (S->resto)
    for (int i = 0; i < ng; ++i) {
      if (!ELASTIC(i)) continue;
      m.phi0 += S->rho * (S->pe[i] + S->ne[i]) - mu * (log(S->pe[i]) + log(S->ne[i]));
      m.dphi += (S->rho - mu / S->pe[i]) * S->dpe[i] + (S->rho - mu / S->ne[i]) * S->dne[i];
    }
  return m;
}

/* The restoration objective at x (and, with trial elastic values pe + a dpe, ne + a dne written to
   pet, net): zeta/2 sum dr2 (x - xr)^2 + rho sum(pet + net) (the barrier terms are the caller's,
   except the elastic ones, added here). */
static double resto_objective(ipm_ws *S, const double *xv, double a, double mu);

/* A trial point's merit. */
typedef struct { double phi, theta; } trial_t;

/* Evaluate the barrier objective and the infeasibility at (x + a dx, s + a ds) into xt, st_, gt.
   Returns 1 if finite, 0 if not evaluable (NaN/inf, out of the barrier's domain), -1 on an
   evaluation error. */
static int trial_eval(ipm_ws *S, const double *dxv, const double *dsv, double a, double mu, trial_t *t) {
  const double *lbg = S->lbg, *ubg = S->ubg;
  const ipm_struct *st = S->st;
  const int nw = S->nw, ng = S->ng;
  const double *lx = S->lx, *ux = S->ux, *lg = S->lg, *ug = S->ug;
  const double *x = S->x, *s = S->s, *dc = S->dc;
  double *xt = S->xt, *st_ = S->st_, *gt = S->gt;
  for (int j = 0; j < nw; ++j) xt[j] = x[j] + a * dxv[j];
  for (int i = 0; i < ng; ++i) st_[i] = s[i] + a * dsv[i];
  double ft = 0.0;
  if (S->resto) ft = resto_objective(S, xt, a, mu);
  else if (call(&S->E, st->f_grad_f, xt, S->p, 0, 0, &ft, S->hdx)) return -1; /* hdx: gradient scratch */
  if (call(&S->E, st->f_g, xt, S->p, 0, 0, gt, 0)) return -1;
  double ph = ft, th = 0.0;
  if (!isfinite(ft)) return 0;
  for (int j = 0; j < nw; ++j) {
    if (isfinite(lx[j])) ph -= mu * log(xt[j] - lx[j]);
    if (isfinite(ux[j])) ph -= mu * log(ux[j] - xt[j]);
  }
  for (int i = 0; i < ng; ++i) {
    double gi = gt[i] * dc[i];
    if (!isfinite(gi)) return 0;
    double el = ELASTIC(i) ? S->net[i] - S->pet[i] : 0.0;
    if (IS_EQ(i)) th += ELASTIC(i) ? fabs(gi - lg[i] + el) : fabs(gi - lg[i]);
    else {
      th += ELASTIC(i) ? fabs(gi - st_[i] + el) : fabs(gi - st_[i]);
      if (isfinite(lg[i])) ph -= mu * log(st_[i] - lg[i]);
      if (isfinite(ug[i])) ph -= mu * log(ug[i] - st_[i]);
    }
  }
  t->phi = ph; t->theta = th;
  return isfinite(ph) ? 1 : 0;
}

/* IPOPT's filter acceptance (switching condition, Armijo for f-type, sufficient decrease for
   h-type). *f_type is set only once the trial passed theta_max and the filter. */
static int acceptable(const trial_t *t, const merit_t *m, double alpha, double theta_min, const filter_t *F,
                      int *f_type) {
  if (t->theta > F->theta_max) return 0;
  for (int k = 0; k < F->n; ++k)
    if (!(t->theta < F->theta[k] || t->phi < F->phi[k])) return 0;
  int switching = m->dphi < 0.0 && alpha * pow(-m->dphi, IPM_S_PHI) > pow(m->theta0, IPM_S_THETA) &&
                  m->theta0 <= theta_min;
  *f_type = 0;
  if (switching) {
    if (t->phi <= m->phi0 + IPM_ETA_PHI * alpha * m->dphi) { *f_type = 1; return 1; }
    return 0;
  }
  return t->theta <= (1.0 - IPM_GAMMA_THETA) * m->theta0 || t->phi <= m->phi0 - IPM_GAMMA_PHI * m->theta0;
}

/* What a line search ends with: the step length and kind, and whether it was a corrected step. */
typedef struct {
  double alpha, theta_min;
  int accepted, f_type, soc_used;
  trial_t trial;
} search_t;

/* Second-order corrections after a first trial (at ls->alpha) that did not reduce theta: up to
   IPM_MAX_SOC, each re-solving with the accumulated constraint values of the last trial (IPOPT's
   c_soc), each required to cut theta by IPM_KAPPA_SOC. An accepted correction replaces (dx, ds)
   and alpha. Returns -1 on an evaluation error. */
static int second_order_corrections(ipm_ws *S, const merit_t *m, const filter_t *F, double mu, double dw,
                                    double tau, search_t *ls, ipm_stats *stats) {
  const double *lbg = S->lbg, *ubg = S->ubg;
  const int nw = S->nw, ng = S->ng;
  double *c_soc = S->sol + nw; /* the factorised step's rows are no longer needed */
  double theta_prev = ls->trial.theta;
  /* restoration phase: the corrected step's elastic steps go to dpe, dne (read by the step rules
     and the trial), the Newton step's are kept and put back unless a correction is accepted */
  if (S->resto) {
    memcpy(S->dpe_keep, S->dpe, sizeof(double) * ng);
    memcpy(S->dne_keep, S->dne, sizeof(double) * ng);
  }
  for (int i = 0; i < ng; ++i) c_soc[i] = ls->alpha * S->cres[i];
  for (int k = 0; k < IPM_MAX_SOC; ++k) {
    for (int i = 0; i < ng; ++i) {
      double ci = IS_EQ(i) ? S->gt[i] * S->dc[i] - S->lg[i] : S->gt[i] * S->dc[i] - S->st_[i];
      if (ELASTIC(i)) ci += S->net[i] - S->pet[i];
      c_soc[i] += ci;
    }
    for (int j = 0; j < nw; ++j) S->tmp[j] = S->rhs[j];
    for (int i = 0; i < ng; ++i) S->tmp[nw + i] = S->rhs[nw + i] + S->cres[i] - c_soc[i];
    solve_permuted(S, S->tmp, S->soc_buf, S->tmp);
    unpack_step(S, S->tmp, mu, dw, S->dx_soc, S->ds_soc);
    if (S->resto) elastic_steps(S, S->tmp + nw, mu, dw);
    double asoc = primal_step_max(S, S->dx_soc, S->ds_soc, tau);
    int ok = trial_eval(S, S->dx_soc, S->ds_soc, asoc, mu, &ls->trial);
    if (ok < 0) return -1;
    stats->soc++;
    if (ok && acceptable(&ls->trial, m, ls->alpha, ls->theta_min, F, &ls->f_type)) {
      ls->accepted = 1; ls->soc_used = 1;
      memcpy(S->dx, S->dx_soc, sizeof(double) * nw);
      memcpy(S->ds, S->ds_soc, sizeof(double) * ng);
      ls->alpha = asoc;
      return 0;
    }
    if (!ok || ls->trial.theta > IPM_KAPPA_SOC * theta_prev) break;
    theta_prev = ls->trial.theta;
  }
  if (S->resto) {
    memcpy(S->dpe, S->dpe_keep, sizeof(double) * ng);
    memcpy(S->dne, S->dne_keep, sizeof(double) * ng);
  }
  return 0;
}

/* IPOPT's filter line search by backtracking from alpha_max. A trial point must be acceptable to
   the filter and either (f-type, when the step is a good descent direction for phi and theta is
   small) satisfy Armijo on phi, or (h-type) reduce theta or phi sufficiently; h-type steps add the
   current point to the filter (done by the caller). Returns -1 on an evaluation error. */
static int line_search(ipm_ws *S, const merit_t *m, const filter_t *F, double alpha_max, double mu, double dw,
                       double tau, search_t *ls, ipm_stats *stats) {
  ls->theta_min = IPM_THETA_MIN_FACTOR * fmax(1.0, m->theta0);
  ls->alpha = alpha_max;
  ls->accepted = ls->f_type = ls->soc_used = 0;
  ls->trial.phi = ls->trial.theta = 0.0;
  for (int k = 0; k < IPM_MAX_BACKTRACKS; ++k) {
    int ok = trial_eval(S, S->dx, S->ds, ls->alpha, mu, &ls->trial);
    if (ok < 0) return -1;
    if (ok && acceptable(&ls->trial, m, ls->alpha, ls->theta_min, F, &ls->f_type)) { ls->accepted = 1; break; }
    if (k == 0 && ok && ls->trial.theta >= m->theta0) {
      if (second_order_corrections(S, m, F, mu, dw, tau, ls, stats) < 0) return -1;
      if (ls->accepted) break;
    }
    ls->alpha *= IPM_ALPHA_FACTOR;
    stats->backtracks++;
    if (ls->alpha < IPM_ALPHA_MIN) break;
  }
  return 0;
}

/* h-type steps add the current point (with IPOPT's margins) to the filter. */
static void augment_filter(filter_t *F, const merit_t *m) {
  if (F->n >= IPM_MAX_FILTER) return;
  F->theta[F->n] = (1.0 - IPM_GAMMA_THETA) * m->theta0;
  F->phi[F->n] = m->phi0 - IPM_GAMMA_PHI * m->theta0;
  F->n++;
}

/* ------------------------------------------------------------------------------ update -- */

static void take_step(ipm_ws *S, double alpha, double ad) {
  for (int j = 0; j < S->nw; ++j) {
    S->x[j] += alpha * S->dx[j];
    S->zl[j] += ad * S->dzl[j];
    S->zu[j] += ad * S->dzu[j];
  }
  for (int i = 0; i < S->ng; ++i) {
    S->y[i] += alpha * S->dy[i];
    S->s[i] += alpha * S->ds[i];
    S->vl[i] += ad * S->dvl[i];
    S->vu[i] += ad * S->dvu[i];
  }
  if (S->resto)
    for (int i = 0; i < S->ng; ++i) {
      if (!ELASTIC(i)) continue;
      S->pe[i] += alpha * S->dpe[i];
      S->ne[i] += alpha * S->dne[i];
      S->zp[i] += ad * S->dzp[i];
      S->zn[i] += ad * S->dzn[i];
    }
}

/* z kept within [b / kappa_sigma, kappa_sigma b], b = mu / slack (IPOPT's kappa_Sigma safeguard). */
static double clip_multiplier(double z, double b) {
  return fmax(fmin(z, IPM_KAPPA_SIGMA * b), b / IPM_KAPPA_SIGMA);
}

static void clip_bound_multipliers(ipm_ws *S, double mu) {
  const double *lbg = S->lbg, *ubg = S->ubg;
  const double *x = S->x, *lx = S->lx, *ux = S->ux, *s = S->s, *lg = S->lg, *ug = S->ug;
  const int nw = S->nw, ng = S->ng;
  double *zl = S->zl, *zu = S->zu, *vl = S->vl, *vu = S->vu;
  for (int j = 0; j < nw; ++j) {
    if (isfinite(lx[j])) zl[j] = clip_multiplier(zl[j], mu / (x[j] - lx[j]));
    if (isfinite(ux[j])) zu[j] = clip_multiplier(zu[j], mu / (ux[j] - x[j]));
  }
  for (int i = 0; i < ng; ++i) {
    if (IS_EQ(i)) continue;
    if (isfinite(lg[i])) vl[i] = clip_multiplier(vl[i], mu / (s[i] - lg[i]));
    if (isfinite(ug[i])) vu[i] = clip_multiplier(vu[i], mu / (ug[i] - s[i]));
  }
  if (S->resto)
    for (int i = 0; i < ng; ++i)
      if (ELASTIC(i)) {
        S->zp[i] = clip_multiplier(S->zp[i], mu / S->pe[i]);
        S->zn[i] = clip_multiplier(S->zn[i], mu / S->ne[i]);
      }
}

/* ------------------------------------------------------------------ restoration phase -- */
/*
 * IPOPT's restoration phase (Waechter & Biegler 2006, section 3.3): from the point x_R where the
 * line search failed, the l1 elastic feasibility problem
 *
 *     min  rho sum_i (pe_i + ne_i) + zeta/2 sum_j dr2_j (x_j - xr_j)^2
 *     s.t. c_i(x, s) - pe_i + ne_i = 0,  pe, ne >= 0,  x and s within their bounds,
 *
 * (c: the scaled residual g - s of an inequality row, g - lbg of an equality row; zeta =
 * IPM_RESTO_PROXIMITY sqrt(mu); dr2_j = min(1, 1/|xr_j|)^2) is solved by the same barrier method.
 * pe, ne carry log barriers; their Newton steps are eliminated row by row, which only adds
 * 1/(sigma_pe + dw) + 1/(sigma_ne + dw) to the row's diagonal of the augmented matrix and a term to
 * its right-hand side (elastic_rhs): the band, its pattern and its bandwidth are those of the
 * original problem. Fixing rows (initial value embedding) get no elastic pair: they stay exact.
 *
 * Ends: (a) the original violation theta = |c|_1 fell below IPM_KAPPA_RESTO times its value at
 * the failure (phase1: the unscaled violation <= constr_viol_tol): back to the original problem;
 * (b) the feasibility problem converged (scaled KKT error <= tol at mu <= resto_mu_cert) with the
 * unscaled violation still above constr_viol_tol: a stationary point of the l1 violation with
 * positive violation, the certificate of local infeasibility; (c) anything else: undecided.
 */

static double resto_objective(ipm_ws *S, const double *xv, double a, double mu) {
  double f = 0.0;
  for (int j = 0; j < S->nw; ++j) { double d = xv[j] - S->xr[j]; f += S->dr2[j] * d * d; }
  f *= 0.5 * S->zeta;
  for (int i = 0; i < S->ng; ++i) {
    if (!ELASTIC(i)) continue;
    S->pet[i] = S->pe[i] + a * S->dpe[i];
    S->net[i] = S->ne[i] + a * S->dne[i];
    f += S->rho * (S->pet[i] + S->net[i]) - mu * (log(S->pet[i]) + log(S->net[i]));
  }
  return f;
}

/* The proximity term's value (*fval) and gradient (grad) at x, with the current zeta. */
static void resto_gradient(ipm_ws *S, double *fval) {
  double f = 0.0;
  for (int j = 0; j < S->nw; ++j) {
    double d = S->x[j] - S->xr[j];
    S->grad[j] = S->zeta * S->dr2[j] * d;
    f += S->dr2[j] * d * d;
  }
  *fval = 0.5 * S->zeta * f;
}

/* g and J at x (scaled), the proximity objective and its gradient. */
static int resto_evaluate(ipm_ws *S, double *fval) {
  const ipm_struct *st = S->st;
  if (call(&S->E, st->f_jac_g, S->x, S->p, 0, 0, S->g, S->jraw)) return IPM_EVALUATION_ERROR;
  for (int e = 0; e < st->n_j; ++e) S->jac[e] = S->jraw[e] * S->dc[st->j_rows[e]];
  for (int i = 0; i < S->ng; ++i) S->g[i] *= S->dc[i];
  resto_gradient(S, fval);
  return IPM_CONVERGED;
}

/* ne >= 0 of the pair minimising rho (pe + ne) - mu log(pe) - mu log(ne) with pe - ne = c
   (IPOPT's start of the elastic variables), in a form without cancellation. */
static double elastic_start(double c, double mu, double rho) {
  double a = (mu - rho * c) / (2.0 * rho), b = mu * c / (2.0 * rho);
  double r = sqrt(a * a + b);
  return a >= 0.0 ? a + r : b / (r - a);
}

/* The restoration problem's start at the current (x, s): reference point, elastic pairs at their
   barrier minimisers, y = 0, bound multipliers centred (slack * multiplier = mu). */
static int resto_start(ipm_ws *S, double mu) {
  const double *lbg = S->lbg, *ubg = S->ubg;
  const int nw = S->nw, ng = S->ng;
  if (call(&S->E, S->st->f_g, S->x, S->p, 0, 0, S->g, 0)) return IPM_EVALUATION_ERROR;
  for (int j = 0; j < nw; ++j) {
    double d = fmin(1.0, 1.0 / fabs(S->x[j]));
    S->xr[j] = S->x[j];
    S->dr2[j] = d * d;
    S->zl[j] = isfinite(S->lx[j]) ? mu / (S->x[j] - S->lx[j]) : 0.0;
    S->zu[j] = isfinite(S->ux[j]) ? mu / (S->ux[j] - S->x[j]) : 0.0;
  }
  for (int i = 0; i < ng; ++i) {
    S->y[i] = 0.0;
    if (!IS_EQ(i)) {
      S->vl[i] = isfinite(S->lg[i]) ? mu / (S->s[i] - S->lg[i]) : 0.0;
      S->vu[i] = isfinite(S->ug[i]) ? mu / (S->ug[i] - S->s[i]) : 0.0;
    }
    if (!ELASTIC(i)) continue;
    double gi = S->g[i] * S->dc[i];
    double c = IS_EQ(i) ? gi - S->lg[i] : gi - S->s[i];
    S->ne[i] = elastic_start(c, mu, S->rho);
    S->pe[i] = c + S->ne[i];
    if (!(S->pe[i] > 0.0)) S->pe[i] = mu / S->rho; /* round-off when c << 0 */
    S->zp[i] = mu / S->pe[i];
    S->zn[i] = mu / S->ne[i];
  }
  return IPM_CONVERGED;
}

/* |c|_1 of the original rows (scaled) at the current (x, s), from the residuals' cres. */
static double original_theta(const ipm_ws *S) {
  double th = 0.0;
  for (int i = 0; i < S->ng; ++i) th += fabs(ELASTIC(i) ? S->cres[i] - S->ne[i] + S->pe[i] : S->cres[i]);
  return th;
}

/* One restoration phase from the current point (the original problem's mu0, its theta at the
   failure theta_fail). Returns IPM_CONVERGED when the original problem may go on from the new
   point, else the status that ends the solve. */
static int restoration(ipm_ws *S, double mu0, double theta_fail, int phase1, ipm_stats *stats) {
  const ipm_opts *o = S->o;
  const ipm_struct *st = S->st;
  double zero = 0.0, fval = 0.0;
  stats->resto_calls++;
  S->resto = 1;
  S->rho = o->resto_rho;
  /* mu_R = max(mu, |c|_inf) as in IPOPT, from the scaled residual of the original rows */
  double cmax = 0.0;
  if (call(&S->E, st->f_g, S->x, S->p, 0, 0, S->g, 0)) { S->resto = 0; return IPM_EVALUATION_ERROR; }
  for (int i = 0; i < S->ng; ++i) {
    double gi = S->g[i] * S->dc[i];
    if (!S->fixed[i]) cmax = fmax(cmax, fabs(S->lbg[i] == S->ubg[i] ? gi - S->lg[i] : gi - S->s[i]));
  }
  double mu = fmax(mu0, cmax);
  S->zeta = IPM_RESTO_PROXIMITY * sqrt(mu);
  int status = resto_start(S, mu);
  filter_t F = {.n = 0, .mu = -1.0, .theta_max = INFINITY};
  double dw_last = 0.0;
  for (int it = 0; status == IPM_CONVERGED; ++it) {
    if (resto_evaluate(S, &fval)) { status = IPM_EVALUATION_ERROR; break; }
    kkt_errors err = residuals(S);
    double theta = original_theta(S);
    double err0 = fmax(err.inf_du / err.sd, fmax(err.inf_pr, err.inf_co / err.sc));
    stats->inf_pr = err.viol_unscaled; stats->mu = mu;
    stats->cert_violation = theta; stats->cert_stationarity = err0; stats->cert_mu = mu;
    if (!isfinite(err0)) { status = IPM_RESTORATION_FAILED; break; }
    int feasible = err.viol_unscaled <= o->constr_viol_tol;
    if (phase1 ? feasible : theta < IPM_KAPPA_RESTO * theta_fail) break; /* restored */
    if (err0 <= o->tol && mu <= o->resto_mu_cert) {
      status = feasible ? IPM_CONVERGED : IPM_INFEASIBLE_PROBLEM_DETECTED;
      break;
    }
    if (it >= o->resto_max_iter) { status = IPM_RESTORATION_FAILED; break; }
    mu = update_barrier(S, mu, &err);
    S->zeta = IPM_RESTO_PROXIMITY * sqrt(mu);
    resto_gradient(S, &fval);
    double tau = fmax(IPM_TAU_MIN, 1.0 - mu);
    for (int i = 0; i < S->ng; ++i) S->tmp[i] = S->y[i] * S->dc[i];
    if (call(&S->E, st->f_hess_l, S->x, S->p, &zero, S->tmp, S->hess, 0)) { status = IPM_EVALUATION_ERROR; break; }
    barrier_diagonals(S);
    double dw = 0.0;
    if (newton_step(S, mu, dw_last, &dw, stats)) { status = IPM_RESTORATION_FAILED; break; }
    dw_last = dw;
    bound_multiplier_steps(S, mu);
    double ap = primal_step_max(S, S->dx, S->ds, tau);
    double ad = dual_step_max(S, tau);
    merit_t m = current_merit(S, fval, mu);
    if (mu != F.mu) { F.n = 0; F.mu = mu; F.theta_max = IPM_THETA_MAX_FACTOR * fmax(1.0, m.theta0); }
    search_t ls;
    if (line_search(S, &m, &F, ap, mu, dw, tau, &ls, stats)) { status = IPM_EVALUATION_ERROR; break; }
    if (ls.soc_used) { bound_multiplier_steps(S, mu); ad = dual_step_max(S, tau); }
    if (o->verbose)
      fprintf(stderr, "resto %2d mu %.1e theta %.2e elastic %.2e phi0 %.6e err0 %.2e ap %.3e alpha %.3e dw %.1e\n",
              it, mu, theta, m.theta0, m.phi0, err0, ap, ls.alpha, dw);
    if (!ls.accepted) { status = IPM_RESTORATION_FAILED; break; }
    if (!ls.f_type) augment_filter(&F, &m);
    take_step(S, ls.alpha, ad);
    clip_bound_multipliers(S, mu);
    stats->resto_iterations++;
  }
  S->resto = 0;
  return status;
}

/* Back to the original problem after a restoration: its multipliers restart from y = 0 (the
   restoration's y belong to the l1 problem); the bound multipliers are the restoration's. */
static void leave_restoration(ipm_ws *S) {
  for (int i = 0; i < S->ng; ++i) S->y[i] = 0.0;
}

/* ----------------------------------------------------------------------------- the solver -- */

/* Outputs in CasADi's convention (unscaled). */
static void write_multipliers(const ipm_ws *S, double *lam_x, double *lam_g) {
  for (int i = 0; i < S->ng; ++i) lam_g[i] = S->y[i] * S->dc[i];
  for (int j = 0; j < S->nw; ++j) lam_x[j] = S->zu[j] - S->zl[j];
}

static int finish(ipm_stats *stats, int status) {
  stats->status = status;
  return status;
}

/* The start: relaxed bounds, embedding, row scales, pushed primal point, duals; sets *mu. */
static int start(ipm_ws *S, const double *lam_x, const double *lam_g, ipm_stats *stats, double *mu) {
  const ipm_opts *o = S->o;
  relax_variable_bounds(S);
  if (embed_initial_value(S)) return IPM_EVALUATION_ERROR;
  double theta_start = 0.0;
  if (scale_rows(S, &theta_start)) return IPM_EVALUATION_ERROR;
  stats->theta_start = theta_start;
  stats->far = o->warm && theta_start > o->theta_far;
  const double push = stats->far ? o->push_far : o->bound_push;
  *mu = stats->far ? o->mu_far : o->mu_init;
  if (primal_start(S, push)) return IPM_EVALUATION_ERROR;
  dual_start(S, lam_x, lam_g);
  return IPM_CONVERGED;
}

int ipm_solve(const ipm_struct *st, const ipm_opts *o, const double *p, const double *lbx, const double *ubx,
              const double *lbg, const double *ubg, double *x, double *lam_x, double *lam_g, ipm_stats *stats,
              double *wd, int *wi) {
  ipm_ws W = {0};
  ipm_ws *S = &W;
  S->st = st; S->o = o; S->p = p; S->lbx = lbx; S->ubx = ubx; S->lbg = lbg; S->ubg = ubg; S->x = x;
  S->nw = st->n_w; S->ng = st->n_g; S->n = st->n;
  carve_workspace(S, wd, wi);
  init_stats(stats, o);
  double mu = 0.0, fval = 0.0, one = 1.0;
  int status = start(S, lam_x, lam_g, stats, &mu);
  if (status) return finish(stats, status);
  if (o->phase1) {
    status = restoration(S, mu, INFINITY, 1, stats);
    stats->iterations = stats->resto_iterations;
    write_multipliers(S, lam_x, lam_g);
    return finish(stats, status == IPM_CONVERGED ? IPM_FEASIBLE_POINT_FOUND : status);
  }

  filter_t F = {.n = 0, .mu = -1.0, .theta_max = INFINITY};
  double dw_last = 0.0; /* last successful primal regularisation */
  for (int it = 0; it <= o->max_iter; ++it) {
    stats->iterations = it + stats->resto_iterations;
    if (evaluate(S, &fval)) return finish(stats, IPM_EVALUATION_ERROR);
    kkt_errors err = residuals(S);
    stats->inf_pr = err.viol_unscaled; stats->inf_du = err.inf_du / err.sd; stats->mu = mu;
    if (!isfinite(err.inf_du) || !isfinite(err.inf_pr)) return finish(stats, IPM_NONFINITE);
    /* termination: overall optimality (mu = 0) */
    double err0 = fmax(err.inf_du / err.sd, fmax(err.inf_pr, err.inf_co / err.sc));
    if (err0 <= o->tol && err.viol_unscaled <= o->constr_viol_tol) { stats->status = IPM_CONVERGED; break; }
    if (it == o->max_iter) { stats->status = IPM_MAX_ITERATIONS; break; }
    mu = update_barrier(S, mu, &err);
    double tau = fmax(IPM_TAU_MIN, 1.0 - mu);
    /* Hessian of the Lagrangian (unscaled multipliers) */
    for (int i = 0; i < S->ng; ++i) S->tmp[i] = S->y[i] * S->dc[i];
    if (call(&S->E, st->f_hess_l, x, p, &one, S->tmp, S->hess, 0)) return finish(stats, IPM_EVALUATION_ERROR);
    barrier_diagonals(S);
    double dw = 0.0;
    if (newton_step(S, mu, dw_last, &dw, stats)) return finish(stats, IPM_REGULARISATION_FAILED);
    dw_last = dw;
    if (dw > 0.0) stats->regularised++;
    bound_multiplier_steps(S, mu);
    double ap = primal_step_max(S, S->dx, S->ds, tau);
    double ad = dual_step_max(S, tau);

    merit_t m = current_merit(S, fval, mu);
    if (it == 0 || mu != F.mu) { F.n = 0; F.mu = mu; F.theta_max = IPM_THETA_MAX_FACTOR * fmax(1.0, m.theta0); }
    search_t ls;
    if (line_search(S, &m, &F, ap, mu, dw, tau, &ls, stats)) return finish(stats, IPM_EVALUATION_ERROR);
    if (ls.soc_used) { /* bound-multiplier steps and their step size from the corrected step */
      bound_multiplier_steps(S, mu);
      ad = dual_step_max(S, tau);
    }
    if (o->verbose)
      fprintf(stderr, "it %2d mu %.1e theta0 %.2e phi0 %.6e dphi %.2e inf_du %.2e err0 %.2e ap %.3e ad %.3e alpha %.3e dw %.1e %s\n",
              it, mu, m.theta0, m.phi0, m.dphi, err.inf_du / err.sd, err0, ap, ad, ls.alpha, dw, ls.f_type ? "f" : "h");
    if (!ls.accepted && o->restoration && stats->resto_calls < IPM_MAX_RESTO_CALLS) {
      status = restoration(S, mu, m.theta0, 0, stats);
      stats->iterations = it + stats->resto_iterations;
      if (status != IPM_CONVERGED) { write_multipliers(S, lam_x, lam_g); return finish(stats, status); }
      leave_restoration(S);
      F.mu = -1.0; /* a new filter from the restored point */
      continue;
    }
    if (!ls.accepted) return finish(stats, IPM_LINE_SEARCH_FAILED);
    if (!ls.f_type) augment_filter(&F, &m);
    if (it == 0) stats->first_alpha = ls.soc_used ? -ls.alpha : ls.alpha; /* negative: a corrected step */
    take_step(S, ls.alpha, ad);
    clip_bound_multipliers(S, mu);
  }
  write_multipliers(S, lam_x, lam_g);
  return stats->status;
}

/* ---------------------------------------------------------------------------------- ABI -- */

int ipm_abi_version(void) { return IPM_ABI_VERSION; }

#define OFF(T, f) (int64_t)offsetof(T, f)

int ipm_abi_layout(int64_t *out, int cap) {
  const int64_t layout[] = {
    (int64_t)sizeof(ipm_struct), 30,
    OFF(ipm_struct, n_w), OFF(ipm_struct, n_g), OFF(ipm_struct, n), OFF(ipm_struct, bw), OFF(ipm_struct, ldab),
    OFF(ipm_struct, n_j), OFF(ipm_struct, j_rows), OFF(ipm_struct, j_cols),
    OFF(ipm_struct, n_h), OFF(ipm_struct, h_rows), OFF(ipm_struct, h_cols),
    OFF(ipm_struct, n_hs), OFF(ipm_struct, hs_row), OFF(ipm_struct, hs_col), OFF(ipm_struct, hs_src),
    OFF(ipm_struct, perm), OFF(ipm_struct, n_ent), OFF(ipm_struct, ent_kind), OFF(ipm_struct, ent_src),
    OFF(ipm_struct, ent_row), OFF(ipm_struct, ent_pos),
    OFF(ipm_struct, f_g), OFF(ipm_struct, f_grad_f), OFF(ipm_struct, f_jac_g), OFF(ipm_struct, f_hess_l),
    OFF(ipm_struct, work_sizes), OFF(ipm_struct, n_fix), OFF(ipm_struct, fix_row), OFF(ipm_struct, fix_var),
    OFF(ipm_struct, fix_coef),
    (int64_t)sizeof(ipm_opts), 18,
    OFF(ipm_opts, tol), OFF(ipm_opts, constr_viol_tol), OFF(ipm_opts, mu_init), OFF(ipm_opts, mu_min),
    OFF(ipm_opts, bound_push), OFF(ipm_opts, mult_push), OFF(ipm_opts, bound_relax), OFF(ipm_opts, max_iter),
    OFF(ipm_opts, warm), OFF(ipm_opts, verbose), OFF(ipm_opts, theta_far), OFF(ipm_opts, mu_far),
    OFF(ipm_opts, push_far), OFF(ipm_opts, restoration), OFF(ipm_opts, phase1), OFF(ipm_opts, resto_max_iter),
    OFF(ipm_opts, resto_rho), OFF(ipm_opts, resto_mu_cert),
    (int64_t)sizeof(ipm_stats), 17,
    OFF(ipm_stats, iterations), OFF(ipm_stats, status), OFF(ipm_stats, factorisations),
    OFF(ipm_stats, regularised), OFF(ipm_stats, backtracks), OFF(ipm_stats, soc), OFF(ipm_stats, far),
    OFF(ipm_stats, inf_pr), OFF(ipm_stats, inf_du), OFF(ipm_stats, mu), OFF(ipm_stats, theta_start),
    OFF(ipm_stats, first_alpha), OFF(ipm_stats, resto_calls), OFF(ipm_stats, resto_iterations),
    OFF(ipm_stats, cert_violation), OFF(ipm_stats, cert_stationarity), OFF(ipm_stats, cert_mu),
  };
  const int count = (int)(sizeof layout / sizeof layout[0]);
  if (count <= cap) memcpy(out, layout, sizeof layout);
  return count;
}

#undef OFF

const char *ipm_status_name(int status) {
  static const char *const names[IPM_STATUS_COUNT] = {
    [IPM_CONVERGED] = "Converged",
    [IPM_MAX_ITERATIONS] = "Max_Iterations",
    [IPM_LINE_SEARCH_FAILED] = "Line_Search_Failed",
    [IPM_REGULARISATION_FAILED] = "Regularisation_Failed",
    [IPM_NONFINITE] = "Nonfinite",
    [IPM_EVALUATION_ERROR] = "Evaluation_Error",
    [IPM_INFEASIBLE_PROBLEM_DETECTED] = "Infeasible_Problem_Detected",
    [IPM_RESTORATION_FAILED] = "Restoration_Failed",
    [IPM_FEASIBLE_POINT_FOUND] = "Feasible_Point_Found",
  };
  return status >= 0 && status < IPM_STATUS_COUNT ? names[status] : NULL;
}
