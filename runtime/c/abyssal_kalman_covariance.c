/* abyssal_kalman_covariance.c: see abyssal_kalman_covariance.h. Hand-written C99. */
#include "abyssal_kalman_covariance.h"

#include <float.h>
#include <math.h>
#include <string.h>

#define AT(a, n, i, j) ((a)[(i) + (j) * (n)])
#define MAX_SWEEPS 100

static double largest_magnitude(int count, const double* a) {
  double top = 0.0;
  int k;
  for (k = 0; k < count; ++k) {
    double v = fabs(a[k]);
    if (v > top) top = v;
  }
  return top;
}

/* One Jacobi rotation in the plane (p, q) that zeroes a[p, q] (a symmetric, both triangles kept). */
static void rotate(int n, double* a, double* vectors, int p, int q) {
  double apq = AT(a, n, p, q), theta, t, c, s;
  int k;
  theta = (AT(a, n, q, q) - AT(a, n, p, p)) / (2.0 * apq);
  if (fabs(theta) > 1e150) {
    t = 0.5 / theta;  /* theta^2 would overflow; t = 1 / (2 theta) to first order */
  } else {
    t = 1.0 / (fabs(theta) + sqrt(theta * theta + 1.0));
    if (theta < 0.0) t = -t;
  }
  c = 1.0 / sqrt(t * t + 1.0);
  s = t * c;
  for (k = 0; k < n; ++k) { /* columns: A J */
    double akp = AT(a, n, k, p), akq = AT(a, n, k, q);
    AT(a, n, k, p) = c * akp - s * akq;
    AT(a, n, k, q) = s * akp + c * akq;
  }
  for (k = 0; k < n; ++k) { /* rows: J^T A */
    double apk = AT(a, n, p, k), aqk = AT(a, n, q, k);
    AT(a, n, p, k) = c * apk - s * aqk;
    AT(a, n, q, k) = s * apk + c * aqk;
  }
  AT(a, n, p, q) = 0.0;
  AT(a, n, q, p) = 0.0;
  if (vectors) {
    for (k = 0; k < n; ++k) {
      double vkp = AT(vectors, n, k, p), vkq = AT(vectors, n, k, q);
      AT(vectors, n, k, p) = c * vkp - s * vkq;
      AT(vectors, n, k, q) = s * vkp + c * vkq;
    }
  }
}

int abyssal_symmetric_eigen(int n, double* a, double* values, double* vectors) {
  int sweep, p, q, i, j;
  if (!abyssal_all_finite(n * n, a)) return -1;
  if (vectors) {
    memset(vectors, 0, sizeof(double) * (size_t)n * (size_t)n);
    for (i = 0; i < n; ++i) AT(vectors, n, i, i) = 1.0;
  }
  for (sweep = 0; sweep < MAX_SWEEPS; ++sweep) {
    double off = 0.0, diagonal = 0.0;
    for (q = 0; q < n; ++q) {
      diagonal += AT(a, n, q, q) * AT(a, n, q, q);
      for (p = 0; p < q; ++p) off += AT(a, n, p, q) * AT(a, n, p, q);
    }
    if (off == 0.0 || off <= 1e-4 * DBL_EPSILON * DBL_EPSILON * diagonal) break;
    for (q = 1; q < n; ++q) {
      for (p = 0; p < q; ++p) {
        double apq = AT(a, n, p, q);
        if (apq == 0.0) continue;
        /* negligible beside both diagonal entries: set to zero instead of rotating (after a few sweeps) */
        if (sweep > 3 && fabs(AT(a, n, p, p)) + 1e3 * fabs(apq) == fabs(AT(a, n, p, p)) &&
            fabs(AT(a, n, q, q)) + 1e3 * fabs(apq) == fabs(AT(a, n, q, q))) {
          AT(a, n, p, q) = 0.0;
          AT(a, n, q, p) = 0.0;
          continue;
        }
        rotate(n, a, vectors, p, q);
      }
    }
  }
  if (sweep == MAX_SWEEPS) return -1;
  for (i = 0; i < n; ++i) values[i] = AT(a, n, i, i);
  for (i = 1; i < n; ++i) { /* insertion sort, ascending, vectors alongside */
    for (j = i; j > 0 && values[j - 1] > values[j]; --j) {
      double t = values[j];
      values[j] = values[j - 1];
      values[j - 1] = t;
      if (vectors) {
        int k;
        for (k = 0; k < n; ++k) {
          double u = AT(vectors, n, k, j);
          AT(vectors, n, k, j) = AT(vectors, n, k, j - 1);
          AT(vectors, n, k, j - 1) = u;
        }
      }
    }
  }
  return 0;
}

void abyssal_symmetrise(int n, const double* A, double* out) {
  int i, j;
  for (j = 0; j < n; ++j) {
    for (i = 0; i <= j; ++i) {
      double v = 0.5 * AT(A, n, i, j) + 0.5 * AT(A, n, j, i);
      AT(out, n, i, j) = v;
      AT(out, n, j, i) = v;
    }
  }
}

int abyssal_covariance_problem(int n, const double* A, int definite, double* scratch) {
  double* C = scratch;
  double* values = scratch + n * n;
  double scale, asymmetry = 0.0;
  int i, j;
  if (!abyssal_all_finite(n * n, A)) return 1;
  scale = largest_magnitude(n * n, A);
  if (scale > 0.0) {
    for (j = 0; j < n; ++j)
      for (i = 0; i < j; ++i) {
        double d = fabs(AT(A, n, i, j) / scale - AT(A, n, j, i) / scale);
        if (d > asymmetry) asymmetry = d;
      }
  }
  if (asymmetry > ABYSSAL_SYMMETRY_TOLERANCE) return 2;
  abyssal_symmetrise(n, A, C);
  for (i = 0; i < n; ++i) {
    double d = AT(C, n, i, i);
    if (d < 0.0 || (definite && !(d > 0.0))) return 3;
  }
  /* the correlation matrix D^-1/2 A D^-1/2 (entries in [-1, 1] for a positive semi-definite A) */
  for (i = 0; i < n; ++i) values[i] = AT(C, n, i, i) > 0.0 ? sqrt(AT(C, n, i, i)) : 1.0;
  for (j = 0; j < n; ++j)
    for (i = 0; i < n; ++i) AT(C, n, i, j) = AT(C, n, i, j) / values[i] / values[j];
  if (abyssal_symmetric_eigen(n, C, values, 0) != 0) return 4;
  if (definite ? !(values[0] > n * DBL_EPSILON) : values[0] < -ABYSSAL_SYMMETRY_TOLERANCE) return 4;
  return 0;
}

int abyssal_repair_covariance(int n, const double* P, const double* Q, double floor, double* out, double* scratch) {
  double* A = scratch;
  double* vectors = scratch + n * n;
  double* values = scratch + 2 * n * n;
  double scale, top = 0.0;
  int i, j, k;
  if (!abyssal_all_finite(n * n, P)) return -1;
  if (largest_magnitude(n * n, P) == 0.0) { /* the Dirac: its nearest Gaussian */
    double q = largest_magnitude(n * n, Q);
    memset(out, 0, sizeof(double) * (size_t)n * (size_t)n);
    for (i = 0; i < n; ++i) AT(out, n, i, i) = floor * (q > 1.0 ? q : 1.0);
    return 0;
  }
  abyssal_symmetrise(n, P, A);
  scale = largest_magnitude(n * n, A);
  if (!(scale > 0.0) || !isfinite(scale)) scale = 1.0;
  for (k = 0; k < n * n; ++k) A[k] /= scale;
  if (abyssal_symmetric_eigen(n, A, values, vectors) != 0) return -1;
  for (i = 0; i < n; ++i)
    if (fabs(values[i]) > top) top = fabs(values[i]);
  if (top < DBL_MIN) top = DBL_MIN;
  for (i = 0; i < n; ++i)
    if (values[i] < floor * top) values[i] = floor * top;
  for (j = 0; j < n; ++j) { /* V diag(values) V^T, upper triangle, mirrored */
    for (i = 0; i <= j; ++i) {
      double sum = 0.0;
      for (k = 0; k < n; ++k) sum += AT(vectors, n, i, k) * values[k] * AT(vectors, n, j, k);
      AT(out, n, i, j) = sum * scale;
      AT(out, n, j, i) = sum * scale;
    }
  }
  return 0;
}

double abyssal_nis(int m, const double* nu, const double* S, double* scratch) {
  double* L = scratch;
  double* y = scratch + m * m;
  double nis = 0.0;
  int i, j, k;
  for (j = 0; j < m; ++j) {
    double d = AT(S, m, j, j);
    for (k = 0; k < j; ++k) d -= AT(L, m, j, k) * AT(L, m, j, k);
    if (!(d > 0.0) || !isfinite(d)) return INFINITY;
    AT(L, m, j, j) = sqrt(d);
    for (i = j + 1; i < m; ++i) {
      double v = AT(S, m, i, j);
      for (k = 0; k < j; ++k) v -= AT(L, m, i, k) * AT(L, m, j, k);
      AT(L, m, i, j) = v / AT(L, m, j, j);
    }
  }
  for (i = 0; i < m; ++i) { /* y = L^-1 nu, NIS = |y|^2 */
    double v = nu[i];
    for (k = 0; k < i; ++k) v -= AT(L, m, i, k) * y[k];
    y[i] = v / AT(L, m, i, i);
    nis += y[i] * y[i];
  }
  return isfinite(nis) ? nis : INFINITY;
}

int abyssal_grew_beyond(int n, double limit, const double* before, const double* after, const double* noise) {
  double top_before = -INFINITY, top_after = -INFINITY, top_noise = -INFINITY, base;
  int i;
  for (i = 0; i < n; ++i) {
    double b = AT(before, n, i, i), a = AT(after, n, i, i), q = AT(noise, n, i, i);
    if (b > top_before) top_before = b;
    if (q > top_noise) top_noise = q;
    if (isnan(a)) return 1;
    if (a > top_after) top_after = a;
  }
  base = top_before + top_noise;
  if (!(base >= DBL_MIN)) base = DBL_MIN;
  return !(top_after <= limit * base);
}
