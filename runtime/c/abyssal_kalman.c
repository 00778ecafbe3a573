/* abyssal_kalman.c: the Kalman-family runtime (see abyssal_kalman.h). Hand-written C99.
 *
 * Object layout (byte offsets from its start, all 8-byte aligned; no pointers into itself):
 *
 *   header (struct abyssal_kalman) | gate | x[3] P[3] (buffer sets) | innovation[2] S[2] | Q R
 *   ---------------------------------------------- the committed state ends here (state_bytes)
 *   Qk z0 mask | present gated present0 (bytes) | gate copy | sigma points X, U, Y | arg res iw w | scratch
 *
 * Transactions. The state is buffer set `current`; a call writes only into the other two sets and into
 * scratch, collects what it would change in a `pending` record, and commits it in one step that cannot fail.
 * A predict reads the current set and writes one of the others; its substeps ping-pong between those two; an
 * update reads its prior (the current set, or the prediction) and writes the remaining one. The gate's counters
 * are updated in a copy and copied back on commit; the reported innovation and S alternate between two buffers.
 */
#include "abyssal_kalman.h"

#include <float.h>
#include <math.h>
#include <string.h>

#include "abyssal_kalman_covariance.h"

#define KALMAN_MAGIC 0x6e616d6c616b7962ULL /* "byskalman" */
#define DT_CACHE 8
#define ROUND8(b) (((b) + 7u) & ~(size_t)7u)

struct abyssal_kalman {
  unsigned long long magic;
  const abyssal_model* model;
  abyssal_kalman_options options;
  int n, m, n_u, n_p, points;     /* points: sigma points per predict (0: EKF) */
  int current;                    /* the buffer set holding the state */
  int reported;                   /* the innovation/S buffer of the last accepted update; -1: none yet */
  int nis_dof;
  double nis;
  long long repairs, substeps;
  double checked_dt;              /* predicts with dt up to this passed the stability check */
  double cache_dt[DT_CACHE];      /* dt -> number of pieces found stable for it (0: empty entry) */
  long long cache_pieces[DT_CACHE];
  long long cache_next;
  double abk[3];                  /* alpha, beta, kappa: an input of the unscented functions */
  double robust;                  /* sigma (MCUKF) or gamma (Huber): an input of the robust updates */
  long long x[3], P[3], innovation[2], S[2], Q, R, wm, wc, gate, state_bytes;
  long long Qk, z0, mask, present, gated, present0, gate_copy, X, U, Y, arg, res, iw, w, scratch, bytes;
};

/* What a call changes, committed at its end. */
typedef struct {
  int set;
  long long repairs, substeps;
  double checked_dt, cache_dt;
  long long cache_pieces;
  int updated, reported, nis_dof, noted, inflate;
  double nis;
} pending;

#define DOUBLES(f, offset) ((double*)(void*)((char*)(f) + (offset)))
#define BYTES(f, offset) ((unsigned char*)(void*)((char*)(f) + (offset)))
#define XS(f, k) DOUBLES(f, (f)->x[k])
#define PS(f, k) DOUBLES(f, (f)->P[k])

static int is_unscented(abyssal_filter filter) { return filter == ABYSSAL_UKF || filter == ABYSSAL_MCUKF || filter == ABYSSAL_HUBER_UKF; }

static const abyssal_function* predict_points(const abyssal_model* model, abyssal_filter filter) {
  return filter == ABYSSAL_CKF ? &model->ckf_predict_points : &model->ukf_predict_points;
}

static const abyssal_function* predict_weights(const abyssal_model* model, abyssal_filter filter) {
  return filter == ABYSSAL_CKF ? &model->ckf_predict_weights : &model->ukf_predict_weights;
}

static const abyssal_function* update_function(const abyssal_model* model, abyssal_filter filter) {
  switch (filter) {
    case ABYSSAL_EKF: return &model->ekf_update;
    case ABYSSAL_CKF: return &model->ckf_update;
    case ABYSSAL_UKF: return &model->ukf_update;
    case ABYSSAL_MCUKF: return &model->mcukf_update;
    default: return &model->huber_ukf_update;
  }
}

/* ------------------------------------------------------------------ options and sizes */

abyssal_kalman_options abyssal_kalman_default_options(abyssal_filter filter) {
  abyssal_kalman_options o;
  o.filter = filter;
  o.alpha = 1.0;
  o.beta = 2.0;
  o.kappa = 0.0;
  o.sigma = 15.0;
  o.gamma = 1.345;
  o.gate_probability = 1e-10;
  o.gate_patience = 5;
  o.gate_inflation = 4.0;
  o.growth_limit = 1e3;
  o.max_substeps = 64;
  o.repair_floor = 1e-10;
  return o;
}

int abyssal_kalman_check_options(const abyssal_model* model, const abyssal_kalman_options* o) {
  const abyssal_function* needed[4];
  int count = 0, k;
  if (!model || !o) return model ? ABYSSAL_E_FILTER : ABYSSAL_E_MODEL;
  if (o->filter < ABYSSAL_EKF || o->filter > ABYSSAL_HUBER_UKF) return ABYSSAL_E_FILTER;
  if (model->n_x < 1 || model->n_y < 1 || model->n_u < 0 || model->n_p < 0) return ABYSSAL_E_MODEL;
  if (o->filter == ABYSSAL_EKF) {
    needed[count++] = &model->ekf_predict;
  } else {
    if (!model->f_soa) return ABYSSAL_E_MODEL;
    needed[count++] = predict_points(model, o->filter);
    needed[count++] = predict_weights(model, o->filter);
  }
  needed[count++] = update_function(model, o->filter);
  for (k = 0; k < count; ++k)
    if (!needed[k]->eval) return ABYSSAL_E_MODEL;
  if (is_unscented(o->filter)) {
    double c = o->alpha * o->alpha * (model->n_x + o->kappa);
    if (!isfinite(o->alpha) || !isfinite(o->beta) || !isfinite(o->kappa) || !(c > 0.0 && c < INFINITY) ||
        !isfinite((c - model->n_x) / c + 1.0 - o->alpha * o->alpha + o->beta) || !isfinite(1.0 / (2.0 * c)))
      return ABYSSAL_E_SIGMA_POINTS;
  }
  if ((o->filter == ABYSSAL_MCUKF && !(o->sigma > 0.0)) || (o->filter == ABYSSAL_HUBER_UKF && !(o->gamma > 0.0)))
    return ABYSSAL_E_ROBUST;
  if (!(o->gate_probability >= 0.0 && o->gate_probability < 1.0) || o->gate_patience < 1 ||
      !(o->gate_inflation >= 1.0 && o->gate_inflation < INFINITY))
    return ABYSSAL_E_GATE;
  if (!(o->growth_limit > 1.0) || o->max_substeps < 1 || !(o->repair_floor > 0.0 && o->repair_floor < 1.0))
    return ABYSSAL_E_SUBSTEPS;
  return ABYSSAL_OK;
}

static void grow(int* size, int value) {
  if (value > *size) *size = value;
}

/* The layout of a filter object (offsets into `f`, which may be a stack copy of the header only). */
static void lay_out(struct abyssal_kalman* f, const abyssal_model* model, const abyssal_kalman_options* o) {
  const abyssal_function* used[3];
  int n = model->n_x, m = model->n_y, sz_arg = 4, sz_res = 1, sz_iw = 0, sz_w = 0, count = 0, k, scratch;
  size_t at = ROUND8(sizeof(struct abyssal_kalman)), gate = abyssal_gate_size(m);
  f->n = n;
  f->m = m;
  f->n_u = model->n_u;
  f->n_p = model->n_p;
  f->points = o->filter == ABYSSAL_CKF ? 2 * n : (is_unscented(o->filter) ? 2 * n + 1 : 0);
#define TAKE(field, bytes) do { f->field = (long long)at; at += ROUND8(bytes); } while (0)
  TAKE(gate, gate);
  for (k = 0; k < 3; ++k) TAKE(x[k], sizeof(double) * n);
  for (k = 0; k < 3; ++k) TAKE(P[k], sizeof(double) * n * n);
  for (k = 0; k < 2; ++k) TAKE(innovation[k], sizeof(double) * m);
  for (k = 0; k < 2; ++k) TAKE(S[k], sizeof(double) * m * m);
  TAKE(Q, sizeof(double) * n * n);
  TAKE(R, sizeof(double) * m * m);
  TAKE(wm, sizeof(double) * f->points);
  TAKE(wc, sizeof(double) * f->points);
  f->state_bytes = (long long)at;
  if (o->filter == ABYSSAL_EKF) {
    used[count++] = &model->ekf_predict;
  } else {
    used[count++] = predict_points(model, o->filter);
    used[count++] = predict_weights(model, o->filter);
  }
  used[count++] = update_function(model, o->filter);
  for (k = 0; k < count; ++k) {
    grow(&sz_arg, used[k]->sz_arg);
    grow(&sz_res, used[k]->sz_res);
    grow(&sz_iw, used[k]->sz_iw);
    grow(&sz_w, used[k]->sz_w);
  }
  scratch = 3 * n * n + n;  /* the repair (the largest user; the covariance check takes 2 n^2 + n) */
  grow(&scratch, 2 * m * m + m);
  TAKE(Qk, sizeof(double) * n * n);
  TAKE(z0, sizeof(double) * m);
  TAKE(mask, sizeof(double) * m);
  TAKE(present, m);
  TAKE(gated, m);
  TAKE(present0, m);
  TAKE(gate_copy, gate);
  TAKE(X, sizeof(double) * f->points * n);
  TAKE(U, sizeof(double) * f->points * model->n_u);
  TAKE(Y, sizeof(double) * f->points * n);
  TAKE(arg, sizeof(const double*) * sz_arg);
  TAKE(res, sizeof(double*) * sz_res);
  TAKE(iw, sizeof(long long) * sz_iw);
  TAKE(w, sizeof(double) * sz_w);
  TAKE(scratch, sizeof(double) * (scratch + n * n));
#undef TAKE
  f->bytes = (long long)at;
}

size_t abyssal_kalman_work_size(const abyssal_model* model, const abyssal_kalman_options* options) {
  struct abyssal_kalman layout;
  if (abyssal_kalman_check_options(model, options) != ABYSSAL_OK) return 0;
  lay_out(&layout, model, options);
  return (size_t)layout.bytes;
}

/* ------------------------------------------------------------------ calls of generated functions */

static int evaluate(abyssal_kalman* f, const abyssal_function* fn, const double* const* args, int n_args,
                    double* const* results, int n_res) {
  const double** arg = (const double**)(void*)((char*)f + f->arg);
  double** res = (double**)(void*)((char*)f + f->res);
  int k;
  for (k = 0; k < n_args; ++k) arg[k] = args[k];
  for (k = 0; k < n_res; ++k) res[k] = results[k];
  return fn->eval(arg, res, (long long*)(void*)((char*)f + f->iw), DOUBLES(f, f->w), 0);
}

/* sum_k a_k b_k in four interleaved partial sums (k mod 4, the tail in the first), added pairwise at the end: a
 * fixed order, so every compiler computes the same sum, in 4-wide vector operations where it can. */
static double dot(int N, const double* restrict a, const double* restrict b) {
  double s[4] = {0.0, 0.0, 0.0, 0.0};
  int k = 0, lane;
  for (; k + 4 <= N; k += 4)
    for (lane = 0; lane < 4; ++lane) s[lane] += a[k + lane] * b[k + lane];
  for (; k < N; ++k) s[0] += a[k] * b[k];
  return (s[0] + s[1]) + (s[2] + s[3]);
}

/* The moments of the propagated points Y (points x n, column-major: the N values of state i are contiguous at
 * Y + i N, the layout of the model's SIMD kernel), with the rule's weights: x_i = sum_k wm_k Y_ik and
 * P_ij = sum_k wc_k D_ik D_jk + sym(Q)_ij with D = Y - x (in place), on and above the diagonal, mirrored (P exactly
 * symmetric). E = wc D goes to the points' buffer X. 1 when x and P are finite. */
static int moments(abyssal_kalman* f, double* Y, const double* Q, double* x, double* P) {
  const int N = f->points, n = f->n;
  const double *wm = DOUBLES(f, f->wm), *wc = DOUBLES(f, f->wc);
  double *D = Y, *E = DOUBLES(f, f->X), total = 0.0;
  int i, j, k;
  for (i = 0; i < n; ++i) {
    double* d = D + i * N;
    double* e = E + i * N;
    const double mean = dot(N, wm, d);
    x[i] = mean;
    total += mean;
    for (k = 0; k < N; ++k) {
      d[k] -= mean;
      e[k] = wc[k] * d[k];
    }
  }
  for (j = 0; j < n; ++j)
    for (i = 0; i <= j; ++i) {
      double value = dot(N, E + i * N, D + j * N) + (i == j ? Q[i + j * n] : (Q[i + j * n] + Q[j + i * n]) / 2);
      P[i + j * n] = value;
      P[j + i * n] = value;
      total += value;
    }
  return isfinite(total);
}

/* predict from buffer set src into dst with step dt and noise Q; 1 when it succeeded (every Cholesky pivot passed
 * its guard, every output finite). */
static int predict_once(abyssal_kalman* f, int src, int dst, const double* u, const double* p, double dt,
                        const double* Q) {
  const abyssal_model* model = f->model;
  double ok = 0.0;
  if (f->options.filter == ABYSSAL_EKF) {
    const double* args[6];
    double* res[3];
    args[0] = XS(f, src); args[1] = PS(f, src); args[2] = u; args[3] = p; args[4] = &dt; args[5] = Q;
    res[0] = XS(f, dst); res[1] = PS(f, dst); res[2] = &ok;
    evaluate(f, &model->ekf_predict, args, 6, res, 3);
    return ok == 1.0;
  } else {
    double *X = DOUBLES(f, f->X), *U = DOUBLES(f, f->U), *Y = DOUBLES(f, f->Y);
    const double* args[4];
    double* res[2];
    int N = f->points, i, j;
    args[0] = XS(f, src); args[1] = PS(f, src); args[2] = f->abk;
    res[0] = X; res[1] = &ok;
    evaluate(f, predict_points(model, f->options.filter), args, is_unscented(f->options.filter) ? 3 : 2, res, 2);
    if (ok != 1.0) return 0;
    for (i = 0; i < f->n_u; ++i) /* every point gets u: the kernel's u is per point */
      for (j = 0; j < N; ++j) U[i * N + j] = u[i];
    args[0] = X; args[1] = U; args[2] = p; args[3] = &dt;
    res[0] = Y;
    model->f_soa(N, N, args, res);
    return moments(f, Y, Q, XS(f, dst), PS(f, dst));
  }
}

/* update from buffer set src into dst with z0 (0 where left out) and the mask; innovation/S into buffer rb. */
static int update_once(abyssal_kalman* f, int src, int dst, const double* p, int rb) {
  const double* args[8];
  double* res[5];
  double ok = 0.0;
  args[0] = XS(f, src); args[1] = PS(f, src); args[2] = DOUBLES(f, f->z0); args[3] = p; args[4] = DOUBLES(f, f->R);
  args[5] = DOUBLES(f, f->mask); args[6] = f->abk; args[7] = &f->robust;
  res[0] = XS(f, dst); res[1] = PS(f, dst); res[2] = DOUBLES(f, f->innovation[rb]); res[3] = DOUBLES(f, f->S[rb]);
  res[4] = &ok;
  evaluate(f, update_function(f->model, f->options.filter), args,
           f->options.filter == ABYSSAL_EKF || f->options.filter == ABYSSAL_CKF ? 6
           : f->options.filter == ABYSSAL_UKF ? 7 : 8, res, 5);
  return ok == 1.0;
}

/* The prior of buffer set src with its covariance repaired: in place when src is scratch, else in `spare` (x
 * copied). Returns the set, or -1 when the state is not finite. */
static int repaired(abyssal_kalman* f, int src, int spare) {
  int n = f->n;
  double* scratch = DOUBLES(f, f->scratch);
  double* out = scratch + 3 * n * n + n;
  if (!abyssal_all_finite(n, XS(f, src)) ||
      abyssal_repair_covariance(n, PS(f, src), DOUBLES(f, f->Q), f->options.repair_floor, out, scratch) != 0)
    return -1;
  if (src == f->current) {
    memcpy(XS(f, spare), XS(f, src), sizeof(double) * n);
    src = spare;
  }
  memcpy(PS(f, src), out, sizeof(double) * n * n);
  return src;
}

static long long cached_pieces(const abyssal_kalman* f, double dt) {
  int k;
  for (k = 0; k < DT_CACHE; ++k)
    if (f->cache_pieces[k] > 0 && f->cache_dt[k] == dt) return f->cache_pieces[k];
  return 1;
}

/* ------------------------------------------------------------------ the predict and the update */

static int predict_into(abyssal_kalman* f, const double* u, const double* p, double dt, pending* out) {
  int c = f->current, a = (c + 1) % 3, b = (c + 2) % 3, n = f->n;
  const double* Q = DOUBLES(f, f->Q);
  const double limit = f->options.growth_limit;
  long long pieces;
  int known_dt = dt <= f->checked_dt;
  if (known_dt) { /* a dt found stable before: one predict, checked like any other */
    int prior = c, ok = predict_once(f, c, a, u, p, dt, Q), repairs = 0;
    if (!ok) { /* maybe only a covariance to repair */
      prior = repaired(f, c, b);
      if (prior < 0) return ABYSSAL_E_STATE;
      ok = predict_once(f, prior, a, u, p, dt, Q);
      repairs = 1;
    }
    if (ok && !abyssal_grew_beyond(n, limit, PS(f, prior), PS(f, a), Q)) {
      out->set = a;
      out->repairs += repairs;
      return ABYSSAL_OK;
    }
    /* it blew up at this state and input (a glitch of u accepted as finite: rov4dof at u = 1e5 N went to |x| ~ 1e39
     * in one 0.1 s predict): subdivided like a long dt, but not remembered for this dt */
    pieces = 2;
  } else {
    pieces = cached_pieces(f, dt);
  }
  for (; pieces <= f->options.max_substeps; pieces *= 2) {
    double* Qk = DOUBLES(f, f->Qk);
    double piece = dt / (double)pieces;
    int src = c, stable = 1, repairs = 0, k;
    if (pieces > 1)
      for (k = 0; k < n * n; ++k) Qk[k] = Q[k] / (double)pieces;
    else
      memcpy(Qk, Q, sizeof(double) * n * n);
    for (k = 0; k < pieces; ++k) {
      int dst = src == a ? b : a, prior = src;
      int ok = predict_once(f, src, dst, u, p, piece, Qk);
      if (!ok && pieces == 1) { /* maybe only a covariance to repair */
        prior = repaired(f, src, b);
        ok = prior >= 0 && predict_once(f, prior, dst, u, p, piece, Qk);
        repairs = ok;
      }
      if (!ok || abyssal_grew_beyond(n, limit, PS(f, prior), PS(f, dst), Qk)) {
        stable = 0;
        break;
      }
      src = dst;
    }
    if (stable) {
      out->set = src;
      out->repairs += repairs;
      if (pieces == 1) {
        out->checked_dt = dt;
      } else {
        if (!known_dt) {
          out->cache_dt = dt;
          out->cache_pieces = pieces;
        }
        out->substeps += 1;
      }
      return ABYSSAL_OK;
    }
  }
  return known_dt ? ABYSSAL_E_UNSTABLE_INPUT : ABYSSAL_E_UNSTABLE;
}

/* The update of the prior in buffer set `src` (the state, or a prediction) with the present entries of z. */
static int update_into(abyssal_kalman* f, int src, const double* z, const unsigned char* mask, const double* p,
                       pending* out) {
  int c = f->current, m = f->m, dst, spare, prior = src, rb = f->reported == 0 ? 1 : 0, round, verdict, dof, i;
  unsigned char *present = BYTES(f, f->present), *gated = BYTES(f, f->gated), *present0 = BYTES(f, f->present0);
  double *z0 = DOUBLES(f, f->z0), *maskd = DOUBLES(f, f->mask), nis = INFINITY;
  abyssal_gate* gate = (abyssal_gate*)(void*)((char*)f + f->gate);
  abyssal_gate* copy = (abyssal_gate*)(void*)((char*)f + f->gate_copy);
  for (dof = 0, i = 0; i < m; ++i) {
    present[i] = (unsigned char)((!mask || mask[i]) && !isnan(z[i]));
    present0[i] = present[i];
    gated[i] = 0;
    dof += present[i];
  }
  out->set = src;
  if (dof == 0) return ABYSSAL_OK; /* no measurement: nothing to update, nothing to count */
  dst = src == c ? (c + 1) % 3 : 3 - c - src;
  spare = 3 - src - dst;
  verdict = ABYSSAL_GATE_REJECT;
  for (round = 0; round < 2; ++round) {
    for (i = 0; i < m; ++i) {
      z0[i] = present[i] ? z[i] : 0.0;
      maskd[i] = present[i];
    }
    if (!update_once(f, prior, dst, p, rb)) {
      prior = repaired(f, prior, spare);
      if (prior < 0) return ABYSSAL_E_STATE;
      out->repairs += 1;
      if (!update_once(f, prior, dst, p, rb)) return ABYSSAL_E_DIVERGED;
    }
    verdict = abyssal_gate_judge(gate, round, DOUBLES(f, f->innovation[rb]), DOUBLES(f, f->S[rb]), present, gated,
                                 &nis, DOUBLES(f, f->scratch));
    if (verdict != ABYSSAL_GATE_RETRY) break;
  }
  memcpy(copy, gate, (size_t)gate->bytes);
  out->noted = 1;
  out->inflate = abyssal_gate_note(copy, gated, present0);
  if (verdict == ABYSSAL_GATE_ACCEPT) {
    out->set = dst;
    out->updated = 1;
    out->reported = rb;
    out->nis = nis;
    for (out->nis_dof = 0, i = 0; i < m; ++i) out->nis_dof += present[i];
  } else {
    out->set = prior;
  }
  return ABYSSAL_OK;
}

static void commit(abyssal_kalman* f, const pending* pd) {
  f->current = pd->set;
  f->repairs += pd->repairs;
  f->substeps += pd->substeps;
  if (pd->checked_dt > f->checked_dt) f->checked_dt = pd->checked_dt;
  if (pd->cache_pieces > 0) {
    int k, slot = -1;
    for (k = 0; k < DT_CACHE; ++k)
      if (f->cache_pieces[k] > 0 && f->cache_dt[k] == pd->cache_dt) slot = k;
    if (slot < 0) {
      slot = (int)(f->cache_next % DT_CACHE);
      f->cache_next += 1;
    }
    f->cache_dt[slot] = pd->cache_dt;
    f->cache_pieces[slot] = pd->cache_pieces;
  }
  if (pd->updated) {
    f->reported = pd->reported;
    f->nis = pd->nis;
    f->nis_dof = pd->nis_dof;
  }
  if (pd->noted) {
    abyssal_gate* gate = (abyssal_gate*)(void*)((char*)f + f->gate);
    memcpy(gate, (char*)f + f->gate_copy, (size_t)gate->bytes);
    if (pd->inflate) {
      double* P = PS(f, f->current);
      int k;
      for (k = 0; k < f->n * f->n; ++k) P[k] *= gate->inflation;
    }
  }
}

static void begin(pending* pd, int set) {
  memset(pd, 0, sizeof *pd);
  pd->set = set;
  pd->reported = -1;
}

/* ------------------------------------------------------------------ input checks */

static int valid(const abyssal_kalman* f) { return f && f->magic == KALMAN_MAGIC; }

static int check_inputs(const abyssal_kalman* f, const double* u, const double* dt, const double* p) {
  if (u && (f->n_u > 0) && !abyssal_all_finite(f->n_u, u)) return ABYSSAL_E_U;
  if (!u && f->n_u > 0 && dt) return ABYSSAL_E_U;
  if (dt && !(*dt > 0.0 && *dt < INFINITY)) return ABYSSAL_E_DT;
  if (p && !abyssal_all_finite(f->n_p, p)) return ABYSSAL_E_P;
  return ABYSSAL_OK;
}

static int check_z(const abyssal_kalman* f, const double* z, const unsigned char* mask) {
  int i;
  for (i = 0; i < f->m; ++i)
    if ((!mask || mask[i]) && isinf(z[i])) return ABYSSAL_E_Z;
  return ABYSSAL_OK;
}

/* ------------------------------------------------------------------ the public calls */

int abyssal_kalman_step(abyssal_kalman* f, const double* u, double dt, const double* z, const unsigned char* mask,
                        const double* p) {
  pending pd;
  int rc;
  if (!valid(f)) return ABYSSAL_E_MEMORY;
  rc = check_inputs(f, u, &dt, p);
  if (rc == ABYSSAL_OK && z) rc = check_z(f, z, mask);
  if (rc != ABYSSAL_OK) return rc;
  if (!p) p = f->model->p_default;
  begin(&pd, f->current);
  rc = predict_into(f, u, p, dt, &pd);
  if (rc == ABYSSAL_OK && z) rc = update_into(f, pd.set, z, mask, p, &pd);
  if (rc != ABYSSAL_OK) return rc;
  commit(f, &pd);
  return pd.updated ? ABYSSAL_UPDATED : ABYSSAL_OK;
}

int abyssal_kalman_predict(abyssal_kalman* f, const double* u, double dt, const double* p) {
  return abyssal_kalman_step(f, u, dt, 0, 0, p);
}

int abyssal_kalman_update(abyssal_kalman* f, const double* z, const unsigned char* mask, const double* p) {
  pending pd;
  int rc;
  if (!valid(f)) return ABYSSAL_E_MEMORY;
  rc = check_inputs(f, 0, 0, p);
  if (rc == ABYSSAL_OK && z) rc = check_z(f, z, mask);
  if (rc != ABYSSAL_OK || !z) return rc;
  if (!p) p = f->model->p_default;
  begin(&pd, f->current);
  rc = update_into(f, f->current, z, mask, p, &pd);
  if (rc != ABYSSAL_OK) return rc;
  commit(f, &pd);
  return pd.updated ? ABYSSAL_UPDATED : ABYSSAL_OK;
}

/* ------------------------------------------------------------------ construction and state */

static int covariance_code(const abyssal_kalman* f, int n, const double* A, int definite, int code) {
  if (!A || abyssal_covariance_problem(n, A, definite, DOUBLES(f, f->scratch)) != 0) return code;
  return ABYSSAL_OK;
}

int abyssal_kalman_init(void* memory, size_t bytes, const abyssal_model* model, const abyssal_kalman_options* options,
                        const double* x0, const double* P0, const double* Q, const double* R, abyssal_kalman** filter) {
  abyssal_kalman* f = (abyssal_kalman*)memory;
  size_t size;
  int rc, k;
  if (filter) *filter = 0;
  rc = abyssal_kalman_check_options(model, options);
  if (rc != ABYSSAL_OK) return rc;
  size = abyssal_kalman_work_size(model, options);
  if (!memory || ((size_t)memory & 7u) || bytes < size) return ABYSSAL_E_MEMORY;
  memset(memory, 0, size);
  f->model = model;
  f->options = *options;
  lay_out(f, model, options);
  if (!x0 || !abyssal_all_finite(f->n, x0)) rc = ABYSSAL_E_X0;
  if (rc == ABYSSAL_OK) rc = covariance_code(f, f->n, P0, 0, ABYSSAL_E_P0);
  if (rc == ABYSSAL_OK) rc = covariance_code(f, f->n, Q, 0, ABYSSAL_E_Q);
  if (rc == ABYSSAL_OK) rc = covariance_code(f, f->m, R, 1, ABYSSAL_E_R);
  if (rc == ABYSSAL_OK &&
      abyssal_gate_init((char*)f + f->gate, abyssal_gate_size(f->m), f->m, options->gate_probability,
                        options->gate_patience, options->gate_inflation, 0) != 0)
    rc = ABYSSAL_E_GATE;
  if (rc != ABYSSAL_OK) {
    memset(memory, 0, sizeof(struct abyssal_kalman));
    return rc;
  }
  memcpy(XS(f, 0), x0, sizeof(double) * f->n);
  abyssal_symmetrise(f->n, P0, PS(f, 0));
  abyssal_symmetrise(f->n, Q, DOUBLES(f, f->Q));
  abyssal_symmetrise(f->m, R, DOUBLES(f, f->R));
  for (k = 0; k < f->m * f->m; k += f->m + 1) DOUBLES(f, f->S[0])[k] = DOUBLES(f, f->S[1])[k] = 1.0;
  f->abk[0] = options->alpha;
  f->abk[1] = options->beta;
  f->abk[2] = options->kappa;
  f->robust = options->filter == ABYSSAL_HUBER_UKF ? options->gamma : options->sigma;
  if (f->points > 0) { /* the rule's weights, once: they depend on alpha, beta, kappa only */
    const double* args[1];
    double* res[2];
    args[0] = f->abk;
    res[0] = DOUBLES(f, f->wm);
    res[1] = DOUBLES(f, f->wc);
    evaluate(f, predict_weights(model, options->filter), args, is_unscented(options->filter) ? 1 : 0, res, 2);
    if (!abyssal_all_finite(f->points, DOUBLES(f, f->wm)) || !abyssal_all_finite(f->points, DOUBLES(f, f->wc))) {
      memset(memory, 0, sizeof(struct abyssal_kalman));
      return ABYSSAL_E_SIGMA_POINTS;
    }
  }
  f->current = 0;
  f->reported = -1;
  f->nis = NAN;
  f->magic = KALMAN_MAGIC;
  if (filter) *filter = f;
  return ABYSSAL_OK;
}

int abyssal_kalman_reset(abyssal_kalman* f, const double* x, const double* P) {
  if (!valid(f)) return ABYSSAL_E_MEMORY;
  if (!x || !abyssal_all_finite(f->n, x)) return ABYSSAL_E_X0;
  if (covariance_code(f, f->n, P, 0, ABYSSAL_E_P0) != ABYSSAL_OK) return ABYSSAL_E_P0;
  memcpy(XS(f, f->current), x, sizeof(double) * f->n);
  abyssal_symmetrise(f->n, P, PS(f, f->current));
  return ABYSSAL_OK;
}

int abyssal_kalman_set_Q(abyssal_kalman* f, const double* Q) {
  if (!valid(f)) return ABYSSAL_E_MEMORY;
  if (covariance_code(f, f->n, Q, 0, ABYSSAL_E_Q) != ABYSSAL_OK) return ABYSSAL_E_Q;
  abyssal_symmetrise(f->n, Q, DOUBLES(f, f->Q));
  return ABYSSAL_OK;
}

int abyssal_kalman_set_R(abyssal_kalman* f, const double* R) {
  if (!valid(f)) return ABYSSAL_E_MEMORY;
  if (covariance_code(f, f->m, R, 1, ABYSSAL_E_R) != ABYSSAL_OK) return ABYSSAL_E_R;
  abyssal_symmetrise(f->m, R, DOUBLES(f, f->R));
  return ABYSSAL_OK;
}

const double* abyssal_kalman_x(const abyssal_kalman* f) { return valid(f) ? XS(f, f->current) : 0; }
const double* abyssal_kalman_P(const abyssal_kalman* f) { return valid(f) ? PS(f, f->current) : 0; }
const abyssal_model* abyssal_kalman_model(const abyssal_kalman* f) { return valid(f) ? f->model : 0; }

void abyssal_kalman_get_report(const abyssal_kalman* f, abyssal_kalman_report* r) {
  const abyssal_gate* gate;
  memset(r, 0, sizeof *r);
  r->nis = NAN;
  if (!valid(f)) return;
  gate = (const abyssal_gate*)(const void*)((const char*)f + f->gate);
  if (f->reported >= 0) {
    r->innovation = DOUBLES(f, f->innovation[f->reported]);
    r->S = DOUBLES(f, f->S[f->reported]);
    r->nis = f->nis;
    r->nis_dof = f->nis_dof;
  }
  r->gated = gate->gated;
  r->inflations = gate->inflations;
  r->repairs = f->repairs;
  r->substeps = f->substeps;
}

long long abyssal_kalman_offset(const abyssal_kalman* f, int item) {
  if (!valid(f)) return -1;
  if (item >= ABYSSAL_AT_X && item < ABYSSAL_AT_X + 3) return f->x[item - ABYSSAL_AT_X];
  if (item >= ABYSSAL_AT_P && item < ABYSSAL_AT_P + 3) return f->P[item - ABYSSAL_AT_P];
  if (item >= ABYSSAL_AT_INNOVATION && item < ABYSSAL_AT_INNOVATION + 2) return f->innovation[item - ABYSSAL_AT_INNOVATION];
  if (item >= ABYSSAL_AT_S && item < ABYSSAL_AT_S + 2) return f->S[item - ABYSSAL_AT_S];
  switch (item) {
    case ABYSSAL_AT_Q: return f->Q;
    case ABYSSAL_AT_R: return f->R;
    case ABYSSAL_AT_GATE: return f->gate;
    case ABYSSAL_AT_CURRENT: return (long long)offsetof(struct abyssal_kalman, current);
    case ABYSSAL_AT_REPORTED: return (long long)offsetof(struct abyssal_kalman, reported);
    case ABYSSAL_AT_NIS: return (long long)offsetof(struct abyssal_kalman, nis);
    case ABYSSAL_AT_NIS_DOF: return (long long)offsetof(struct abyssal_kalman, nis_dof);
    case ABYSSAL_AT_REPAIRS: return (long long)offsetof(struct abyssal_kalman, repairs);
    case ABYSSAL_AT_SUBSTEPS: return (long long)offsetof(struct abyssal_kalman, substeps);
    case ABYSSAL_AT_STATE_BYTES: return f->state_bytes;
    default: return -1;
  }
}

const char* abyssal_kalman_message(int code) {
  switch (code) {
    case ABYSSAL_UPDATED: return "updated: a measurement was used";
    case ABYSSAL_OK: return "ok: predicted (no measurement entry present, or every entry gated)";
    case ABYSSAL_E_MEMORY: return "memory: NULL, not 8-byte aligned, smaller than abyssal_kalman_work_size(), or not an "
                                  "initialised filter";
    case ABYSSAL_E_MODEL: return "model: it lacks the generated functions of this filter (regenerate it with the "
                                 "filter's family)";
    case ABYSSAL_E_FILTER: return "options.filter is not an abyssal_filter";
    case ABYSSAL_E_SIGMA_POINTS: return "the sigma points need finite alpha, beta, kappa with 0 < alpha^2 (n + kappa) "
                                        "< inf";
    case ABYSSAL_E_ROBUST: return "the robust update needs sigma (MCUKF) or gamma (Huber) > 0 (inf gives the plain "
                                  "UKF update)";
    case ABYSSAL_E_GATE: return "gate options: 0 <= gate_probability < 1 (0: no gate), gate_patience >= 1 and "
                                "1 <= gate_inflation < inf are required";
    case ABYSSAL_E_SUBSTEPS: return "growth_limit > 1, max_substeps >= 1 and 0 < repair_floor < 1 are required";
    case ABYSSAL_E_X0: return "x0: not finite";
    case ABYSSAL_E_P0: return "P0: not a finite symmetric positive semi-definite matrix";
    case ABYSSAL_E_Q: return "Q: not a finite symmetric positive semi-definite matrix";
    case ABYSSAL_E_R: return "R: not a finite symmetric positive definite matrix";
    case ABYSSAL_E_U: return "u has non-finite entries";
    case ABYSSAL_E_DT: return "dt must be a positive finite number of seconds";
    case ABYSSAL_E_Z: return "z has infinite entries; use NaN for a missing entry";
    case ABYSSAL_E_P: return "p has non-finite entries";
    case ABYSSAL_E_DIVERGED: return "the generated step failed (non-finite outputs or a covariance that is not positive "
                                    "definite) even after repairing P; the filter diverged or Q, R, dt do not suit the "
                                    "model. State left unchanged.";
    case ABYSSAL_E_UNSTABLE: return "dt: the step blew up even in max_substeps substeps (the covariance grew more than "
                                    "growth_limit times in one substep, or the integration overflowed): either the "
                                    "filter diverged, or dt is beyond the model's stable range at this state. State "
                                    "left unchanged.";
    case ABYSSAL_E_STATE: return "the filter state is not finite";
    case ABYSSAL_E_UNSTABLE_INPUT: return "u or p: the predict blew up at a dt that was stable before, even in "
                                          "max_substeps substeps (the covariance grew more than growth_limit times in "
                                          "one substep, or the integration overflowed): the input drives the model out "
                                          "of its stable range at this state, or the filter diverged. State left "
                                          "unchanged.";
    default: return "unknown return code";
  }
}
