/*
 * ipm.c - a lean primal-dual interior-point method for the TO-CBF-MPC NLP (mcverify/ipm.py).
 *
 * The algorithm is IPOPT's (Waechter & Biegler 2006) without its filter: slacks for the
 * inequality rows, log barriers on every finite bound, the primal-dual Newton step from the
 * augmented system
 *
 *     [ W + Sigma_x + dw I    J^T ] [dx]   [ -grad phi_mu - J^T y            ]
 *     [ J                    -D   ] [dy] = [ -c (+ q / Sigma_s on slack rows) ]
 *
 * (D = 1/Sigma_s on inequality rows, dc on equality rows), fraction-to-the-boundary step
 * rules, a backtracking line search on the l1 merit function phi_mu + nu |c|_1, and the
 * monotone barrier update. What makes it fast is the linear algebra and the absence of layers:
 * the KKT matrix has a fixed pattern that a reverse Cuthill-McKee ordering makes banded
 * (bandwidth 16 for N = 50), factorised by a banded LU with partial pivoting in tens of
 * microseconds, and the NLP's functions are the CasADi-generated C of the kernel, called
 * through function pointers. Inertia is not available from an LU; the step is instead
 * accepted only if it has positive curvature, dx'(W + Sigma_x + dw)dx + ds' Sigma_s ds >=
 * 1e-12 |(dx, ds)|^2 (the inertia-free test of Chiang & Zavala 2016), otherwise dw grows as
 * in IPOPT (1e-4, then x8).
 *
 * Rows of g are scaled by min(1, 100 / max_j |J_ij|) at the starting point (IPOPT's
 * gradient-based scaling); the objective is not scaled. Multipliers come back unscaled in
 * CasADi's convention (L = f + lam_g' g + lam_x' x).
 *
 * Deterministic (fixed orders, no threads); no allocation (workspace from the caller).
 */
#include <math.h>
#include <stdint.h>
#include <string.h>
#include <stdio.h>

typedef long long casadi_int_t;
typedef int (*casadi_fun)(const double **arg, double **res, casadi_int_t *iw, double *w, int mem);

typedef struct {
  int n_w, n_g, n, bw, ldab;
  int n_j;
  const int *j_rows, *j_cols;
  int n_h;                 /* upper-triangle Hessian nonzeros */
  const int *h_rows, *h_cols;
  int n_hs;                /* full symmetric Hessian entries -> upper-triangle source */
  const int *hs_row, *hs_col, *hs_src;
  const int *perm;         /* perm[k]: original index at band position k */
  int n_ent;               /* KKT entries: kind 0 H (src: hs), 1 primal diag, 2 J^T, 3 J, 4 dual diag */
  const int *ent_kind, *ent_src, *ent_row;
  const int64_t *ent_pos;
  /* generated functions and their work sizes (arg, res, iw, w) */
  casadi_fun f_g, f_grad_f, f_jac_g, f_hess_l;
  const int64_t *work_sizes; /* 4 functions x 4 */
  /* rows of g with one constant Jacobian entry a (g_i = a x_j - c(p)), for the initial value embedding */
  int n_fix;
  const int *fix_row, *fix_var;
  const double *fix_coef;
} ipm_struct;

typedef struct {
  double tol, constr_viol_tol, mu_init, mu_min, bound_push, mult_push, bound_relax;
  int max_iter, warm, verbose;
  /* a start whose largest scaled constraint violation exceeds theta_far uses mu_far, push_far */
  double theta_far, mu_far, push_far;
} ipm_opts;

typedef struct {
  int iterations, status, factorisations, regularised, backtracks, soc, far;
  double inf_pr, inf_du, mu, theta_start, first_alpha; /* first_alpha: primal step of iteration 0 */
} ipm_stats;
/* status: 0 converged, 1 max iterations, 2 line search failed, 3 singular / no regularisation,
   4 nonfinite, 5 evaluation error */

/* ----------------------------------------------------------------------------- band LU ---- */

static int band_lu(double *ab, int n, int bw, int ldab, int *ipiv) {
  const int kl = bw, kv = 2 * bw;
  int ju = 0;
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < kl; ++i) ab[i + (int64_t)ldab * j] = 0.0;
  for (int j = 0; j < n; ++j) {
    int km = kl < n - 1 - j ? kl : n - 1 - j;
    double *col = ab + (int64_t)ldab * j + kv;
    int jp = 0;
    double amax = fabs(col[0]);
    for (int i = 1; i <= km; ++i)
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
          for (int i = 1; i <= km; ++i) a[i] -= col[i] * f;
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

/* ----------------------------------------------------------------------------- evaluation -- */

typedef struct {
  const ipm_struct *st;
  const double *p;
  const double **arg;
  double **res;
  casadi_int_t *iw;
  double *w;
} evalctx;

static int call(const evalctx *e, int which, casadi_fun f, const double *a0, const double *a1, const double *a2,
                const double *a3, double *r0, double *r1) {
  (void)which;
  e->arg[0] = a0; e->arg[1] = a1; e->arg[2] = a2; e->arg[3] = a3;
  e->res[0] = r0; e->res[1] = r1;
  return f(e->arg, e->res, e->iw, e->w, 0);
}


/* Evaluate the barrier objective and the infeasibility at (x + a dx, s + a ds). Returns 1 if
   finite, 0 if not evaluable (NaN/inf, out of the barrier's domain), -1 on an evaluation error. */
static int trial_eval(const evalctx *E, const ipm_struct *st, const double *p, const double *x, const double *s,
                      const double *dx, const double *ds, double a, double *xt, double *st_, double *gt,
                      double *gscratch, const double *lx, const double *ux, const double *lg, const double *ug,
                      const double *dc, const double *lbg, const double *ubg, double mu, double *phit,
                      double *thetat) {
  const int nw = st->n_w, ng = st->n_g;
  for (int j = 0; j < nw; ++j) xt[j] = x[j] + a * dx[j];
  for (int i = 0; i < ng; ++i) st_[i] = s[i] + a * ds[i];
  double ft = 0.0;
  if (call(E, 1, st->f_grad_f, xt, p, 0, 0, &ft, gscratch)) return -1;
  if (call(E, 0, st->f_g, xt, p, 0, 0, gt, 0)) return -1;
  double ph = ft, th = 0.0;
  if (!isfinite(ft)) return 0;
  for (int j = 0; j < nw; ++j) {
    if (isfinite(lx[j])) ph -= mu * log(xt[j] - lx[j]);
    if (isfinite(ux[j])) ph -= mu * log(ux[j] - xt[j]);
  }
  for (int i = 0; i < ng; ++i) {
    double gi = gt[i] * dc[i];
    if (!isfinite(gi)) return 0;
    if (lbg[i] == ubg[i]) th += fabs(gi - lg[i]);
    else {
      th += fabs(gi - st_[i]);
      if (isfinite(lg[i])) ph -= mu * log(st_[i] - lg[i]);
      if (isfinite(ug[i])) ph -= mu * log(ug[i] - st_[i]);
    }
  }
  *phit = ph; *thetat = th;
  return isfinite(ph) ? 1 : 0;
}

/* IPOPT's filter acceptance (switching condition, Armijo for f-type, sufficient decrease for h-type). */
static int acceptable(double phit, double thetat, double phi0, double theta0, double dphi, double alpha,
                      double theta_min, double theta_max, const double *ft, const double *fp, int nf, int *f_type) {
  if (thetat > theta_max) return 0;
  for (int k = 0; k < nf; ++k)
    if (!(thetat < ft[k] || phit < fp[k])) return 0;
  int switching = dphi < 0.0 && alpha * pow(-dphi, 2.3) > pow(theta0, 1.1) && theta0 <= theta_min;
  *f_type = 0;
  if (switching) {
    if (phit <= phi0 + 1e-8 * alpha * dphi) { *f_type = 1; return 1; }
    return 0;
  }
  return thetat <= (1.0 - 1e-5) * theta0 || phit <= phi0 - 1e-8 * theta0;
}

/* ----------------------------------------------------------------------------- the solver -- */


void ipm_work_sizes(const ipm_struct *st, int64_t *n_dbl, int64_t *n_int) {
  int64_t n = st->n, nw = st->n_w, ng = st->n_g;
  int64_t wmax = 0, iwmax = 0, amax = 0, rmax = 0;
  for (int k = 0; k < 4; ++k) {
    if (st->work_sizes[4 * k + 0] > amax) amax = st->work_sizes[4 * k + 0];
    if (st->work_sizes[4 * k + 1] > rmax) rmax = st->work_sizes[4 * k + 1];
    if (st->work_sizes[4 * k + 2] > iwmax) iwmax = st->work_sizes[4 * k + 2];
    if (st->work_sizes[4 * k + 3] > wmax) wmax = st->work_sizes[4 * k + 3];
  }
  *n_dbl = (int64_t)st->ldab * n + 8 * n + 24 * nw + 24 * ng + 2 * st->n_j + st->n_h + wmax + 64;
  *n_int = (n + 2) + 2 * (iwmax + 8) + 2 * (amax + 8) + 2 * (rmax + 8) + 64;
}

/* x (n_w), lam_x (n_w), lam_g (n_g): start in, solution out (multipliers unscaled, CasADi sign). */
int ipm_solve(const ipm_struct *st, const ipm_opts *o, const double *p, const double *lbx, const double *ubx,
              const double *lbg, const double *ubg, double *x, double *lam_x, double *lam_g, ipm_stats *stats,
              double *wd, int *wi) {
  const int nw = st->n_w, ng = st->n_g, n = st->n, bw = st->bw, ldab = st->ldab;
  /* ---- workspace ---- */
  double *ab = wd; wd += (int64_t)ldab * n;
  double *rhs = wd; wd += n;
  double *sol = wd; wd += n;
  double *tmp = wd; wd += n;
  double *soc_buf = wd; wd += n;
  wd += 4 * n;
  double *lx = wd; wd += nw;     /* relaxed bounds */
  double *ux = wd; wd += nw;
  double *zl = wd; wd += nw;
  double *zu = wd; wd += nw;
  double *grad = wd; wd += nw;
  double *dx = wd; wd += nw;
  double *dzl = wd; wd += nw;
  double *dzu = wd; wd += nw;
  double *xt = wd; wd += nw;     /* trial point */
  double *sigx = wd; wd += nw;
  double *jty = wd; wd += nw;
  double *hdx = wd; wd += nw;
  double *dx_soc = wd; wd += nw;
  wd += 11 * nw;
  double *lg = wd; wd += ng;     /* scaled, relaxed row bounds */
  double *ug = wd; wd += ng;
  double *dc = wd; wd += ng;     /* row scales */
  double *g = wd; wd += ng;      /* scaled g */
  double *s = wd; wd += ng;
  double *y = wd; wd += ng;      /* scaled multipliers */
  double *vl = wd; wd += ng;
  double *vu = wd; wd += ng;
  double *ds = wd; wd += ng;
  double *dy = wd; wd += ng;
  double *dvl = wd; wd += ng;
  double *dvu = wd; wd += ng;
  double *cres = wd; wd += ng;
  double *sigs = wd; wd += ng;
  double *gt = wd; wd += ng;
  double *st_ = wd; wd += ng;    /* trial slack */
  double *ds_soc = wd; wd += ng;
  wd += 7 * ng;
  double *jac = wd; wd += st->n_j; /* scaled */
  double *jraw = wd; wd += st->n_j;
  double *hess = wd; wd += st->n_h;
  double *fw = wd;               /* function work */
  int *ipiv = wi; wi += n + (n & 1); /* keep 8-byte alignment for what follows */
  casadi_int_t *iw = (casadi_int_t *)wi;
  int64_t iwmax = 0, amax = 0, rmax = 0;
  for (int k = 0; k < 4; ++k) {
    if (st->work_sizes[4 * k + 0] > amax) amax = st->work_sizes[4 * k + 0];
    if (st->work_sizes[4 * k + 1] > rmax) rmax = st->work_sizes[4 * k + 1];
    if (st->work_sizes[4 * k + 2] > iwmax) iwmax = st->work_sizes[4 * k + 2];
  }
  wi += 2 * (iwmax + 8);
  const double **arg = (const double **)wi; wi += 2 * (amax + 8);
  double **res = (double **)wi;
  evalctx E = {st, p, arg, res, iw, fw};

  stats->iterations = 0; stats->status = 0; stats->factorisations = 0; stats->regularised = 0; stats->backtracks = 0;
  stats->soc = 0; stats->far = 0; stats->theta_start = 0.0; stats->first_alpha = 0.0;
  stats->inf_pr = INFINITY; stats->inf_du = INFINITY; stats->mu = o->mu_init;
  double fval = 0.0, one = 1.0;

  /* ---- relaxed bounds (IPOPT's bound_relax_factor) ---- */
  for (int j = 0; j < nw; ++j) {
    lx[j] = isfinite(lbx[j]) ? lbx[j] - o->bound_relax * fmax(1.0, fabs(lbx[j])) : -INFINITY;
    ux[j] = isfinite(ubx[j]) ? ubx[j] + o->bound_relax * fmax(1.0, fabs(ubx[j])) : INFINITY;
  }
  /* ---- initial value embedding: each fixing row g_i = a x_j - c(p) is solved for x_j exactly, by
     evaluating g with x_j = 0 (g_i = -c(p)) ---- */
  for (int k = 0; k < st->n_fix; ++k) x[st->fix_var[k]] = 0.0;
  if (call(&E, 0, st->f_g, x, p, 0, 0, g, 0)) { stats->status = 5; return 5; }
  for (int k = 0; k < st->n_fix; ++k) {
    int i = st->fix_row[k], j = st->fix_var[k];
    x[j] = (lbg[i] - g[i]) / st->fix_coef[k];
  }
  /* ---- row scales from the Jacobian at the (embedded) start; how far is it from feasible? ---- */
  if (call(&E, 2, st->f_jac_g, x, p, 0, 0, g, jraw)) { stats->status = 5; return 5; }
  for (int i = 0; i < ng; ++i) dc[i] = 0.0;
  for (int e = 0; e < st->n_j; ++e) { double a = fabs(jraw[e]); if (a > dc[st->j_rows[e]]) dc[st->j_rows[e]] = a; }
  for (int i = 0; i < ng; ++i) dc[i] = dc[i] > 100.0 ? 100.0 / dc[i] : 1.0;
  double theta_start = 0.0;
  for (int i = 0; i < ng; ++i) {
    double v = fmax(lbg[i] - g[i], g[i] - ubg[i]);
    if (v > 0.0) theta_start = fmax(theta_start, v * dc[i]);
  }
  for (int j = 0; j < nw; ++j) theta_start = fmax(theta_start, fmax(lbx[j] - x[j], x[j] - ubx[j]));
  stats->theta_start = theta_start;
  stats->far = o->warm && theta_start > o->theta_far;
  const double push = stats->far ? o->push_far : o->bound_push;
  double mu = stats->far ? o->mu_far : o->mu_init;
  /* ---- primal start: pushed inside the (relaxed) bounds ---- */
  for (int j = 0; j < nw; ++j) {
    double push_l = isfinite(lx[j]) ? push * fmax(1.0, fabs(lx[j])) : 0.0;
    double push_u = isfinite(ux[j]) ? push * fmax(1.0, fabs(ux[j])) : 0.0;
    if (isfinite(lx[j]) && isfinite(ux[j])) {
      double half = 0.5 * (ux[j] - lx[j]);
      if (push_l > half) push_l = half;
      if (push_u > half) push_u = half;
    }
    if (isfinite(lx[j]) && x[j] < lx[j] + push_l) x[j] = lx[j] + push_l;
    if (isfinite(ux[j]) && x[j] > ux[j] - push_u) x[j] = ux[j] - push_u;
  }
  if (call(&E, 0, st->f_g, x, p, 0, 0, g, 0)) { stats->status = 5; return 5; }
  for (int i = 0; i < ng; ++i) {
    double l = lbg[i] * dc[i], u = ubg[i] * dc[i];
    if (lbg[i] == ubg[i]) { lg[i] = l; ug[i] = u; }
    else {
      lg[i] = isfinite(lbg[i]) ? l - o->bound_relax * fmax(1.0, fabs(l)) : -INFINITY;
      ug[i] = isfinite(ubg[i]) ? u + o->bound_relax * fmax(1.0, fabs(u)) : INFINITY;
    }
  }
#define IS_EQ(i) (lbg[i] == ubg[i])
  for (int i = 0; i < ng; ++i) {
    double gi = g[i] * dc[i];
    if (IS_EQ(i)) { s[i] = lg[i]; continue; }
    double push_l = isfinite(lg[i]) ? push * fmax(1.0, fabs(lg[i])) : 0.0;
    double push_u = isfinite(ug[i]) ? push * fmax(1.0, fabs(ug[i])) : 0.0;
    if (isfinite(lg[i]) && isfinite(ug[i])) {
      double half = 0.5 * (ug[i] - lg[i]);
      if (push_l > half) push_l = half;
      if (push_u > half) push_u = half;
    }
    s[i] = gi;
    if (isfinite(lg[i]) && s[i] < lg[i] + push_l) s[i] = lg[i] + push_l;
    if (isfinite(ug[i]) && s[i] > ug[i] - push_u) s[i] = ug[i] - push_u;
  }
  /* ---- dual start ---- */
  for (int i = 0; i < ng; ++i) {
    y[i] = o->warm ? lam_g[i] / dc[i] : 0.0;
    vl[i] = vu[i] = 0.0;
    if (IS_EQ(i)) continue;
    /* on slack rows y = vU - vL */
    if (isfinite(lg[i])) vl[i] = fmax(o->warm ? fmax(-y[i], 0.0) : 1.0, o->mult_push);
    if (isfinite(ug[i])) vu[i] = fmax(o->warm ? fmax(y[i], 0.0) : 1.0, o->mult_push);
  }
  for (int j = 0; j < nw; ++j) {
    zl[j] = zu[j] = 0.0;
    if (isfinite(lx[j])) zl[j] = fmax(o->warm ? fmax(-lam_x[j], 0.0) : 1.0, o->mult_push);
    if (isfinite(ux[j])) zu[j] = fmax(o->warm ? fmax(lam_x[j], 0.0) : 1.0, o->mult_push);
  }

#define MAX_FILTER 256
  double filt_theta[MAX_FILTER], filt_phi[MAX_FILTER];
  int nfilter = 0;
  double mu_filter = -1.0, theta_max = INFINITY;
  double dw_last = 0.0; /* last successful primal regularisation */
  for (int it = 0; it <= o->max_iter; ++it) {
    stats->iterations = it;
    /* ---- evaluate at x ---- */
    if (call(&E, 1, st->f_grad_f, x, p, 0, 0, &fval, grad)) { stats->status = 5; return 5; }
    if (call(&E, 2, st->f_jac_g, x, p, 0, 0, g, jraw)) { stats->status = 5; return 5; }
    for (int e = 0; e < st->n_j; ++e) jac[e] = jraw[e] * dc[st->j_rows[e]];
    for (int i = 0; i < ng; ++i) g[i] *= dc[i];
    /* residuals */
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
      inf_pr = fmax(inf_pr, fabs(cres[i]));
      double graw = g[i] / dc[i];
      viol_unscaled = fmax(viol_unscaled, fmax(lbg[i] - graw, graw - ubg[i]));
    }
    double smax = 100.0;
    double sd = fmax(smax, (ysum + zsum) / (cnt_y + cnt_z)) / smax;
    double sc = fmax(smax, zsum / (cnt_z > 0 ? cnt_z : 1)) / smax;
    stats->inf_pr = viol_unscaled; stats->inf_du = inf_du / sd; stats->mu = mu;
    if (!isfinite(inf_du) || !isfinite(inf_pr)) { stats->status = 4; return 4; }
    /* overall optimality (mu = 0) */
    double err0 = fmax(inf_du / sd, fmax(inf_pr, inf_co / sc));
    if (err0 <= o->tol && viol_unscaled <= o->constr_viol_tol) { stats->status = 0; break; }
    if (it == o->max_iter) { stats->status = 1; break; }
    /* barrier error and monotone mu update (possibly several times, IPOPT's rule) */
    for (int k = 0; k < 10; ++k) {
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
      double err_mu = fmax(inf_du / sd, fmax(inf_pr, co_mu / sc));
      if (err_mu > 10.0 * mu || mu <= o->mu_min) break;
      double mnew = fmin(0.2 * mu, pow(mu, 1.5));
      mu = fmax(o->mu_min, mnew);
    }
    double tau = fmax(0.99, 1.0 - mu);
    /* ---- Hessian of the Lagrangian (unscaled multipliers) ---- */
    for (int i = 0; i < ng; ++i) tmp[i] = y[i] * dc[i];
    if (call(&E, 3, st->f_hess_l, x, p, &one, tmp, hess, 0)) { stats->status = 5; return 5; }
    /* ---- barrier diagonals ---- */
    for (int j = 0; j < nw; ++j) {
      double sg = 0.0;
      if (isfinite(lx[j])) sg += zl[j] / (x[j] - lx[j]);
      if (isfinite(ux[j])) sg += zu[j] / (ux[j] - x[j]);
      sigx[j] = sg;
    }
    for (int i = 0; i < ng; ++i) {
      double sg = 0.0;
      if (!IS_EQ(i)) {
        if (isfinite(lg[i])) sg += vl[i] / (s[i] - lg[i]);
        if (isfinite(ug[i])) sg += vu[i] / (ug[i] - s[i]);
      }
      sigs[i] = sg;
    }
    /* ---- Newton step with inertia-free regularisation ---- */
    double dw = 0.0, dcr = 0.0;
    int solved = 0;
    for (int attempt = 0; attempt < 12 && !solved; ++attempt) {
      memset(ab, 0, sizeof(double) * (size_t)ldab * (size_t)n);
      for (int e = 0; e < st->n_ent; ++e) {
        int r = st->ent_row[e];
        double v;
        switch (st->ent_kind[e]) {
          case 0: v = hess[st->hs_src[st->ent_src[e]]]; break;
          case 1: v = sigx[r] + dw; break;
          case 2: case 3: v = jac[st->ent_src[e]]; break;
          default: {
            int i = r - nw;
            v = IS_EQ(i) ? -dcr : -1.0 / (sigs[i] + dw) - dcr;
          }
        }
        ab[st->ent_pos[e]] += v;
      }
      int info = band_lu(ab, n, bw, ldab, ipiv);
      stats->factorisations++;
      if (info != 0) {
        /* singular: regularise the constraints as well as the primal block */
        dcr = 1e-8 * pow(mu, 0.25);
        dw = dw == 0.0 ? (dw_last == 0.0 ? 1e-4 : fmax(1e-20, dw_last / 3.0)) : 8.0 * dw;
        continue;
      }
      /* right-hand side */
      for (int j = 0; j < nw; ++j) {
        double r = -grad[j] - jty[j];
        if (isfinite(lx[j])) r += mu / (x[j] - lx[j]);
        if (isfinite(ux[j])) r -= mu / (ux[j] - x[j]);
        rhs[j] = r;
      }
      for (int i = 0; i < ng; ++i) {
        if (IS_EQ(i)) rhs[nw + i] = -cres[i];
        else {
          double q = y[i];
          if (isfinite(lg[i])) q += mu / (s[i] - lg[i]);
          if (isfinite(ug[i])) q -= mu / (ug[i] - s[i]);
          rhs[nw + i] = -cres[i] + q / (sigs[i] + dw);
        }
      }
      for (int k = 0; k < n; ++k) tmp[k] = rhs[st->perm[k]];
      band_solve(ab, n, bw, ldab, ipiv, tmp);
      for (int k = 0; k < n; ++k) sol[st->perm[k]] = tmp[k];
      for (int j = 0; j < nw; ++j) dx[j] = sol[j];
      for (int i = 0; i < ng; ++i) dy[i] = sol[nw + i];
      /* a fixing row has one variable and zero residual: its step is exactly 0 (not round-off) */
      for (int k = 0; k < st->n_fix; ++k) dx[st->fix_var[k]] = 0.0;
      /* slack step */
      for (int i = 0; i < ng; ++i) {
        if (IS_EQ(i)) { ds[i] = 0.0; continue; }
        double q = y[i];
        if (isfinite(lg[i])) q += mu / (s[i] - lg[i]);
        if (isfinite(ug[i])) q -= mu / (ug[i] - s[i]);
        ds[i] = (dy[i] + q) / (sigs[i] + dw);
      }
      /* curvature test */
      for (int j = 0; j < nw; ++j) hdx[j] = 0.0;
      for (int e = 0; e < st->n_hs; ++e) hdx[st->hs_row[e]] += hess[st->hs_src[e]] * dx[st->hs_col[e]];
      double curv = 0.0, nrm = 0.0;
      for (int j = 0; j < nw; ++j) { curv += dx[j] * (hdx[j] + (sigx[j] + dw) * dx[j]); nrm += dx[j] * dx[j]; }
      for (int i = 0; i < ng; ++i) if (!IS_EQ(i)) { curv += (sigs[i] + dw) * ds[i] * ds[i]; nrm += ds[i] * ds[i]; }
      int finite = isfinite(curv);
      if (finite && curv >= 1e-12 * nrm) { solved = 1; break; }
      dw = dw == 0.0 ? (dw_last == 0.0 ? 1e-4 : fmax(1e-20, dw_last / 3.0)) : 8.0 * dw;
    }
    if (!solved) { stats->status = 3; return 3; }
    dw_last = dw;
    if (dw > 0.0) stats->regularised++;
    /* bound-multiplier steps */
    for (int j = 0; j < nw; ++j) {
      dzl[j] = isfinite(lx[j]) ? mu / (x[j] - lx[j]) - zl[j] - zl[j] / (x[j] - lx[j]) * dx[j] : 0.0;
      dzu[j] = isfinite(ux[j]) ? mu / (ux[j] - x[j]) - zu[j] + zu[j] / (ux[j] - x[j]) * dx[j] : 0.0;
    }
    for (int i = 0; i < ng; ++i) {
      dvl[i] = dvu[i] = 0.0;
      if (IS_EQ(i)) continue;
      if (isfinite(lg[i])) dvl[i] = mu / (s[i] - lg[i]) - vl[i] - vl[i] / (s[i] - lg[i]) * ds[i];
      if (isfinite(ug[i])) dvu[i] = mu / (ug[i] - s[i]) - vu[i] + vu[i] / (ug[i] - s[i]) * ds[i];
    }
    /* fraction to the boundary */
    double ap = 1.0, ad = 1.0;
    for (int j = 0; j < nw; ++j) {
      if (isfinite(lx[j]) && dx[j] < 0.0) ap = fmin(ap, -tau * (x[j] - lx[j]) / dx[j]);
      if (isfinite(ux[j]) && dx[j] > 0.0) ap = fmin(ap, tau * (ux[j] - x[j]) / dx[j]);
      if (dzl[j] < 0.0) ad = fmin(ad, -tau * zl[j] / dzl[j]);
      if (dzu[j] < 0.0) ad = fmin(ad, -tau * zu[j] / dzu[j]);
    }
    for (int i = 0; i < ng; ++i) {
      if (IS_EQ(i)) continue;
      if (isfinite(lg[i]) && ds[i] < 0.0) ap = fmin(ap, -tau * (s[i] - lg[i]) / ds[i]);
      if (isfinite(ug[i]) && ds[i] > 0.0) ap = fmin(ap, tau * (ug[i] - s[i]) / ds[i]);
      if (dvl[i] < 0.0) ad = fmin(ad, -tau * vl[i] / dvl[i]);
      if (dvu[i] < 0.0) ad = fmin(ad, -tau * vu[i] / dvu[i]);
    }
    /* ---- filter line search (IPOPT's, without second-order corrections) ----
       theta = |c|_1 (scaled rows), phi = barrier objective. A trial point must be acceptable to
       the filter and either (f-type, when the step is a good descent direction for phi and theta
       is small) satisfy Armijo on phi, or (h-type) reduce theta or phi sufficiently; h-type
       steps add the current point to the filter. */
    double theta0 = 0.0;
    for (int i = 0; i < ng; ++i) theta0 += fabs(cres[i]);
    double phi0 = fval, dphi = 0.0;
    for (int j = 0; j < nw; ++j) {
      double gj = grad[j];
      if (isfinite(lx[j])) { phi0 -= mu * log(x[j] - lx[j]); gj -= mu / (x[j] - lx[j]); }
      if (isfinite(ux[j])) { phi0 -= mu * log(ux[j] - x[j]); gj += mu / (ux[j] - x[j]); }
      dphi += gj * dx[j];
    }
    for (int i = 0; i < ng; ++i) {
      if (IS_EQ(i)) continue;
      double gs = 0.0;
      if (isfinite(lg[i])) { phi0 -= mu * log(s[i] - lg[i]); gs -= mu / (s[i] - lg[i]); }
      if (isfinite(ug[i])) { phi0 -= mu * log(ug[i] - s[i]); gs += mu / (ug[i] - s[i]); }
      dphi += gs * ds[i];
    }
    if (it == 0 || mu != mu_filter) { nfilter = 0; mu_filter = mu; theta_max = 1e4 * fmax(1.0, theta0); }
    double theta_min = 1e-4 * fmax(1.0, theta0);
    double alpha = ap;
    int accepted = 0, f_type = 0, soc_used = 0;
    double phit = 0.0, thetat = 0.0;
    /* trial at (x + a dx_, s + a ds_): sets phit, thetat; returns 1 if evaluable */
#define TRIAL(a_, DX_, DS_) trial_eval(&E, st, p, x, s, DX_, DS_, a_, xt, st_, gt, hdx, lx, ux, lg, ug, dc, lbg, ubg, mu, &phit, &thetat)
#define ACCEPTABLE(a_) acceptable(phit, thetat, phi0, theta0, dphi, a_, theta_min, theta_max, filt_theta, filt_phi, nfilter, &f_type)
    for (int ls = 0; ls < 40; ++ls) {
      int ok = TRIAL(alpha, dx, ds);
      if (ok < 0) { stats->status = 5; return 5; }
      if (ok && ACCEPTABLE(alpha)) { accepted = 1; break; }
      if (ls == 0 && ok && thetat >= theta0) {
        /* second-order corrections (IPOPT: up to 4, each must cut theta by kappa_soc = 0.99) */
        double theta_prev = thetat;
        for (int i = 0; i < ng; ++i) sol[nw + i] = alpha * cres[i]; /* c_soc accumulates here */
        for (int k = 0; k < 4; ++k) {
          for (int i = 0; i < ng; ++i) {
            double ci = IS_EQ(i) ? gt[i] * dc[i] - lg[i] : gt[i] * dc[i] - st_[i];
            sol[nw + i] += ci;
          }
          for (int j = 0; j < nw; ++j) tmp[j] = rhs[j];
          for (int i = 0; i < ng; ++i) tmp[nw + i] = rhs[nw + i] + cres[i] - sol[nw + i];
          for (int q = 0; q < n; ++q) soc_buf[q] = tmp[st->perm[q]];
          band_solve(ab, n, bw, ldab, ipiv, soc_buf);
          for (int q = 0; q < n; ++q) tmp[st->perm[q]] = soc_buf[q];
          for (int j = 0; j < nw; ++j) dx_soc[j] = tmp[j];
          for (int q = 0; q < st->n_fix; ++q) dx_soc[st->fix_var[q]] = 0.0;
          for (int i = 0; i < ng; ++i) {
            if (IS_EQ(i)) { ds_soc[i] = 0.0; continue; }
            double qv = y[i];
            if (isfinite(lg[i])) qv += mu / (s[i] - lg[i]);
            if (isfinite(ug[i])) qv -= mu / (ug[i] - s[i]);
            ds_soc[i] = (tmp[nw + i] + qv) / (sigs[i] + dw);
          }
          double asoc = 1.0;
          for (int j = 0; j < nw; ++j) {
            if (isfinite(lx[j]) && dx_soc[j] < 0.0) asoc = fmin(asoc, -tau * (x[j] - lx[j]) / dx_soc[j]);
            if (isfinite(ux[j]) && dx_soc[j] > 0.0) asoc = fmin(asoc, tau * (ux[j] - x[j]) / dx_soc[j]);
          }
          for (int i = 0; i < ng; ++i) {
            if (IS_EQ(i)) continue;
            if (isfinite(lg[i]) && ds_soc[i] < 0.0) asoc = fmin(asoc, -tau * (s[i] - lg[i]) / ds_soc[i]);
            if (isfinite(ug[i]) && ds_soc[i] > 0.0) asoc = fmin(asoc, tau * (ug[i] - s[i]) / ds_soc[i]);
          }
          int ok2 = TRIAL(asoc, dx_soc, ds_soc);
          if (ok2 < 0) { stats->status = 5; return 5; }
          stats->soc++;
          if (ok2 && ACCEPTABLE(alpha)) {
            accepted = 1; soc_used = 1;
            memcpy(dx, dx_soc, sizeof(double) * nw);
            memcpy(ds, ds_soc, sizeof(double) * ng);
            alpha = asoc;
            break;
          }
          if (!ok2 || thetat > 0.99 * theta_prev) break;
          theta_prev = thetat;
        }
        if (accepted) break;
      }
      alpha *= 0.5;
      stats->backtracks++;
      if (alpha < 1e-14) break;
    }
#undef TRIAL
#undef ACCEPTABLE
    if (soc_used) { /* bound-multiplier steps and their step size from the corrected step */
      ad = 1.0;
      for (int j = 0; j < nw; ++j) {
        dzl[j] = isfinite(lx[j]) ? mu / (x[j] - lx[j]) - zl[j] - zl[j] / (x[j] - lx[j]) * dx[j] : 0.0;
        dzu[j] = isfinite(ux[j]) ? mu / (ux[j] - x[j]) - zu[j] + zu[j] / (ux[j] - x[j]) * dx[j] : 0.0;
        if (dzl[j] < 0.0) ad = fmin(ad, -tau * zl[j] / dzl[j]);
        if (dzu[j] < 0.0) ad = fmin(ad, -tau * zu[j] / dzu[j]);
      }
      for (int i = 0; i < ng; ++i) {
        dvl[i] = dvu[i] = 0.0;
        if (IS_EQ(i)) continue;
        if (isfinite(lg[i])) dvl[i] = mu / (s[i] - lg[i]) - vl[i] - vl[i] / (s[i] - lg[i]) * ds[i];
        if (isfinite(ug[i])) dvu[i] = mu / (ug[i] - s[i]) - vu[i] + vu[i] / (ug[i] - s[i]) * ds[i];
        if (dvl[i] < 0.0) ad = fmin(ad, -tau * vl[i] / dvl[i]);
        if (dvu[i] < 0.0) ad = fmin(ad, -tau * vu[i] / dvu[i]);
      }
    }
    if (o->verbose)
      fprintf(stderr, "it %2d mu %.1e theta0 %.2e phi0 %.6e dphi %.2e inf_du %.2e err0 %.2e ap %.3e ad %.3e alpha %.3e dw %.1e %s\n",
              it, mu, theta0, phi0, dphi, inf_du / sd, err0, ap, ad, alpha, dw, f_type ? "f" : "h");
    if (!accepted) { stats->status = 2; return 2; }
    if (!f_type && nfilter < MAX_FILTER) { /* augment the filter */
      filt_theta[nfilter] = (1.0 - 1e-5) * theta0;
      filt_phi[nfilter] = phi0 - 1e-8 * theta0;
      nfilter++;
    }
    if (it == 0) stats->first_alpha = soc_used ? -alpha : alpha; /* negative: a corrected step */
    /* ---- update ---- */
    for (int j = 0; j < nw; ++j) {
      x[j] += alpha * dx[j];
      zl[j] += ad * dzl[j];
      zu[j] += ad * dzu[j];
    }
    for (int i = 0; i < ng; ++i) {
      y[i] += alpha * dy[i];
      s[i] += alpha * ds[i];
      vl[i] += ad * dvl[i];
      vu[i] += ad * dvu[i];
    }
    /* keep bound multipliers within a factor of mu / slack (IPOPT's kappa_Sigma safeguard) */
    for (int j = 0; j < nw; ++j) {
      if (isfinite(lx[j])) { double b = mu / (x[j] - lx[j]); zl[j] = fmax(fmin(zl[j], 1e10 * b), b / 1e10); }
      if (isfinite(ux[j])) { double b = mu / (ux[j] - x[j]); zu[j] = fmax(fmin(zu[j], 1e10 * b), b / 1e10); }
    }
    for (int i = 0; i < ng; ++i) {
      if (IS_EQ(i)) continue;
      if (isfinite(lg[i])) { double b = mu / (s[i] - lg[i]); vl[i] = fmax(fmin(vl[i], 1e10 * b), b / 1e10); }
      if (isfinite(ug[i])) { double b = mu / (ug[i] - s[i]); vu[i] = fmax(fmin(vu[i], 1e10 * b), b / 1e10); }
    }
  }
  /* ---- outputs in CasADi's convention ---- */
  for (int i = 0; i < ng; ++i) lam_g[i] = y[i] * dc[i];
  for (int j = 0; j < nw; ++j) lam_x[j] = zu[j] - zl[j];
  return stats->status;
#undef IS_EQ
}
