/* abyssal_linalg.c: see abyssal_linalg.h. Hand-written C99. */
#include "abyssal_linalg.h"

#include <math.h>
#include <string.h>

#define AT(a, ld, i, j) ((a)[(i) + (j) * (ld)])
#define TWO_PI 6.283185307179586
#define PI 3.141592653589793

int abyssal_cholesky(int n, const double* A, double* L) {
  int ok = 1, i, j;
  memset(L, 0, sizeof(double) * (size_t)n * (size_t)n);
  for (j = 0; j < n; ++j) {
    double* l = L + (size_t)j * n;
    double d, threshold, inverse;
    /* column j below the diagonal: A's, less L[j:, :j] L[j, :j]^T, each entry's sum in the order k = 0, 1, ... */
    abyssal_gemv_signed(n - j, j, L + j, n, L + j, n, -1.0, A + j + (size_t)j * n, l + j);
    d = l[j];
    threshold = ABYSSAL_PIVOT_RELATIVE * fabs(AT(A, n, j, j)) + ABYSSAL_PIVOT_ABSOLUTE;
    if (!(d > threshold)) {
      ok = 0;
      d = threshold; /* NaN too: the factor stays finite for finite A */
    }
    l[j] = sqrt(d);
    inverse = 1.0 / l[j]; /* one division per column */
    for (i = j + 1; i < n; ++i) l[i] *= inverse;
  }
  return ok;
}

void abyssal_solve_lower(int n, const double* L, int m, double* B) {
  int c, i, k;
  for (c = 0; c < m; ++c) {
    double* b = B + (size_t)c * (size_t)n;
    for (i = 0; i < n; ++i) {
      double v = b[i];
      for (k = 0; k < i; ++k) v -= AT(L, n, i, k) * b[k];
      b[i] = v / AT(L, n, i, i);
    }
  }
}

void abyssal_solve_lower_transposed(int n, const double* L, int m, double* B) {
  int c, i, k;
  for (c = 0; c < m; ++c) {
    double* b = B + (size_t)c * (size_t)n;
    for (i = n - 1; i >= 0; --i) {
      double v = b[i];
      for (k = i + 1; k < n; ++k) v -= AT(L, n, k, i) * b[k];
      b[i] = v / AT(L, n, i, i);
    }
  }
}

void abyssal_solve_right_lower_transposed(int r, int n, const double* L, double* B) {
  int i, j, k;
  for (j = 0; j < n; ++j) { /* Y L^T = B, column j: Y[:, j] L_jj = B[:, j] - sum_{k < j} Y[:, k] L_jk */
    double* b = B + (size_t)j * r;
    const double d = AT(L, n, j, j);
    for (k = 0; k < j; ++k) {
      const double ljk = AT(L, n, j, k), *y = B + (size_t)k * r;
      for (i = 0; i < r; ++i) b[i] -= y[i] * ljk;
    }
    for (i = 0; i < r; ++i) b[i] /= d;
  }
}

void abyssal_solve_right_lower(int r, int n, const double* L, double* B) {
  int i, j, k;
  for (j = n - 1; j >= 0; --j) { /* K L = B, column j: K[:, j] L_jj = B[:, j] - sum_{k > j} K[:, k] L_kj */
    double* b = B + (size_t)j * r;
    const double d = AT(L, n, j, j);
    for (k = j + 1; k < n; ++k) {
      const double lkj = AT(L, n, k, j), *y = B + (size_t)k * r;
      for (i = 0; i < r; ++i) b[i] -= y[i] * lkj;
    }
    for (i = 0; i < r; ++i) b[i] /= d;
  }
}

double abyssal_wrap_angle(double d) {
  if (d > -PI && d <= PI) return d;
  return d - TWO_PI * ceil((d - PI) / TWO_PI);
}

void abyssal_multiply_transposed(int r, int c, int k, const double* A, int lda, const double* B, int ldb, double* out,
                                 int ldo) {
  int i, j, l;
  for (j = 0; j < c; ++j)
    for (i = 0; i < r; ++i) {
      double v = 0.0;
      for (l = 0; l < k; ++l) v += AT(A, lda, i, l) * AT(B, ldb, j, l);
      AT(out, ldo, i, j) = v;
    }
}

void abyssal_congruence(int r, int n, const double* A, const double* P, double* PAt, double* out) {
  int i, j;
  for (j = 0; j < r; ++j) /* column j of P A^T = P (row j of A), P symmetric; the row's zeros skipped */
    abyssal_gemv(n, n, P, n, A + j, r, 0, PAt + (size_t)j * n);
  for (j = 0; j < r; ++j) /* column j of A (P A^T) */
    abyssal_gemv(r, n, A, r, PAt + (size_t)j * n, 1, 0, out + (size_t)j * r);
  for (j = 0; j < r; ++j) /* exactly symmetric: the upper triangle mirrored */
    for (i = j + 1; i < r; ++i) AT(out, r, i, j) = AT(out, r, j, i);
}

double abyssal_largest(int count, const double* a) {
  double top = 0.0;
  int k;
  for (k = 0; k < count; ++k) {
    double v = fabs(a[k]);
    if (v > top) top = v;
  }
  return top;
}
