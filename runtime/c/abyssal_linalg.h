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

/* B <- B L^-T for B (r x n) and lower-triangular L (n x n): sweeps over B's columns, vectorised over its r rows
 * (the form for a gain P H^T S^-1 with n states and a few measurement rows). */
void abyssal_solve_right_lower_transposed(int r, int n, const double* L, double* B);

/* B <- B L^-1 for B (r x n) and lower-triangular L (n x n), as abyssal_solve_right_lower_transposed. */
void abyssal_solve_right_lower(int r, int n, const double* L, double* B);

/* sum_k a[k] b[k] in four interleaved partial sums (k mod 4, the tail in the first), added pairwise at the end: a
 * fixed order, so every compiler computes the same sum, in 4-wide vector operations where it can. Inline: the
 * vectors of a filter step are short, and a call would cost as much as the arithmetic. */
static inline double abyssal_dot(int count, const double* a, const double* b) {
  double s[4] = {0.0, 0.0, 0.0, 0.0};
  int k = 0, lane;
  for (; k + 4 <= count; k += 4)
    for (lane = 0; lane < 4; ++lane) s[lane] += a[k + lane] * b[k + lane];
  for (; k < count; ++k) s[0] += a[k] * b[k];
  return (s[0] + s[1]) + (s[2] + s[3]);
}

/* d wrapped to (-pi, pi]; exactly d (bitwise) when it is already in that interval. */
double abyssal_wrap_angle(double d);

/* out = A B^T (A: r x k, B: c x k, out: r x c), with strides lda, ldb, ldo (rows of storage). */
void abyssal_multiply_transposed(int r, int c, int k, const double* A, int lda, const double* B, int ldb, double* out,
                                 int ldo);

/* out = A P A^T for A (r x n) and symmetric P (n x n); PAt (n x r) receives P A^T. out is exactly symmetric (its
 * upper triangle mirrored). Two sweeps of abyssal_gemv, whose register blocks hold a column across the sum: at a
 * filter's sizes (n ~ 12) loop overhead, not arithmetic, is the cost, and on rov4dof's F this beat per-entry loops,
 * an index list of A's nonzeros and a compressed-column pattern. */
void abyssal_congruence(int r, int n, const double* A, const double* P, double* PAt, double* out);

/* y = base + sign A w for A (n x K, column-major with leading dimension lda), w (K entries, stride ws) and sign
 * +1 or -1; base NULL: 0. In blocks of 8 (then 4) rows held in registers across the K columns (no store-to-load
 * chain through y), each row's sum in the order k = 0, 1, ...; zero entries of w are skipped. y may not alias A or
 * w. Inline, as abyssal_dot. */
static inline void abyssal_gemv_signed(int n, int K, const double* A, int lda, const double* w, int ws, double sign,
                                       const double* base, double* y) {
  int i0 = 0, ii, k;
  for (; i0 + 8 <= n; i0 += 8) {
    double acc[8];
    for (ii = 0; ii < 8; ++ii) acc[ii] = base ? base[i0 + ii] : 0.0;
    for (k = 0; k < K; ++k) {
      const double b = sign * w[(long)k * ws];
      const double* a = A + (long)k * lda + i0;
      if (b == 0.0) continue;
      for (ii = 0; ii < 8; ++ii) acc[ii] += a[ii] * b;
    }
    for (ii = 0; ii < 8; ++ii) y[i0 + ii] = acc[ii];
  }
  if (i0 + 4 <= n) {
    double acc[4];
    for (ii = 0; ii < 4; ++ii) acc[ii] = base ? base[i0 + ii] : 0.0;
    for (k = 0; k < K; ++k) {
      const double b = sign * w[(long)k * ws];
      const double* a = A + (long)k * lda + i0;
      if (b == 0.0) continue;
      for (ii = 0; ii < 4; ++ii) acc[ii] += a[ii] * b;
    }
    for (ii = 0; ii < 4; ++ii) y[i0 + ii] = acc[ii];
    i0 += 4;
  }
  for (; i0 < n; ++i0) { /* the last rows, one at a time */
    double v = base ? base[i0] : 0.0;
    for (k = 0; k < K; ++k) v += A[(long)k * lda + i0] * (sign * w[(long)k * ws]);
    y[i0] = v;
  }
}

/* y = base + A w: abyssal_gemv_signed with sign +1. */
static inline void abyssal_gemv(int n, int K, const double* A, int lda, const double* w, int ws, const double* base,
                                double* y) {
  abyssal_gemv_signed(n, K, A, lda, w, ws, 1.0, base, y);
}

/* The largest |a[k]|. */
double abyssal_largest(int count, const double* a);

#ifdef __cplusplus
}
#endif

#endif /* ABYSSAL_LINALG_H */
