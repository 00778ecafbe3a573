/* abyssal_linalg.c: see abyssal_linalg.h. Hand-written C99. */
#include "abyssal_linalg.h"

#include <math.h>
#include <string.h>

#define AT(a, ld, i, j) ((a)[(i) + (j) * (ld)])
#define TWO_PI 6.283185307179586
#define PI 3.141592653589793

int abyssal_cholesky(int n, const double* A, double* L) {
  int ok = 1, i, j, k;
  memset(L, 0, sizeof(double) * (size_t)n * (size_t)n);
  for (j = 0; j < n; ++j) {
    double d = AT(A, n, j, j), threshold, inverse;
    for (k = 0; k < j; ++k) d -= AT(L, n, j, k) * AT(L, n, j, k);
    threshold = ABYSSAL_PIVOT_RELATIVE * fabs(AT(A, n, j, j)) + ABYSSAL_PIVOT_ABSOLUTE;
    if (!(d > threshold)) {
      ok = 0;
      if (!(d > threshold)) d = threshold; /* NaN too: the factor stays finite for finite A */
    }
    AT(L, n, j, j) = sqrt(d);
    inverse = 1.0 / AT(L, n, j, j); /* one division per column */
    for (i = j + 1; i < n; ++i) {
      double v = AT(A, n, i, j);
      for (k = 0; k < j; ++k) v -= AT(L, n, i, k) * AT(L, n, j, k);
      AT(L, n, i, j) = v * inverse;
    }
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

double abyssal_dot(int count, const double* a, const double* b) {
  double s[4] = {0.0, 0.0, 0.0, 0.0};
  int k = 0, lane;
  for (; k + 4 <= count; k += 4)
    for (lane = 0; lane < 4; ++lane) s[lane] += a[k + lane] * b[k + lane];
  for (; k < count; ++k) s[0] += a[k] * b[k];
  return (s[0] + s[1]) + (s[2] + s[3]);
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

void abyssal_congruence(int r, int n, const double* A, const double* P, double* AP, double* out) {
  int i, j, l;
  for (j = 0; j < n; ++j) /* AP = A P */
    for (i = 0; i < r; ++i) {
      double v = 0.0;
      for (l = 0; l < n; ++l) v += AT(A, r, i, l) * AT(P, n, l, j);
      AT(AP, r, i, j) = v;
    }
  for (j = 0; j < r; ++j) /* out_ij = (A P)_i . A_j */
    for (i = 0; i <= j; ++i) {
      double v = 0.0;
      for (l = 0; l < n; ++l) v += AT(AP, r, i, l) * AT(A, r, j, l);
      AT(out, r, i, j) = v;
      AT(out, r, j, i) = v;
    }
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
