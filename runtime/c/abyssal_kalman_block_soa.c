/* abyssal_kalman_block_soa.c: see abyssal_kalman_block.h. Hand-written C99; the file name ends in _soa.c so the
 * cache builds it with the structure-of-arrays flags (sqrt without errno: the lane loops vectorise).
 *
 * Every function here is its namesake in abyssal_kalman_steps.c or abyssal_linalg.c with each scalar a vector of
 * the block's lanes (the innermost loops run over the lanes); the comments name the scalar original whose order of
 * operations a loop keeps.
 */
#include "abyssal_kalman_block.h"

#include <math.h>
#include <string.h>

#include "abyssal_linalg.h"

#define B ABYSSAL_BLOCK
#define AT(a, ld, i, j) ((a)[(i) + (j) * (ld)])
/* the B lanes of entry e of a block quantity */
#define LANES(a, e) ((a) + (size_t)(e) * B)
#define EACH_LANE for (int j = 0; j < B; ++j)

typedef struct {
  double* at;
} cursor_t;

static double* take(cursor_t* c, size_t doubles) {
  double* out = c->at;
  c->at += (doubles + 7) & ~(size_t)7;
  return out;
}

static int spread_first(abyssal_filter filter) { return filter == ABYSSAL_CKF ? 0 : 1; }

static double spread(const abyssal_algebra* a, int n) {
  if (a->filter == ABYSSAL_CKF) return sqrt((double)n);
  return sqrt(a->alpha * a->alpha * (n + a->kappa));
}

size_t abyssal_block_scratch_bytes(const abyssal_model* model, abyssal_filter filter) {
  const size_t n = (size_t)model->n_x, m = (size_t)(model->n_y > 0 ? model->n_y : 1);
  const size_t points = (size_t)abyssal_sigma_points(filter, model->n_x), nu = (size_t)(model->n_u > 0 ? model->n_u : 1);
  const size_t lanes = (size_t)B, regions = 40;
  return sizeof(double) * (lanes * (n * n + 4 * n * points + nu * points + m * points + points + 2 * m + 7 * m * m +
                                    3 * n * m + 4 * m) +
                           2 * m * m + 8 * regions) +
         sizeof(int) * (3 * m + 3) + 64;
}

/* ------------------------------------------------------------------------------------------ lane algebra */

static void all_ok(double* ok) {
  EACH_LANE ok[j] = 1.0;
}

/* ok[lane] = 0 where one of the count entries of v is not finite */
static void finite_or_fail(int count, const double* v, double* ok) {
  for (int e = 0; e < count; ++e) {
    const double* x = LANES(v, e);
    EACH_LANE if (!isfinite(x[j])) ok[j] = 0.0;
  }
}

/* Both factorisations below: L's upper triangle zeroed, and column c of L from the diagonal down as A's entries less
 * L[i, :c] L[c, :c]^T, the sum in the order k = 0, 1, ... (their pivots and scaling differ) */
static void block_zero_upper(int n, double* L) {
  for (int c = 1; c < n; ++c)
    for (int i = 0; i < c; ++i) {
      double* l = LANES(L, i + c * n);
      EACH_LANE l[j] = 0.0;
    }
}

/* out = a less the sum over k < count of x_k y_k, lane by lane, with x_k = LANES(x, k * stride) (likewise y) and the
 * sum in the order k = 0, 1, ...: the dot-and-subtract of the factorisations and of P - Y Y^T */
static void lanes_less_products(const double* a, const double* x, const double* y, int count, int stride,
                                double* out) {
  double acc[B];
  EACH_LANE acc[j] = a[j];
  for (int k = 0; k < count; ++k) {
    const double* xk = LANES(x, (size_t)k * (size_t)stride);
    const double* yk = LANES(y, (size_t)k * (size_t)stride);
    EACH_LANE acc[j] -= xk[j] * yk[j];
  }
  EACH_LANE out[j] = acc[j];
}

static void block_column_less_products(int n, int c, const double* A, double* L) {
  for (int i = c; i < n; ++i)
    lanes_less_products(LANES(A, i + c * n), LANES(L, i), LANES(L, c), c, n, LANES(L, i + c * n));
}

/* abyssal_cholesky: L (n x n lanes, upper zeroed) from A's lower triangle, the pivots guarded; ok[lane] = 0 where a
 * pivot failed */
static void block_cholesky(int n, const double* A, double* L, double* ok) {
  block_zero_upper(n, L);
  for (int c = 0; c < n; ++c) {
    double inverse[B];
    block_column_less_products(n, c, A, L);
    double* d = LANES(L, c + c * n);
    const double* acc = LANES(A, c + c * n);
#pragma omp simd
    EACH_LANE { /* (selects, no branch: the lanes stay one vector) */
      const double threshold = ABYSSAL_PIVOT_RELATIVE * fabs(acc[j]) + ABYSSAL_PIVOT_ABSOLUTE;
      const int good = d[j] > threshold;
      ok[j] = good ? ok[j] : 0.0;
      d[j] = sqrt(good ? d[j] : threshold);
      inverse[j] = 1.0 / d[j];
    }
    for (int i = c + 1; i < n; ++i) {
      double* l = LANES(L, i + c * n);
      EACH_LANE l[j] *= inverse[j];
    }
  }
}

void abyssal_block_factor(int r, const double* A, double* L, double* ok) {
  block_zero_upper(r, L);
  for (int c = 0; c < r; ++c) {
    block_column_less_products(r, c, A, L);
    double* d = LANES(L, c + c * r);
#pragma omp simd
    EACH_LANE {
      const int good = d[j] > 0.0 && d[j] < INFINITY;
      ok[j] = good ? ok[j] : 0.0;
      d[j] = sqrt(good ? d[j] : 1.0);
    }
    for (int i = c + 1; i < r; ++i) { /* divided, as LAPACK's unblocked factor and plain_cholesky round */
      double* l = LANES(L, i + c * r);
#pragma omp simd
      EACH_LANE l[j] /= d[j];
    }
  }
}

/* abyssal_solve_lower on one vector per lane: b <- L^-1 b (L lanes, or one shared L when shared != 0) */
static void block_solve_lower(int n, const double* L, int shared, double* b) {
  for (int i = 0; i < n; ++i) {
    double v[B];
    const double* bi = LANES(b, i);
    EACH_LANE v[j] = bi[j];
    for (int k = 0; k < i; ++k) {
      const double* bk = LANES(b, k);
      if (shared) {
        const double l = AT(L, n, i, k);
        EACH_LANE v[j] -= l * bk[j];
      } else {
        const double* l = LANES(L, i + k * n);
        EACH_LANE v[j] -= l[j] * bk[j];
      }
    }
    double* out = LANES(b, i);
    if (shared) {
      const double d = AT(L, n, i, i);
#pragma omp simd
      EACH_LANE out[j] = v[j] / d;
    } else {
      const double* d = LANES(L, i + i * n);
#pragma omp simd
      EACH_LANE out[j] = v[j] / d[j];
    }
  }
}

/* abyssal_solve_lower_transposed on one vector per lane: b <- L^-T b */
static void block_solve_lower_transposed(int n, const double* L, double* b) {
  for (int i = n - 1; i >= 0; --i) {
    double v[B];
    const double* bi = LANES(b, i);
    EACH_LANE v[j] = bi[j];
    for (int k = i + 1; k < n; ++k) {
      const double* l = LANES(L, k + i * n);
      const double* bk = LANES(b, k);
      EACH_LANE v[j] -= l[j] * bk[j];
    }
    double* out = LANES(b, i);
    const double* d = LANES(L, i + i * n);
#pragma omp simd
    EACH_LANE out[j] = v[j] / d[j];
  }
}

/* abyssal_dot(count, a, b) per lane, a shared (weights), b[k] lanes: four interleaved partial sums */
static void block_dot_shared(int count, const double* a, const double* b, double* out) {
  double s[4][B];
  int k = 0;
  for (int lane = 0; lane < 4; ++lane) EACH_LANE s[lane][j] = 0.0;
  for (; k + 4 <= count; k += 4)
    for (int lane = 0; lane < 4; ++lane) {
      const double w = a[k + lane];
      const double* v = LANES(b, k + lane);
      EACH_LANE s[lane][j] += w * v[j];
    }
  for (; k < count; ++k) {
    const double w = a[k];
    const double* v = LANES(b, k);
    EACH_LANE s[0][j] += w * v[j];
  }
  EACH_LANE out[j] = (s[0][j] + s[1][j]) + (s[2][j] + s[3][j]);
}

/* abyssal_dot(count, a, b) per lane, both a[k] and b[k] lanes (a[k] at a + k * stride_a lanes) */
static void block_dot(int count, const double* a, int stride_a, const double* b, double* out) {
  double s[4][B];
  int k = 0;
  for (int lane = 0; lane < 4; ++lane) EACH_LANE s[lane][j] = 0.0;
  for (; k + 4 <= count; k += 4)
    for (int lane = 0; lane < 4; ++lane) {
      const double* u = LANES(a, (k + lane) * stride_a);
      const double* v = LANES(b, k + lane);
      EACH_LANE s[lane][j] += u[j] * v[j];
    }
  for (; k < count; ++k) {
    const double* u = LANES(a, k * stride_a);
    const double* v = LANES(b, k);
    EACH_LANE s[0][j] += u[j] * v[j];
  }
  EACH_LANE out[j] = (s[0][j] + s[1][j]) + (s[2][j] + s[3][j]);
}

/* sigma_points: X row r (stride points lanes) from x and L: centre, then x + s L e_i, x - s L e_i */
static void block_sigma_points(const abyssal_algebra* a, int n, int points, const double* x, const double* L,
                               double* X) {
  const int first = spread_first(a->filter);
  const double s = spread(a, n);
  for (int r = 0; r < n; ++r) {
    double* row = X + (size_t)r * (size_t)points * B;
    const double* restrict xr = LANES(x, r);
    if (first) EACH_LANE row[j] = xr[j];
    for (int i = 0; i < n; ++i) {
      const double* restrict l = LANES(L, r + i * n);
      double* restrict plus = LANES(row, first + i);
      double* restrict minus = LANES(row, first + n + i);
      EACH_LANE {
        const double offset = l[j] * s;
        plus[j] = xr[j] + offset;
        minus[j] = xr[j] - offset;
      }
    }
  }
}

/* out = A diag(c) A^T per lane (scaled_congruence) with A shared (m x m) and c lanes */
static void block_scaled_congruence(int m, const double* A, const double* c, double* out) {
  for (int q = 0; q < m; ++q)
    for (int i = 0; i <= q; ++i) {
      double v[B];
      EACH_LANE v[j] = 0.0;
      for (int k = 0; k < m; ++k) {
        const double aik = AT(A, m, i, k), aqk = AT(A, m, q, k);
        const double* ck = LANES(c, k);
        EACH_LANE v[j] += aik * ck[j] * aqk;
      }
      double* upper = LANES(out, i + q * m);
      double* lower = LANES(out, q + i * m);
      EACH_LANE upper[j] = lower[j] = v[j];
    }
}

/* ------------------------------------------------------------------------------------------ predict */

void abyssal_block_predict(const abyssal_model* model, const abyssal_algebra* a, const double* wm, const double* wc,
                           const double* x, const double* P, const double* u, const double* p, double dt,
                           const double* Q, double* x_pred, double* P_pred, double* ok, void* scratch) {
  const int n = model->n_x, n_u = model->n_u, N = abyssal_sigma_points(a->filter, n);
  const size_t ld = (size_t)N * B;
  cursor_t cur;
  const double* args[4];
  double* res[1];
  cur.at = (double*)scratch;
  double* L = take(&cur, (size_t)n * n * B);
  double* X = take(&cur, (size_t)n * ld);
  double* U = take(&cur, (size_t)(n_u > 0 ? n_u : 1) * ld);
  double* Y = take(&cur, (size_t)n * ld);
  double* E = take(&cur, (size_t)n * ld);
  all_ok(ok);
  block_cholesky(n, P, L, ok);
  block_sigma_points(a, n, N, x, L, X);
  for (int i = 0; i < n_u; ++i) /* every point gets u */
    for (size_t k = 0; k < ld; ++k) U[(size_t)i * ld + k] = u[i];
  args[0] = X;
  args[1] = U;
  args[2] = p;
  args[3] = &dt;
  res[0] = Y;
  model->f_soa((long long)ld, (long long)ld, args, res);
  for (int i = 0; i < n; ++i) { /* the mean, then D = Y - x' in place and E = wc D */
    double* d = Y + (size_t)i * ld;
    double* e = E + (size_t)i * ld;
    double* mean = LANES(x_pred, i);
    block_dot_shared(N, wm, d, mean);
    for (int k = 0; k < N; ++k) {
      double* dk = LANES(d, k);
      double* ek = LANES(e, k);
      const double w = wc[k];
      EACH_LANE {
        dk[j] -= mean[j];
        ek[j] = w * dk[j];
      }
    }
  }
  for (int q = 0; q < n; ++q)
    for (int i = 0; i <= q; ++i) {
      double v[B];
      const double qiq = AT(Q, n, i, q);
      block_dot(N, E + (size_t)i * ld, 1, Y + (size_t)q * ld, v);
      double* upper = LANES(P_pred, i + q * n);
      double* lower = LANES(P_pred, q + i * n);
      EACH_LANE upper[j] = lower[j] = v[j] + qiq;
    }
  finite_or_fail(n, x_pred, ok);
  finite_or_fail(n * n, P_pred, ok);
}

/* ------------------------------------------------------------------------------------------ update */

/* robust_noise: R~ per lane from R on the present entries (m x m, shared), Pzz and nu (lanes); ok_noise: the
 * guarded factor of R passed */
static int block_robust_noise(const abyssal_algebra* a, int m, const double* R, const double* Pzz, const double* nu,
                              double* R_tilde, cursor_t* cur) {
  double* fa = take(cur, (size_t)m * m);
  double* zeta = take(cur, (size_t)m * B);
  double* c = take(cur, (size_t)m * B);
  const int ok = abyssal_cholesky(m, R, fa);
  if (a->filter == ABYSSAL_MCUKF) {
    const double denominator = 2 * a->sigma * a->sigma;
    memcpy(zeta, nu, sizeof(double) * (size_t)m * B);
    block_solve_lower(m, fa, 1, zeta);
    for (int i = 0; i < m; ++i) {
      const double* z = LANES(zeta, i);
      double* ci = LANES(c, i);
      EACH_LANE {
        const double e = z[j] * z[j] / denominator;
        ci[j] = exp(e < ABYSSAL_MCC_MAX_EXPONENT ? e : ABYSSAL_MCC_MAX_EXPONENT);
      }
    }
    block_scaled_congruence(m, fa, c, R_tilde);
    return ok;
  }
  double* residual = take(cur, (size_t)m * B);
  double* A = take(cur, (size_t)m * m * B);
  double* L2 = take(cur, (size_t)m * m * B);
  double ignored[B];
  memcpy(residual, nu, sizeof(double) * (size_t)m * B);
  for (int it = 0; it < a->huber_iterations; ++it) {
    memcpy(zeta, residual, sizeof(double) * (size_t)m * B);
    block_solve_lower(m, fa, 1, zeta);
    for (int i = 0; i < m; ++i) {
      const double* z = LANES(zeta, i);
      double* ci = LANES(c, i);
      EACH_LANE {
        const double r = fabs(z[j]) / a->gamma;
        ci[j] = r > 1.0 ? r : 1.0;
      }
    }
    block_scaled_congruence(m, fa, c, R_tilde);
    for (int e = 0; e < m * m; ++e) {
      const double* pz = LANES(Pzz, e);
      const double* rt = LANES(R_tilde, e);
      double* ae = LANES(A, e);
      EACH_LANE ae[j] = pz[j] + rt[j];
    }
    block_cholesky(m, A, L2, ignored);
    memcpy(zeta, nu, sizeof(double) * (size_t)m * B); /* the post-fit residual R~ (Pzz + R~)^-1 nu */
    block_solve_lower(m, L2, 0, zeta);
    block_solve_lower_transposed(m, L2, zeta);
    for (int i = 0; i < m; ++i) block_dot(m, LANES(R_tilde, (size_t)i * m), 1, zeta, LANES(residual, i));
  }
  return ok;
}

void abyssal_block_update(const abyssal_model* model, const abyssal_algebra* a, const double* wm, const double* wc,
                          const double* x, const double* P, const double* z, const unsigned char* present,
                          const double* p, const double* R, double* x_post, double* P_post, double* innovation,
                          double* S, double* ok, void* scratch) {
  const int n = model->n_x, rows = model->n_y, N = abyssal_sigma_points(a->filter, n);
  const int first = spread_first(a->filter);
  const double s_spread = spread(a, n);
  const size_t ld = (size_t)N * B;
  cursor_t cur;
  int m = 0, ok_noise = 1;
  cur.at = (double*)scratch;
  int* idx = (int*)(void*)take(&cur, (size_t)rows + 1);
  int* angle_row = (int*)(void*)take(&cur, (size_t)rows + 1);
  double* Rp = take(&cur, (size_t)rows * rows + 1);
  double* L = take(&cur, (size_t)n * n * B);
  double* X = take(&cur, (size_t)n * ld);
  double* Z = take(&cur, (size_t)(rows > 0 ? rows : 1) * ld);
  double* Ec = take(&cur, ld);
  double* zp = take(&cur, (size_t)rows * B + 1);
  double* nu = take(&cur, (size_t)rows * B + 1);
  double* Czz = take(&cur, (size_t)rows * rows * B + 1);
  double* C = take(&cur, (size_t)n * rows * B + 1);
  double* Rt = take(&cur, (size_t)rows * rows * B + 1);
  double* Sp = take(&cur, (size_t)rows * rows * B + 1);
  double* LS = take(&cur, (size_t)rows * rows * B + 1);
  double* e = take(&cur, (size_t)rows * B + 1);
  double ok_points[B], ok_s[B];
  for (int sel = 0, r = 0; sel < model->n_sensors; ++sel) {
    const abyssal_sensor* sensor = &model->sensors[sel];
    for (int k = 0; k < sensor->n_y; ++k, ++r) angle_row[r] = sensor->angle_outputs ? sensor->angle_outputs[k] : 0;
  }
  for (int r = 0; r < rows; ++r)
    if (present[r]) idx[m++] = r;
  for (int q = 0; q < m; ++q) /* R on the present entries */
    for (int i = 0; i < m; ++i) AT(Rp, m, i, q) = AT(R, rows, idx[i], idx[q]);
  all_ok(ok_points);
  block_cholesky(n, P, L, ok_points);
  block_sigma_points(a, n, N, x, L, X);
  for (int sel = 0; sel < model->n_sensors; ++sel) {
    const abyssal_sensor* sensor = &model->sensors[sel];
    const double* args[2];
    double* res[1];
    args[0] = X;
    args[1] = p;
    res[0] = Z + (size_t)sensor->offset * ld;
    sensor->h_soa((long long)ld, (long long)ld, args, res);
  }
  for (int r = 0; r < rows; ++r) { /* z_pred, and the residuals Z_k - z_pred in place (angles wrapped) */
    double* zr = Z + (size_t)r * ld;
    double* zpr = LANES(zp, r);
    block_dot_shared(N, wm, zr, zpr);
    if (!present[r]) continue;
    for (int k = 0; k < N; ++k) {
      double* zk = LANES(zr, k);
      if (angle_row[r])
        EACH_LANE zk[j] = abyssal_wrap_angle(zk[j] - zpr[j]);
      else
        EACH_LANE zk[j] = zk[j] - zpr[j];
    }
  }
  for (int i = 0; i < m; ++i) {
    const double* zpr = LANES(zp, idx[i]);
    double* v = LANES(nu, i);
    const double zi = z[idx[i]];
    if (angle_row[idx[i]])
      EACH_LANE v[j] = abyssal_wrap_angle(zi - zpr[j]);
    else
      EACH_LANE v[j] = zi - zpr[j];
  }
  for (int q = 0; q < m; ++q) { /* Pzz = sum wc_k dz dz^T on the present rows */
    const double* dq = Z + (size_t)idx[q] * ld;
    for (int k = 0; k < N; ++k) {
      const double w = wc[k];
      const double* d = LANES(dq, k);
      double* ek = LANES(Ec, k);
      EACH_LANE ek[j] = w * d[j];
    }
    for (int i = 0; i <= q; ++i) {
      double v[B];
      block_dot(N, Ec, 1, Z + (size_t)idx[i] * ld, v);
      double* upper = LANES(Czz, i + q * m);
      double* lower = LANES(Czz, q + i * m);
      EACH_LANE upper[j] = lower[j] = v[j];
    }
  }
  for (int q = 0; q < m; ++q) { /* cross_covariance: Pxz = s sum_i L e_i (wc_+ D_+ - wc_- D_-) on the present rows */
    const double* d = Z + (size_t)idx[q] * ld;
    for (int c = 0; c < n; ++c) EACH_LANE LANES(C, c + q * n)[j] = 0.0;
    for (int i = 0; i < n; ++i) {
      double diff[B];
      const double wp = wc[first + i], wn = wc[first + n + i];
      const double* dp = LANES(d, first + i);
      const double* dn = LANES(d, first + n + i);
      EACH_LANE diff[j] = wp * dp[j] - wn * dn[j];
      for (int c = 0; c < n; ++c) {
        const double* l = LANES(L, c + i * n);
        double* out = LANES(C, c + q * n);
        EACH_LANE out[j] += l[j] * diff[j];
      }
    }
    for (int c = 0; c < n; ++c) {
      double* out = LANES(C, c + q * n);
      EACH_LANE out[j] *= s_spread;
    }
  }
  if (a->filter == ABYSSAL_MCUKF || a->filter == ABYSSAL_HUBER_UKF) {
    ok_noise = block_robust_noise(a, m, Rp, Czz, nu, Rt, &cur);
  } else {
    for (int k = 0; k < m * m; ++k) EACH_LANE LANES(Rt, k)[j] = Rp[k];
  }
  for (int q = 0; q < m; ++q)
    for (int i = 0; i <= q; ++i) {
      const double* cz = LANES(Czz, i + q * m);
      const double* rt = LANES(Rt, i + q * m);
      double* upper = LANES(Sp, i + q * m);
      double* lower = LANES(Sp, q + i * m);
      EACH_LANE upper[j] = lower[j] = cz[j] + rt[j];
    }
  all_ok(ok_s);
  block_cholesky(m, Sp, LS, ok_s);
  EACH_LANE ok[j] = ok_s[j] != 0.0 && ok_points[j] != 0.0 && ok_noise ? 1.0 : 0.0;
  /* Y = Pxz L_S^-T (abyssal_solve_right_lower_transposed, in C), e = L_S^-1 nu: x + Y e, P - Y Y^T */
  for (int q = 0; q < m; ++q) {
    const double* d = LANES(LS, q + q * m);
    for (int k = 0; k < q; ++k) {
      const double* lqk = LANES(LS, q + k * m);
      for (int i = 0; i < n; ++i) {
        double* b = LANES(C, i + q * n);
        const double* y = LANES(C, i + k * n);
#pragma omp simd
        EACH_LANE b[j] -= y[j] * lqk[j];
      }
    }
    for (int i = 0; i < n; ++i) {
      double* b = LANES(C, i + q * n);
#pragma omp simd
      EACH_LANE b[j] /= d[j];
    }
  }
  memcpy(e, nu, sizeof(double) * (size_t)m * B);
  block_solve_lower(m, LS, 0, e);
  for (int i = 0; i < n; ++i) { /* x + Y e (abyssal_gemv: the sum from x, k = 0, 1, ...) */
    double acc[B];
    const double* xi = LANES(x, i);
    EACH_LANE acc[j] = xi[j];
    for (int k = 0; k < m; ++k) {
      const double* y = LANES(C, i + k * n);
      const double* ek = LANES(e, k);
      EACH_LANE acc[j] += y[j] * ek[j];
    }
    double* out = LANES(x_post, i);
    EACH_LANE out[j] = acc[j];
  }
  for (int q = 0; q < n; ++q) /* column q of P - Y Y^T, rows 0..q (abyssal_gemv with -Y), mirrored */
    for (int i = 0; i <= q; ++i) {
      double acc[B];
      lanes_less_products(LANES(P, i + q * n), LANES(C, i), LANES(C, q), m, n, acc);
      double* upper = LANES(P_post, i + q * n);
      double* lower = LANES(P_post, q + i * n);
      EACH_LANE upper[j] = lower[j] = acc[j];
    }
  /* the report in the selection's layout: 0 / identity on absent entries */
  for (int r = 0; r < rows; ++r) EACH_LANE LANES(innovation, r)[j] = 0.0;
  for (int i = 0; i < m; ++i) memcpy(LANES(innovation, idx[i]), LANES(nu, i), sizeof(double) * B);
  for (int q = 0; q < rows; ++q)
    for (int i = 0; i < rows; ++i) {
      const double v = i == q && !present[i] ? 1.0 : 0.0;
      EACH_LANE LANES(S, i + q * rows)[j] = v;
    }
  for (int q = 0; q < m; ++q)
    for (int i = 0; i < m; ++i) memcpy(LANES(S, idx[i] + idx[q] * rows), LANES(Sp, i + q * m), sizeof(double) * B);
  finite_or_fail(n, x_post, ok);
  finite_or_fail(n * n, P_post, ok);
  finite_or_fail(m, nu, ok);
  finite_or_fail(m * m, Sp, ok);
}
