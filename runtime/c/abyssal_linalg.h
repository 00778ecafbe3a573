/* abyssal_linalg.h: the small dense linear algebra of the filter runtime (factorisations, triangular solves,
 * congruences), generic over the dimensions.
 *
 * Matrices are column-major (CasADi's and Fortran's layout): entry (i, j) of an r x c matrix A is A[i + j r].
 * Symmetric matrices are computed on and above the diagonal and mirrored, so they are exactly symmetric. No
 * allocation: the caller passes every buffer. Hand-written C99.
 */
#ifndef ABYSSAL_LINALG_H
#define ABYSSAL_LINALG_H

#ifdef __cplusplus
extern "C" {
#endif

/* A pivot d_j of A = L L^T passes when d_j > ABYSSAL_PIVOT_RELATIVE * A_jj + ABYSSAL_PIVOT_ABSOLUTE: d_j / A_jj is
 * the variance of coordinate j given the ones before it over its variance, so the guard trips on a matrix that is
 * indefinite or singular to within roundoff (condition number beyond ~1e13). */
#define ABYSSAL_PIVOT_RELATIVE 1e-13
#define ABYSSAL_PIVOT_ABSOLUTE 1e-300

/* L (n x n, lower triangle; the upper one is zeroed) with A ~ L L^T, from the lower triangle of A. A pivot that
 * fails the guard is replaced by its threshold, so L is finite for a finite A. Returns 1 when every pivot passed,
 * else 0. L may not alias A. */
int abyssal_cholesky(int n, const double* A, double* L);

/* B <- L^-1 B for lower-triangular L (n x n) and B (n x m). */
void abyssal_solve_lower(int n, const double* L, int m, double* B);

/* B <- L^-T B for lower-triangular L (n x n) and B (n x m). */
void abyssal_solve_lower_transposed(int n, const double* L, int m, double* B);

/* sum_k a[k] b[k] in four interleaved partial sums (k mod 4, the tail in the first), added pairwise at the end: a
 * fixed order, so every compiler computes the same sum, in 4-wide vector operations where it can. */
double abyssal_dot(int count, const double* a, const double* b);

/* d wrapped to (-pi, pi]; exactly d (bitwise) when it is already in that interval. */
double abyssal_wrap_angle(double d);

/* out = A B^T (A: r x k, B: c x k, out: r x c), with strides lda, ldb, ldo (rows of storage). */
void abyssal_multiply_transposed(int r, int c, int k, const double* A, int lda, const double* B, int ldb, double* out,
                                 int ldo);

/* out = A P A^T for A (r x n) and symmetric P (n x n); AP (r x n) receives A P. out is exactly symmetric. */
void abyssal_congruence(int r, int n, const double* A, const double* P, double* AP, double* out);

/* The largest |a[k]|. */
double abyssal_largest(int count, const double* a);

#ifdef __cplusplus
}
#endif

#endif /* ABYSSAL_LINALG_H */
