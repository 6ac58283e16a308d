/*
 * ipm.h - the ABI of the interior-point solver (ipm.c), as bound by mcverify/solver/ipm.py.
 *
 * The Python side mirrors the three structs below field by field (ctypes.Structure) and the
 * status codes in ipm.STATUS; at load it compares them with ipm_abi_version(), ipm_abi_layout()
 * and ipm_status_name(), so any edit here must be made there too (and IPM_ABI_VERSION raised
 * when a meaning changes without a change of layout).
 *
 * Calling sequence (one problem, many solves):
 *   1. fill an ipm_struct from the kernel's sparsity (mcverify.solver.kkt.KktStructure) and the
 *      kernel's generated function pointers;
 *   2. ipm_work_sizes(st, &n_dbl, &n_int): the caller allocates n_dbl doubles and n_int ints
 *      (8-byte aligned) once;
 *   3. ipm_solve(...) per solve, with that workspace. Nothing is allocated or kept between calls:
 *      the workspace is scratch, every result is written to the caller's x, lam_x, lam_g, stats.
 *
 * Ownership: every pointer in ipm_struct and every array argument belongs to the caller and must
 * stay valid for the call (ipm_struct's arrays: as long as the struct is used). The solver never
 * frees or keeps a pointer.
 *
 * Shapes (all arrays dense, C order, 0-based indices):
 *   n_w variables, n_g constraint rows, n = n_w + n_g unknowns of the KKT system, n_p parameters
 *   (the kernel's second input). Units are those of the NLP (mcverify.ocp.problem.build_nlp).
 */
#ifndef MCVERIFY_IPM_H
#define MCVERIFY_IPM_H

#include <stdint.h>

/* Raised when a struct's meaning changes; ipm.py refuses a library of another version. */
#define IPM_ABI_VERSION 4

/* ------------------------------------------------------------------------- status codes ---- */

/* Return value of ipm_solve and ipm_stats.status; ipm_status_name() gives the Python names. */
enum ipm_status {
  IPM_CONVERGED = 0,             /* scaled KKT error <= tol and unscaled violation <= constr_viol_tol */
  IPM_MAX_ITERATIONS = 1,        /* max_iter iterations without convergence */
  IPM_LINE_SEARCH_FAILED = 2,    /* no acceptable step in IPM_MAX_BACKTRACKS trials above IPM_ALPHA_MIN */
  IPM_REGULARISATION_FAILED = 3, /* KKT matrix singular or without positive curvature after
                                    IPM_MAX_REGULARISATIONS factorisations */
  IPM_NONFINITE = 4,             /* an infinite dual or primal residual (the max-norms use fmax, which
                                    skips NaN: a NaN derivative ends in IPM_REGULARISATION_FAILED) */
  IPM_EVALUATION_ERROR = 5,      /* a generated function returned nonzero */
  /* only with ipm_opts.restoration or ipm_opts.phase1 (never returned otherwise): */
  IPM_INFEASIBLE_PROBLEM_DETECTED = 6, /* certificate of local infeasibility: the restoration phase
                                    converged (its scaled KKT error <= tol at mu <= resto_mu_cert) to
                                    a point whose unscaled violation exceeds constr_viol_tol; the
                                    measured violation and stationarity are in ipm_stats.cert_* */
  IPM_RESTORATION_FAILED = 7,    /* undecided: the restoration phase neither restored feasibility
                                    nor converged (its iteration limit, line search or factorisation) */
  IPM_FEASIBLE_POINT_FOUND = 8,  /* phase1 only: a point with unscaled violation <= constr_viol_tol */
  IPM_STATUS_COUNT = 9
};

/* Kinds of KKT entries in ipm_struct.ent_kind (mcverify.solver.kkt.KIND_*). */
enum ipm_entry_kind {
  IPM_ENTRY_HESSIAN = 0,     /* W: ent_src indexes hs_src */
  IPM_ENTRY_PRIMAL_DIAG = 1, /* Sigma_x + dw of variable ent_row */
  IPM_ENTRY_JAC_T = 2,       /* J^T: ent_src indexes the Jacobian nonzeros */
  IPM_ENTRY_JAC = 3,         /* J: likewise */
  IPM_ENTRY_DUAL_DIAG = 4    /* -D of row ent_row - n_w */
};

/* ---------------------------------------------------------------- algorithmic constants ---- */
/* IPOPT's names (Waechter & Biegler 2006) where the constant has one; IPOPT's default values. */

#define IPM_SCALING_MAX_GRADIENT 100.0 /* rows scaled to a largest Jacobian entry of at most this */
#define IPM_S_MAX 100.0                /* s_max of the scaled dual and complementarity errors */
#define IPM_MAX_MU_UPDATES 10          /* barrier decreases per iteration at most */
#define IPM_KAPPA_EPSILON 10.0         /* decrease mu once the barrier error is <= kappa_eps mu */
#define IPM_KAPPA_MU 0.2               /* mu <- max(mu_min, min(kappa_mu mu, mu^theta_mu)) */
#define IPM_THETA_MU 1.5
#define IPM_TAU_MIN 0.99               /* fraction to the boundary: tau = max(tau_min, 1 - mu) */
#define IPM_MAX_REGULARISATIONS 12     /* factorisations per Newton step at most */
#define IPM_DELTA_W_FIRST 1e-4         /* first primal regularisation */
#define IPM_DELTA_W_MIN 1e-20          /* smallest primal regularisation */
#define IPM_KAPPA_W_MINUS 3.0          /* a step starts from the last regularisation / this */
#define IPM_KAPPA_W_PLUS 8.0           /* regularisation growth while it fails */
#define IPM_DELTA_C 1e-8               /* constraint regularisation delta_c mu^kappa_c (singular KKT) */
#define IPM_KAPPA_C 0.25
#define IPM_CURVATURE_MIN 1e-12        /* inertia-free test: curvature >= this |(dx, ds)|^2 */
#define IPM_MAX_BACKTRACKS 40          /* trial step lengths per line search at most */
#define IPM_ALPHA_FACTOR 0.5           /* backtracking factor */
#define IPM_ALPHA_MIN 1e-14            /* the line search fails below this step length */
#define IPM_MAX_SOC 4                  /* second-order corrections per line search at most */
#define IPM_KAPPA_SOC 0.99             /* each correction must cut theta by this factor */
#define IPM_THETA_MAX_FACTOR 1e4       /* filter: theta_max = this max(1, theta_0) */
#define IPM_THETA_MIN_FACTOR 1e-4      /* switching condition: theta_min = this max(1, theta_0) */
#define IPM_GAMMA_THETA 1e-5           /* sufficient decrease of theta */
#define IPM_GAMMA_PHI 1e-8             /* sufficient decrease of phi (h-type steps) */
#define IPM_ETA_PHI 1e-8               /* Armijo factor (f-type steps) */
#define IPM_S_PHI 2.3                  /* switching condition exponents */
#define IPM_S_THETA 1.1
#define IPM_MAX_FILTER 256             /* filter entries kept at most (more are not added) */
#define IPM_KAPPA_SIGMA 1e10           /* bound multipliers stay within [b / kappa, kappa b], b = mu / slack */
/* Restoration phase (IPOPT's l1 elastic problem, section 3.3 of Waechter & Biegler 2006) */
#define IPM_KAPPA_RESTO 0.9            /* back to the problem once theta <= this theta at the failure */
#define IPM_RESTO_PROXIMITY 1.0        /* zeta = this sqrt(mu): weight of the proximity term */
#define IPM_MAX_RESTO_CALLS 3          /* restoration phases per solve at most */

/* ----------------------------------------------------------------------------- structs ---- */

/* Generated CasADi function: int f(const double **arg, double **res, long long *iw, double *w, int mem). */
typedef long long casadi_int_t;
typedef int (*casadi_fun)(const double **arg, double **res, casadi_int_t *iw, double *w, int mem);

/* The problem: sparsity, KKT band layout and the kernel's functions (see kkt.KktStructure). */
typedef struct {
  int n_w, n_g, n, bw, ldab; /* sizes; bw: half-bandwidth of the permuted KKT matrix, ldab = 3 bw + 1 */
  int n_j;                   /* Jacobian nonzeros, in nlp_jac_g's output order: */
  const int *j_rows, *j_cols;
  int n_h;                   /* upper-triangle Hessian nonzeros (nlp_hess_l's output) */
  const int *h_rows, *h_cols;
  int n_hs;                  /* full symmetric Hessian entries -> upper-triangle source */
  const int *hs_row, *hs_col, *hs_src;
  const int *perm;           /* (n,) perm[k]: original unknown at band position k */
  int n_ent;                 /* KKT entries: kind (enum ipm_entry_kind), */
  const int *ent_kind, *ent_src, *ent_row;
  const int64_t *ent_pos;    /* source, row, flat position in LAPACK band storage */
  /* nlp_g(x, p) -> g; nlp_grad_f(x, p) -> (f, grad f); nlp_jac_g(x, p) -> (g, J);
     nlp_hess_l(x, p, lam_f, lam_g) -> upper triangle of the Lagrangian's Hessian */
  casadi_fun f_g, f_grad_f, f_jac_g, f_hess_l;
  const int64_t *work_sizes; /* (16,) per function above, in that order: sz_arg, sz_res, sz_iw, sz_w */
  /* rows of g with one constant Jacobian entry a (g_i = a x_j - c(p)), for the initial value embedding */
  int n_fix;
  const int *fix_row, *fix_var;
  const double *fix_coef;
} ipm_struct;

/* Options (IPOPT's names; see ipm.IpmOptions). */
typedef struct {
  double tol, constr_viol_tol, mu_init, mu_min, bound_push, mult_push, bound_relax;
  int max_iter, warm, verbose; /* warm: start from the caller's multipliers; verbose: a line per iteration on stderr */
  /* a warm start whose largest scaled constraint violation exceeds theta_far uses mu_far, push_far */
  double theta_far, mu_far, push_far;
  /* ABI 2. restoration: a failed line search starts the restoration phase (0: it ends the solve, the
     behaviour of ABI 1); phase1: solve only the feasibility problem from the start (ends with
     IPM_FEASIBLE_POINT_FOUND, IPM_INFEASIBLE_PROBLEM_DETECTED or IPM_RESTORATION_FAILED);
     resto_max_iter: iterations of one restoration phase at most; resto_rho: the l1 penalty (IPOPT's
     1000); resto_mu_cert: a certificate needs the restoration's barrier parameter at most this */
  int restoration, phase1, resto_max_iter;
  double resto_rho, resto_mu_cert;
} ipm_opts;

/* Counters and errors of one solve (written by ipm_solve). */
typedef struct {
  int iterations, status, factorisations, regularised, backtracks, soc, far;
  double inf_pr;      /* largest unscaled constraint or bound violation */
  double inf_du;      /* scaled dual infeasibility */
  double mu;          /* barrier parameter of the last iteration */
  double theta_start; /* largest scaled violation at the (embedded) start */
  double first_alpha; /* primal step of iteration 0 (negative: a second-order corrected step) */
  /* ABI 2: restoration phases and their iterations (also counted in iterations); at the end of the
     last restoration phase: cert_violation, the l1 norm of the scaled constraint violation (the
     measured violation of a certificate), cert_stationarity, the scaled KKT error of the l1
     feasibility problem (its stationarity) and cert_mu its barrier parameter (nan: no restoration) */
  int resto_calls, resto_iterations;
  double cert_violation, cert_stationarity, cert_mu;
} ipm_stats;

/* ------------------------------------------------------------------------- functions ---- */

/* Workspace one ipm_solve on st needs: *n_dbl doubles and *n_int ints (8-byte aligned). */
void ipm_work_sizes(const ipm_struct *st, int64_t *n_dbl, int64_t *n_int);

/* Solve min f(x, p) s.t. lbg <= g(x, p) <= ubg, lbx <= x <= ubx.
   p (n_p,); lbx, ubx (n_w,); lbg, ubg (n_g,) (+-inf: no bound; lbg == ubg: an equality row).
   x (n_w,): start in, solution out. lam_x (n_w,), lam_g (n_g,): start in when o->warm (else
   ignored), multipliers out, unscaled, in CasADi's convention (L = f + lam_g' g + lam_x' x).
   wd, wi: the workspace of ipm_work_sizes. Returns an ipm_status (also in stats->status). */
int ipm_solve(const ipm_struct *st, const ipm_opts *o, const double *p, const double *lbx, const double *ubx,
              const double *lbg, const double *ubg, double *x, double *lam_x, double *lam_g, ipm_stats *stats,
              double *wd, int *wi);

/* ABI self-description, compared by ipm.py at load. */
int ipm_abi_version(void);
/* Writes, for ipm_struct, ipm_opts, ipm_stats in turn: sizeof, number of fields, each field's
   offset in declaration order; returns the number of values (written only if <= cap). */
int ipm_abi_layout(int64_t *out, int cap);
/* Python name of a status code ("Converged", ...); NULL outside [0, IPM_STATUS_COUNT). */
const char *ipm_status_name(int status);

#endif /* MCVERIFY_IPM_H */
