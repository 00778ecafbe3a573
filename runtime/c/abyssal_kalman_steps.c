/* abyssal_kalman_steps.c: see abyssal_kalman_steps.h. Hand-written C99.
 *
 * Layouts inside: sigma points are stored structure-of-arrays, the N values of coordinate i contiguous at
 * X + i N (the layout of the model's f_soa and h_soa kernels with ld = N). The rule's points are, for the cubature
 * rule, +s e_i (k = i) then -s e_i (k = n + i), s = sqrt(n); for the scaled unscented rule the centre (k = 0), then
 * +s e_i (k = 1 + i) and -s e_i (k = 1 + n + i), s = sqrt(alpha^2 (n + kappa)): so the offset of point k from the
 * mean is +-s times a column of the Cholesky factor L, which the cross-covariances use instead of X_k - x.
 */
#include "abyssal_kalman_steps.h"

#include <math.h>
#include <string.h>

#include "abyssal_linalg.h"

#define AT(a, ld, i, j) ((a)[(i) + (j) * (ld)])
#define ROUND8(b) (((b) + 7u) & ~(size_t)7u)

int abyssal_is_sigma_point(abyssal_filter filter) { return filter >= ABYSSAL_UKF && filter <= ABYSSAL_HUBER_UKF; }



int abyssal_sigma_points(abyssal_filter filter, int n) {
  if (!abyssal_is_sigma_point(filter)) return 0;
  return filter == ABYSSAL_CKF ? 2 * n : 2 * n + 1;
}

/* The rule's spread s (points at +-s L e_i) and its first +/- point. */
static double spread(const abyssal_algebra* a, int n) {
  if (a->filter == ABYSSAL_CKF) return sqrt((double)n);
  return sqrt(a->alpha * a->alpha * (n + a->kappa));
}

static int first_point(abyssal_filter filter) { return filter == ABYSSAL_CKF ? 0 : 1; }

int abyssal_sigma_weights(const abyssal_algebra* a, int n, double* wm, double* wc) {
  int N = abyssal_sigma_points(a->filter, n), k;
  if (N == 0) return 1;
  if (a->filter == ABYSSAL_CKF) {
    double w = 1.0 / (2 * n);
    for (k = 0; k < N; ++k) wm[k] = wc[k] = w;
  } else {
    double c = a->alpha * a->alpha * (n + a->kappa), wi = 1.0 / (2 * c);
    wm[0] = (c - n) / c;
    wc[0] = wm[0] + 1 - a->alpha * a->alpha + a->beta;
    for (k = 1; k < N; ++k) wm[k] = wc[k] = wi;
  }
  for (k = 0; k < N; ++k)
    if (!isfinite(wm[k]) || !isfinite(wc[k])) return 0;
  return 1;
}

int abyssal_selection_rows(const abyssal_model* model, int first, int count) {
  int rows = 0, k;
  if (first < 0 || count < 0 || first + count > model->n_sensors) return -1;
  for (k = first; k < first + count; ++k) rows += model->sensors[k].n_y;
  return rows;
}

/* ------------------------------------------------------------------ scratch */

typedef struct {
  const double** arg;
  double** res;
  long long* iw;
  double* w;
  double* d; /* the doubles region, handed out by take() */
} scratch_t;

static void grow(int* size, int value) {
  if (value > *size) *size = value;
}

static void call_sizes(const abyssal_model* m, int* arg, int* res, int* iw, int* w) {
  const abyssal_function* fns[3];
  int k, s;
  *arg = 4;
  *res = 1;
  *iw = 0;
  *w = 0;
  fns[0] = &m->f;
  fns[1] = &m->F;
  fns[2] = &m->G;
  for (k = 0; k < 3; ++k) {
    grow(arg, fns[k]->sz_arg);
    grow(res, fns[k]->sz_res);
    grow(iw, fns[k]->sz_iw);
    grow(w, fns[k]->sz_w);
  }
  for (s = 0; s < m->n_sensors; ++s) {
    const abyssal_function* hs[2];
    hs[0] = &m->sensors[s].h;
    hs[1] = &m->sensors[s].H;
    for (k = 0; k < 2; ++k) {
      grow(arg, hs[k]->sz_arg);
      grow(res, hs[k]->sz_res);
      grow(iw, hs[k]->sz_iw);
      grow(w, hs[k]->sz_w);
    }
  }
}

/* Doubles the algebra takes from the region (an upper bound over every call). */
static size_t region_doubles(const abyssal_model* m, const abyssal_algebra* a, int rows) {
  size_t n = (size_t)m->n_x, N = (size_t)abyssal_sigma_points(a->filter, m->n_x), r = (size_t)(rows > 0 ? rows : 1);
  size_t nu = (size_t)m->n_u;
  return 8 * n * n + 3 * N * n + N * nu + 2 * N * r + 12 * r * r + 10 * n * r + 4 * n + 8 * r + (size_t)m->n_sensors + 32;
}

size_t abyssal_steps_scratch_bytes(const abyssal_model* m, const abyssal_algebra* a, int max_rows) {
  int arg, res, iw, w;
  call_sizes(m, &arg, &res, &iw, &w);
  return ROUND8(sizeof(const double*) * (size_t)arg) + ROUND8(sizeof(double*) * (size_t)res) +
         sizeof(long long) * (size_t)iw + sizeof(double) * ((size_t)w + region_doubles(m, a, max_rows));
}

static void bind(const abyssal_model* m, void* memory, scratch_t* s) {
  int arg, res, iw, w;
  char* at = (char*)memory;
  call_sizes(m, &arg, &res, &iw, &w);
  s->arg = (const double**)(void*)at;
  at += ROUND8(sizeof(const double*) * (size_t)arg);
  s->res = (double**)(void*)at;
  at += ROUND8(sizeof(double*) * (size_t)res);
  s->iw = (long long*)(void*)at;
  at += sizeof(long long) * (size_t)iw;
  s->w = (double*)(void*)at;
  s->d = s->w + w;
}

static double* take(scratch_t* s, size_t count) {
  double* out = s->d;
  s->d += count;
  return out;
}

/* One call of a generated function: args and results in CasADi's order. */
static void evaluate(scratch_t* s, const abyssal_function* fn, const double* a0, const double* a1, const double* a2,
                     const double* a3, double* r0) {
  s->arg[0] = a0;
  s->arg[1] = a1;
  s->arg[2] = a2;
  s->arg[3] = a3;
  s->res[0] = r0;
  fn->eval(s->arg, s->res, s->iw, s->w, 0);
}

static int all_finite(int count, const double* a) {
  double total = 0.0;
  int k;
  for (k = 0; k < count; ++k) total += a[k] * 0.0; /* 0 for finite entries, NaN for inf or NaN */
  return total == 0.0;
}

static void symmetrised(int n, const double* A, double* out) {
  int i, j;
  for (j = 0; j < n; ++j)
    for (i = 0; i <= j; ++i) {
      double v = i == j ? AT(A, n, i, i) : (AT(A, n, i, j) + AT(A, n, j, i)) / 2;
      AT(out, n, i, j) = v;
      AT(out, n, j, i) = v;
    }
}

/* X = x + s L e_i and x - s L e_i (and the centre x for unscented rules), structure-of-arrays. */
static void sigma_points(const abyssal_algebra* a, int n, const double* x, const double* L, double* X) {
  int N = abyssal_sigma_points(a->filter, n), first = first_point(a->filter), i, j;
  double s = spread(a, n);
  for (j = 0; j < n; ++j) {
    double* row = X + (size_t)j * (size_t)N;
    if (first) row[0] = x[j];
    for (i = 0; i < n; ++i) {
      double offset = AT(L, n, j, i) * s;
      row[first + i] = x[j] + offset;
      row[first + n + i] = x[j] - offset;
    }
  }
}

/* C = sum_k wc_k (X_k - x) D_k^T with X_k - x = +-s L e_i: C_ab = s sum_i L_ai (wc_+ D_b+ - wc_- D_b-), for the
 * rows b of D (structure-of-arrays, rows_d of them, N points; used[b] == 0: a zero column). C is n x rows_d. */
static void cross_covariance(const abyssal_algebra* a, int n, const double* L, const double* wc, const double* D,
                             int rows_d, const unsigned char* used, double* C) {
  int N = abyssal_sigma_points(a->filter, n), first = first_point(a->filter), i, b, c;
  double s = spread(a, n);
  for (b = 0; b < rows_d; ++b) {
    const double* d = D + (size_t)b * (size_t)N;
    for (c = 0; c < n; ++c) AT(C, n, c, b) = 0.0;
    if (used && !used[b]) continue;
    for (i = 0; i < n; ++i) {
      double diff = wc[first + i] * d[first + i] - wc[first + n + i] * d[first + n + i];
      for (c = 0; c < n; ++c) AT(C, n, c, b) += AT(L, n, c, i) * diff;
    }
    for (c = 0; c < n; ++c) AT(C, n, c, b) *= s;
  }
}

/* ------------------------------------------------------------------ predict */

int abyssal_predict_gaussian(const abyssal_model* model, const abyssal_algebra* a, const double* wm, const double* wc,
                             const double* x, const double* P, const double* u, const double* p, double dt,
                             const double* Q, double* x_pred, double* P_pred, double* cross, void* memory) {
  const int n = model->n_x;
  scratch_t s;
  const double *Ps = P, *Qs = Q;
  int ok = 1, i, j;
  bind(model, memory, &s);
  if (!abyssal_is_sigma_point(a->filter)) {
    double* F = take(&s, (size_t)n * n);
    double* PFt = cross ? cross : take(&s, (size_t)n * n); /* P F^T: what smoothing needs */
    evaluate(&s, &model->f, x, u, p, &dt, x_pred);
    evaluate(&s, &model->F, x, u, p, &dt, F);
    abyssal_congruence(n, n, F, Ps, PFt, P_pred);
    for (i = 0; i < n * n; ++i) P_pred[i] += Qs[i]; /* both exactly symmetric: so is the sum */
  } else {
    const int N = abyssal_sigma_points(a->filter, n), n_u = model->n_u;
    double* L = take(&s, (size_t)n * n);
    double* X = take(&s, (size_t)N * n);
    double* U = take(&s, (size_t)N * (n_u > 0 ? n_u : 1));
    double* Y = take(&s, (size_t)N * n);
    double* E = take(&s, (size_t)N * n);
    const double* args[4];
    double* res[1];
    int k;
    ok = abyssal_cholesky(n, Ps, L);
    sigma_points(a, n, x, L, X);
    for (i = 0; i < n_u; ++i) /* every point gets u: the kernel's u is per point */
      for (k = 0; k < N; ++k) U[(size_t)i * N + k] = u[i];
    args[0] = X;
    args[1] = U;
    args[2] = p;
    args[3] = &dt;
    res[0] = Y;
    model->f_soa(N, N, args, res);
    for (i = 0; i < n; ++i) { /* the mean, then D = Y - x' in place and E = wc D */
      double* d = Y + (size_t)i * N;
      double* e = E + (size_t)i * N;
      const double mean = abyssal_dot(N, wm, d);
      x_pred[i] = mean;
      for (k = 0; k < N; ++k) {
        d[k] -= mean;
        e[k] = wc[k] * d[k];
      }
    }
    for (j = 0; j < n; ++j)
      for (i = 0; i <= j; ++i) {
        double v = abyssal_dot(N, E + (size_t)i * N, Y + (size_t)j * N) + AT(Qs, n, i, j);
        AT(P_pred, n, i, j) = v;
        AT(P_pred, n, j, i) = v;
      }
    if (cross) cross_covariance(a, n, L, wc, Y, n, 0, cross);
  }
  return ok && all_finite(n, x_pred) && all_finite(n * n, P_pred) && (!cross || all_finite(n * n, cross));
}

int abyssal_noise_jacobian(const abyssal_model* model, const abyssal_algebra* a, const double* x, const double* u,
                           const double* p, double dt, double* G, void* memory) {
  scratch_t s;
  (void)a;
  if (!model->G.eval || model->n_w < 1) return 0;
  bind(model, memory, &s);
  evaluate(&s, &model->G, x, u, p, &dt, G);
  return all_finite(model->n_x * model->n_w, G);
}

/* ------------------------------------------------------------------ robust measurement noise */

/* out = A diag(c) A^T (m x m, exactly symmetric). */
static void scaled_congruence(int m, const double* A, const double* c, double* out) {
  int i, j, k;
  for (j = 0; j < m; ++j)
    for (i = 0; i <= j; ++i) {
      double v = 0.0;
      for (k = 0; k < m; ++k) v += AT(A, m, i, k) * c[k] * AT(A, m, j, k);
      AT(out, m, i, j) = v;
      AT(out, m, j, i) = v;
    }
}

/* R~ of the robust updates (module docstring of the header) from R = a a^T, the innovation nu and Pzz; 1 when the
 * guarded factor of R (and Huber's factors) passed. */
static int robust_noise(const abyssal_algebra* a, int m, const double* R, const double* Pzz, const double* nu,
                        double* R_tilde, scratch_t* s) {
  double* fa = take(s, (size_t)m * m);
  double* zeta = take(s, (size_t)m);
  double* c = take(s, (size_t)m);
  int ok = abyssal_cholesky(m, R, fa), i, it;
  if (a->filter == ABYSSAL_MCUKF) {
    memcpy(zeta, nu, sizeof(double) * (size_t)m);
    abyssal_solve_lower(m, fa, 1, zeta);
    for (i = 0; i < m; ++i) {
      double e = zeta[i] * zeta[i] / (2 * a->sigma * a->sigma);
      c[i] = exp(e < ABYSSAL_MCC_MAX_EXPONENT ? e : ABYSSAL_MCC_MAX_EXPONENT); /* fmin: NaN takes the cap */
    }
    scaled_congruence(m, fa, c, R_tilde);
    return ok;
  } else {
    double* residual = take(s, (size_t)m);
    double* A = take(s, (size_t)m * m);
    double* L2 = take(s, (size_t)m * m);
    memcpy(residual, nu, sizeof(double) * (size_t)m);
    for (it = 0; it < a->huber_iterations; ++it) {
      memcpy(zeta, residual, sizeof(double) * (size_t)m);
      abyssal_solve_lower(m, fa, 1, zeta);
      for (i = 0; i < m; ++i) {
        double r = fabs(zeta[i]) / a->gamma;
        c[i] = r > 1.0 ? r : 1.0; /* fmax(1, .): NaN gives 1 */
      }
      scaled_congruence(m, fa, c, R_tilde);
      for (i = 0; i < m * m; ++i) A[i] = Pzz[i] + R_tilde[i];
      abyssal_cholesky(m, A, L2);
      memcpy(zeta, nu, sizeof(double) * (size_t)m); /* the post-fit residual R~ (Pzz + R~)^-1 nu */
      abyssal_solve_lower(m, L2, 1, zeta);
      abyssal_solve_lower_transposed(m, L2, 1, zeta);
      for (i = 0; i < m; ++i) residual[i] = abyssal_dot(m, R_tilde + (size_t)i * m, zeta); /* R~ symmetric */
    }
    return ok;
  }
}

/* ------------------------------------------------------------------ update */

int abyssal_update_gaussian(const abyssal_model* model, const abyssal_algebra* a, const double* wm, const double* wc,
                            int first, int count, const double* x, const double* P, const double* z,
                            const unsigned char* present, const double* p, const double* R, double* x_post,
                            double* P_post, double* innovation, double* S, double* Pxz, double* Pzz, void* memory) {
  const int n = model->n_x, rows = abyssal_selection_rows(model, first, count);
  int *idx, *angle_row, *row_sensor_offset; /* the present rows, each row's angle flag, each sensor's first row */
  scratch_t s;
  const double* Ps;
  double *nu, *Rp, *Rt, *Czz, *C, *Sp, *LS, *W, *e;
  int m = 0, ok, i, j, k, r, sel;
  if (rows < 0) return 0;
  bind(model, memory, &s);
  idx = (int*)(void*)take(&s, (size_t)rows + 1);
  angle_row = (int*)(void*)take(&s, (size_t)rows + 1);
  row_sensor_offset = (int*)(void*)take(&s, (size_t)count + 1);
  for (r = 0, sel = 0; sel < count; ++sel) { /* the stacked rows: their angle flags, and the present ones */
    const abyssal_sensor* sensor = &model->sensors[first + sel];
    row_sensor_offset[sel] = r;
    for (k = 0; k < sensor->n_y; ++k, ++r) angle_row[r] = sensor->angle_outputs ? sensor->angle_outputs[k] : 0;
  }
  for (r = 0; r < rows; ++r)
    if (present[r]) idx[m++] = r;
  Ps = P;
  nu = take(&s, (size_t)(m > 0 ? m : 1));
  Rp = take(&s, (size_t)m * m + 1);
  Rt = take(&s, (size_t)m * m + 1);
  Czz = take(&s, (size_t)m * m + 1);
  C = take(&s, (size_t)n * (m > 0 ? m : 1));
  Sp = take(&s, (size_t)m * m + 1);
  LS = take(&s, (size_t)m * m + 1);
  W = take(&s, (size_t)n * (m > 0 ? m : 1));
  e = take(&s, (size_t)(m > 0 ? m : 1));
  for (j = 0; j < m; ++j) /* R on the present entries */
    for (i = 0; i < m; ++i) AT(Rp, m, i, j) = AT(R, rows, idx[i], idx[j]);
  if (!abyssal_is_sigma_point(a->filter)) {
    double* y = take(&s, (size_t)rows);
    double* H = take(&s, (size_t)rows * n);
    double* Hs = take(&s, (size_t)(m > 0 ? m : 1) * n);
    double* K = take(&s, (size_t)n * (m > 0 ? m : 1));
    double* V = take(&s, (size_t)n * (m > 0 ? m : 1));
    for (sel = 0; sel < count; ++sel) {
      const abyssal_sensor* sensor = &model->sensors[first + sel];
      double* Hk = take(&s, (size_t)sensor->n_y * n);
      int o = row_sensor_offset[sel];
      evaluate(&s, &sensor->h, x, p, 0, 0, y + o);
      evaluate(&s, &sensor->H, x, p, 0, 0, Hk);
      for (j = 0; j < n; ++j)
        for (k = 0; k < sensor->n_y; ++k) AT(H, rows, o + k, j) = AT(Hk, sensor->n_y, k, j);
    }
    for (j = 0; j < n; ++j)
      for (i = 0; i < m; ++i) AT(Hs, m, i, j) = AT(H, rows, idx[i], j);
    for (i = 0; i < m; ++i) {
      double d = z[idx[i]] - y[idx[i]];
      nu[i] = angle_row[idx[i]] ? abyssal_wrap_angle(d) : d;
    }
    abyssal_congruence(m, n, Hs, Ps, C, Czz); /* H P H^T, C = P H^T */
    for (j = 0; j < m; ++j)
      for (i = 0; i <= j; ++i) {
        double v = AT(Czz, m, i, j) + AT(Rp, m, i, j);
        AT(Sp, m, i, j) = v;
        AT(Sp, m, j, i) = v;
      }
    ok = abyssal_cholesky(m, Sp, LS);
    memcpy(K, C, sizeof(double) * (size_t)n * m); /* K = P H^T S^-1 = ((P H^T) L^-T) L^-1 */
    abyssal_solve_right_lower_transposed(n, m, LS, K);
    abyssal_solve_right_lower(n, m, LS, K);
    abyssal_gemv(n, m, K, n, nu, 1, x, x_post);
    for (j = 0; j < m; ++j) { /* V = K S - P H^T, by columns */
      for (i = 0; i < n; ++i) AT(V, n, i, j) = -AT(C, n, i, j);
      abyssal_gemv(n, m, K, n, Sp + (size_t)j * m, 1, V + (size_t)j * n, V + (size_t)j * n);
    }
    { /* Joseph: P - K (P H^T)^T - (P H^T) K^T + K S K^T = P - K C^T + V K^T: [K V] [-C^T; K^T], by columns */
      double* KV = take(&s, (size_t)n * 2 * (m > 0 ? m : 1));
      double* w2 = take(&s, (size_t)2 * (m > 0 ? m : 1));
      memcpy(KV, K, sizeof(double) * (size_t)n * m);
      memcpy(KV + (size_t)n * m, V, sizeof(double) * (size_t)n * m);
      for (j = 0; j < n; ++j) {
        for (k = 0; k < m; ++k) {
          w2[k] = -AT(C, n, j, k);
          w2[m + k] = AT(K, n, j, k);
        }
        abyssal_gemv(n, 2 * m, KV, n, w2, 1, Ps + (size_t)j * n, P_post + (size_t)j * n);
      }
      for (j = 0; j < n; ++j) /* exactly symmetric: the upper triangle mirrored */
        for (i = j + 1; i < n; ++i) AT(P_post, n, i, j) = AT(P_post, n, j, i);
    }
  } else {
    const int N = abyssal_sigma_points(a->filter, n);
    double* L = take(&s, (size_t)n * n);
    double* X = take(&s, (size_t)N * n);
    double* Z = take(&s, (size_t)N * (rows > 0 ? rows : 1));
    double* Ec = take(&s, (size_t)N);
    double* zp = take(&s, (size_t)(rows > 0 ? rows : 1));
    double* Cfull = take(&s, (size_t)n * (rows > 0 ? rows : 1));
    const double* args[2];
    double* res[1];
    int ok_points = abyssal_cholesky(n, Ps, L), ok_noise = 1;
    sigma_points(a, n, x, L, X);
    for (sel = 0; sel < count; ++sel) {
      const abyssal_sensor* sensor = &model->sensors[first + sel];
      args[0] = X;
      args[1] = p;
      res[0] = Z + (size_t)row_sensor_offset[sel] * N;
      sensor->h_soa(N, N, args, res);
    }
    for (r = 0; r < rows; ++r) { /* z_pred, and the residuals Z_k - z_pred in place (angles wrapped) */
      double* zr = Z + (size_t)r * N;
      zp[r] = abyssal_dot(N, wm, zr);
      if (!present[r]) continue;
      for (k = 0; k < N; ++k) zr[k] = angle_row[r] ? abyssal_wrap_angle(zr[k] - zp[r]) : zr[k] - zp[r];
    }
    for (i = 0; i < m; ++i) {
      double d = z[idx[i]] - zp[idx[i]];
      nu[i] = angle_row[idx[i]] ? abyssal_wrap_angle(d) : d;
    }
    for (j = 0; j < m; ++j) { /* Pzz = sum wc_k dz dz^T on the present rows */
      const double* dj = Z + (size_t)idx[j] * N;
      for (k = 0; k < N; ++k) Ec[k] = wc[k] * dj[k];
      for (i = 0; i <= j; ++i) {
        double v = abyssal_dot(N, Ec, Z + (size_t)idx[i] * N);
        AT(Czz, m, i, j) = v;
        AT(Czz, m, j, i) = v;
      }
    }
    cross_covariance(a, n, L, wc, Z, rows, present, Cfull);
    for (j = 0; j < m; ++j) memcpy(C + (size_t)j * n, Cfull + (size_t)idx[j] * n, sizeof(double) * (size_t)n);
    if (a->filter == ABYSSAL_MCUKF || a->filter == ABYSSAL_HUBER_UKF) {
      ok_noise = robust_noise(a, m, Rp, Czz, nu, Rt, &s);
    } else {
      memcpy(Rt, Rp, sizeof(double) * (size_t)m * m);
    }
    for (j = 0; j < m; ++j)
      for (i = 0; i <= j; ++i) {
        double v = AT(Czz, m, i, j) + AT(Rt, m, i, j);
        AT(Sp, m, i, j) = v;
        AT(Sp, m, j, i) = v;
      }
    ok = abyssal_cholesky(m, Sp, LS) && ok_points && ok_noise;
    { /* Y = Pxz L_S^-T (n x m), e = L_S^-1 nu: x + Y e, P - Y Y^T */
      double* Y = W;
      double* Yn = take(&s, (size_t)n * (m > 0 ? m : 1)); /* -Y */
      memcpy(Y, C, sizeof(double) * (size_t)n * m);
      abyssal_solve_right_lower_transposed(n, m, LS, Y);
      memcpy(e, nu, sizeof(double) * (size_t)m);
      abyssal_solve_lower(m, LS, 1, e);
      abyssal_gemv(n, m, Y, n, e, 1, x, x_post);
      for (i = 0; i < n * m; ++i) Yn[i] = -Y[i];
      for (j = 0; j < n; ++j) /* column j of P - Y Y^T = P[:, j] + (-Y) (row j of Y), rows 0..j */
        abyssal_gemv(j + 1, m, Yn, n, Y + j, n, Ps + (size_t)j * n, P_post + (size_t)j * n);
      for (j = 0; j < n; ++j) /* exactly symmetric: the upper triangle mirrored */
        for (i = j + 1; i < n; ++i) AT(P_post, n, i, j) = AT(P_post, n, j, i);
    }
  }
  /* the report in the selection's layout: 0 / identity on absent entries */
  for (r = 0; r < rows; ++r) innovation[r] = 0.0;
  for (i = 0; i < m; ++i) innovation[idx[i]] = nu[i];
  for (j = 0; j < rows; ++j)
    for (i = 0; i < rows; ++i) AT(S, rows, i, j) = i == j && !present[i] ? 1.0 : 0.0;
  for (j = 0; j < m; ++j)
    for (i = 0; i < m; ++i) AT(S, rows, idx[i], idx[j]) = AT(Sp, m, i, j);
  if (Pxz) {
    memset(Pxz, 0, sizeof(double) * (size_t)n * (size_t)rows);
    for (j = 0; j < m; ++j) memcpy(Pxz + (size_t)idx[j] * n, C + (size_t)j * n, sizeof(double) * (size_t)n);
  }
  if (Pzz) {
    memset(Pzz, 0, sizeof(double) * (size_t)rows * (size_t)rows);
    for (j = 0; j < m; ++j)
      for (i = 0; i < m; ++i) AT(Pzz, rows, idx[i], idx[j]) = AT(Czz, m, i, j);
  }
  return ok && all_finite(n, x_post) && all_finite(n * n, P_post) && all_finite(m, nu) && all_finite(m * m, Sp);
}

/* ------------------------------------------------------------------ batched steps */

size_t abyssal_steps_batch_scratch_bytes(const abyssal_model* model, abyssal_filter filter) {
  abyssal_algebra a;
  int n = model->n_x, N = abyssal_sigma_points(filter, n);
  memset(&a, 0, sizeof a);
  a.filter = filter;
  /* the steps' scratch, the weights, a predicted (x, P) for a fused step, the present flags */
  /* + the inputs symmetrised: P, Q (n x n) and R (n_y x n_y) */
  return abyssal_steps_scratch_bytes(model, &a, model->n_y) +
         sizeof(double) * (size_t)(2 * N + n + n * n + 2 + 2 * n * n + model->n_y * model->n_y) + ROUND8((size_t)model->n_y + 1);
}

int abyssal_steps_batch(const abyssal_model* model, int filter, int op, void* scratch, long long N, const double** arg,
                        const long long* arg_step, double** res, const long long* res_step) {
  const int n = model->n_x, m = model->n_y, points = abyssal_sigma_points((abyssal_filter)filter, n);
  abyssal_algebra a;
  char* at = (char*)scratch;
  double *wm, *wc, *x_mid, *P_mid, *Ps, *Qs, *Rs;
  unsigned char* present;
  void* steps;
  const int unscented = abyssal_is_sigma_point((abyssal_filter)filter) && filter != ABYSSAL_CKF;
  const int robust = op == ABYSSAL_BATCH_UPDATE && (filter == ABYSSAL_MCUKF || filter == ABYSSAL_HUBER_UKF);
  const int rule = op == ABYSSAL_BATCH_STEP ? 9 : 6, n_args = rule + unscented + robust;
  int i;
  long long j;
  if (filter < ABYSSAL_EKF || filter > ABYSSAL_HUBER_UKF || op < 0 || op > 2) return -1;
  memset(&a, 0, sizeof a);
  a.filter = (abyssal_filter)filter;
  a.alpha = 1.0;
  a.beta = 2.0;
  a.sigma = INFINITY;
  a.gamma = INFINITY;
  a.huber_iterations = 3;
  steps = at;
  at += abyssal_steps_scratch_bytes(model, &a, m);
  wm = (double*)(void*)at;
  wc = wm + points;
  x_mid = wc + points;
  P_mid = x_mid + n;
  Ps = P_mid + n * n + 2;
  Qs = Ps + n * n;
  Rs = Qs + n * n;
  present = (unsigned char*)(void*)(Rs + m * m);
  for (j = 0; j < N; ++j) {
    const double* s[11];
    double* r[5];
    int ok = 1, k;
    for (k = 0; k < n_args; ++k) s[k] = arg[k] ? arg[k] + j * arg_step[k] : 0;
    for (k = 0; k < (op == ABYSSAL_BATCH_PREDICT ? 3 : 5); ++k) r[k] = res[k] + j * res_step[k];
    if (unscented) { /* the rule's settings */
      const double* abk = s[rule];
      a.alpha = abk[0];
      a.beta = abk[1];
      a.kappa = abk[2];
      if (robust) {
        a.sigma = s[rule + 1][0];
        a.gamma = s[rule + 1][0];
      }
    }
    if (points && !abyssal_sigma_weights(&a, n, wm, wc)) ok = 0;
    symmetrised(n, s[1], Ps); /* (the generated steps these replace symmetrised their inputs too) */
    if (op == ABYSSAL_BATCH_PREDICT) {
      symmetrised(n, s[5], Qs);
      ok = ok && abyssal_predict_gaussian(model, &a, wm, wc, s[0], Ps, s[2], s[3], s[4][0], Qs, r[0], r[1], 0, steps);
      r[2][0] = ok ? 1.0 : 0.0;
      continue;
    }
    if (op == ABYSSAL_BATCH_STEP) {
      symmetrised(n, s[5], Qs);
      symmetrised(m, s[7], Rs);
      ok = ok && abyssal_predict_gaussian(model, &a, wm, wc, s[0], Ps, s[2], s[3], s[4][0], Qs, x_mid, P_mid, 0, steps);
      for (i = 0; i < m; ++i) present[i] = s[8][i] != 0.0;
      ok = abyssal_update_gaussian(model, &a, wm, wc, 0, model->n_sensors, x_mid, P_mid, s[6], present, s[3], Rs, r[0],
                                   r[1], r[2], r[3], 0, 0, steps) && ok;
    } else {
      symmetrised(m, s[4], Rs);
      for (i = 0; i < m; ++i) present[i] = s[5][i] != 0.0;
      ok = abyssal_update_gaussian(model, &a, wm, wc, 0, model->n_sensors, s[0], Ps, s[2], present, s[3], Rs, r[0],
                                   r[1], r[2], r[3], 0, 0, steps) && ok;
    }
    r[4][0] = ok ? 1.0 : 0.0;
  }
  return 0;
}
