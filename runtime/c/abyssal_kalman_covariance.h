/* abyssal_kalman_covariance.h: the small dense algebra of the Kalman runtime on covariance matrices.
 *
 * Every matrix is n x n, column-major (CasADi's and Fortran's layout; symmetric matrices read the same either
 * way). No allocation: callers pass the scratch named in each comment. Hand-written C99.
 */
#ifndef ABYSSAL_KALMAN_COVARIANCE_H
#define ABYSSAL_KALMAN_COVARIANCE_H

#include <math.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Whether every one of the count doubles at a is finite (1) or not (0); inline for the per-step input checks. */
static inline int abyssal_all_finite(int count, const double* a) {
  int k;
  for (k = 0; k < count; ++k)
    if (!isfinite(a[k])) return 0;
  return 1;
}

/* The relative asymmetry a given covariance may have: max |A - A^T| <= tol * max |A|. */
#define ABYSSAL_SYMMETRY_TOLERANCE 1e-9

/* Eigenvalues (ascending) and, when vectors is not NULL, orthonormal eigenvectors (columns) of the symmetric
 * n x n matrix a by cyclic Jacobi rotations. a is overwritten (scratch). Returns 0, or -1 when the rotations
 * did not converge (never seen on finite input) or an entry is not finite. */
int abyssal_symmetric_eigen(int n, double* a, double* values, double* vectors);

/* Whether A (n x n) is a covariance: 0 when it is finite, symmetric within ABYSSAL_SYMMETRY_TOLERANCE and
 * positive semi-definite (definite != 0: positive definite), judged on its correlation matrix so that entries
 * near 1e308 or of very different scales are judged exactly. Otherwise 1 (not finite), 2 (not symmetric),
 * 3 (a negative or, definite, a zero diagonal entry), 4 (an eigenvalue of the correlation matrix below
 * -ABYSSAL_SYMMETRY_TOLERANCE, or, definite, not above n * DBL_EPSILON). scratch: 2 n^2 + n doubles. */
int abyssal_covariance_problem(int n, const double* A, int definite, double* scratch);

/* out = (A + A^T) / 2 computed as A/2 + A^T/2 (no overflow near 1e308); out may equal A. */
void abyssal_symmetrise(int n, const double* A, double* out);

/* The nearest covariance a Cholesky factorisation (and a sigma-point rule) accepts: for P with a nonzero entry,
 * P symmetrised, scaled by its largest entry, its eigenvalues clipped from below at floor * max |eigenvalue|,
 * scaled back; for P = 0 (a known state), floor * max(max |Q|, 1) * I. out may not alias P or Q.
 * scratch: 3 n^2 + n doubles. Returns 0, or -1 when P is not finite. */
int abyssal_repair_covariance(int n, const double* P, const double* Q, double floor, double* out, double* scratch);

/* nu^T S^-1 nu for the m x m matrix S (lower triangle read) by a Cholesky factorisation; +inf when S is not
 * numerically positive definite or a value is not finite. scratch: m^2 + m doubles. */
double abyssal_nis(int m, const double* nu, const double* S, double* scratch);

/* Whether a predicted covariance grew more than `limit` times (largest prior variance + largest noise variance)
 * in one predict, or stopped being finite: 1 (grew), 0 (did not). */
int abyssal_grew_beyond(int n, double limit, const double* before, const double* after, const double* noise);

#ifdef __cplusplus
}
#endif

#endif /* ABYSSAL_KALMAN_COVARIANCE_H */
