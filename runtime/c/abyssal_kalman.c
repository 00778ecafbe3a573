/* abyssal_kalman.c: the Kalman-family filter object (see abyssal_kalman.h). Hand-written C99.
 *
 * Object layout (byte offsets from its start, all 8-byte aligned; no pointers anywhere):
 *
 *   header | gate | sensors | x[4] P[4] (buffer sets) | innovation[2] S[2] | Q R wm wc | held u, p | history ring
 *   ------------------------------------------------------------------------ the committed state ends here
 *   gate copy, sensors copy | new history records | selection buffers | gains | the steps' scratch | scratch
 *
 * Transactions. The state is buffer set `current`; a call works in the other three sets and in copies of the gate
 * and sensor counters (a `work` record on the stack holds its scalars), appends the events it makes to new history
 * records in scratch, and commits in one step that cannot fail: the set, the copies, the scalars, and the new records
 * spliced into the ring. A predict ping-pongs its substeps between two free sets; an update writes the third.
 *
 * History. A ring of events (predict, sensor update, stacked update), each with its inputs (u, p, dt; z, R, the
 * sensors) and the state after it (x, P, the gate and sensor counters, and with smoothing the predict's smoother
 * gain). A late measurement restores the state of the last event at or before its stamp, splits the predict that
 * spans the stamp, and replays every later event from its recorded inputs into new records; the commit replaces
 * the ring's tail with them. So a late measurement gives what the in-order calls give.
 */
#include "abyssal_kalman.h"

#include <float.h>
#include <math.h>
#include <string.h>

#include "abyssal_kalman_covariance.h"
#include "abyssal_linalg.h"

#define KALMAN_MAGIC 0x32616d6c616b7962ULL /* "bykalma2" */
#define DT_CACHE 8
#define SETS 4
#define ROUND8(b) (((b) + 7u) & ~(size_t)7u)
#define AT(a, ld, i, j) ((a)[(i) + (j) * (ld)])

enum { EVENT_PREDICT = 1, EVENT_SENSOR = 2, EVENT_STACKED = 3, EVENT_ORIGIN = 4 };
/* the leading doubles of a history record */
enum { REC_KIND, REC_T, REC_DT, REC_SENSOR, REC_HAS_R, REC_HAS_INPUT, REC_REPAIRS, REC_SUBSTEPS, REC_HEAD };

struct abyssal_kalman {
  unsigned long long magic;
  unsigned long long model_id;
  int n, n_u, n_p, n_w, n_y, n_sensors, points, q_rows;
  abyssal_kalman_options options;
  abyssal_algebra algebra;
  /* the committed scalars */
  int current;                    /* the buffer set holding the state */
  int reported;                   /* the innovation/S buffer of the last accepted update; -1: none yet */
  int reported_rows, reported_sensor;
  int nis_dof;
  int fresh;                      /* the state came from init or reset, and no predict was committed since */
  int has_input;                  /* a predict held u and p (the held input exists) */
  int ring_head, ring_count;      /* the history ring: its oldest record and how many it holds */
  double nis;
  double t;                       /* the filter's time */
  long long repairs, substeps, inflations, late;
  double checked_dt;              /* predicts with dt up to this passed the stability check */
  double cache_dt[DT_CACHE];      /* dt -> number of pieces found stable for it (0: empty entry) */
  long long cache_pieces[DT_CACHE];
  long long cache_next;
  /* byte offsets */
  long long gate, sensors, x[SETS], P[SETS], innovation[2], S[2], Q, R, wm, wc, u_held, p_held, ring, state_bytes;
  long long gate_copy, sensors_copy, records, u_work, p_work, p_call, z_sel, R_sel, present, present0, gated, full_present,
      full_gated, nu_full, S_full, Pxz0, Pzz0, cross, G_acc, G_piece, Qk, steps, scratch, bytes;
  /* a history record's layout, in doubles from its start */
  long long rec_doubles, rec_u, rec_p, rec_z, rec_R, rec_x, rec_P, rec_gate, rec_sensors, rec_G;
};

/* What a call changes, committed at its end. */
typedef struct {
  int set;                        /* the working state's buffer set */
  double t;
  int has_input, fresh;
  long long repairs, substeps, inflations;
  double checked_dt, cache_dt;
  long long cache_pieces;
  int updated, reported_buf, reported_rows, reported_sensor, nis_dof;
  double nis;
  int keep;                       /* ring records kept (the oldest `keep`) before the new ones */
  int n_new;                      /* new records */
  int late_sensor;                /* the sensor whose late count grows (-1: none) */
  int recording;                  /* events go into new records */
  int replaying;                  /* replayed events do not touch the call's report */
} work_t;

#define DOUBLES(f, offset) ((double*)(void*)((char*)(f) + (offset)))
#define BYTES(f, offset) ((unsigned char*)(void*)((char*)(f) + (offset)))
#define XS(f, k) DOUBLES(f, (f)->x[k])
#define PS(f, k) DOUBLES(f, (f)->P[k])
#define GATE(f) ((abyssal_gate*)(void*)((char*)(f) + (f)->gate))
#define GATE_COPY(f) ((abyssal_gate*)(void*)((char*)(f) + (f)->gate_copy))

/* ------------------------------------------------------------------ options and sizes */

abyssal_kalman_options abyssal_kalman_default_options(abyssal_filter filter) {
  abyssal_kalman_options o;
  memset(&o, 0, sizeof o);
  o.filter = filter;
  o.alpha = 1.0;
  o.beta = 2.0;
  o.kappa = 0.0;
  o.sigma = 15.0;
  o.gamma = 1.345;
  o.huber_iterations = 3;
  o.gate_probability = 1e-10;
  o.gate_patience = 5;
  o.gate_inflation = 4.0;
  o.gate_max_inflations = 10;
  o.growth_limit = 1e3;
  o.max_substeps = 64;
  o.repair_floor = 1e-10;
  o.noise = ABYSSAL_NOISE_STEP;
  o.history_entries = 0;
  o.history_seconds = 2.0;
  o.smoothing = 0;
  return o;
}

static int model_usable(const abyssal_model* m) {
  int s;
  if (!m || m->version != ABYSSAL_MODEL_VERSION || m->n_x < 1 || m->n_u < 0 || m->n_p < 0 || m->n_w < 0 ||
      m->n_sensors < 1 || !m->sensors || !m->f.eval || !m->F.eval || !m->f_soa)
    return 0;
  for (s = 0; s < m->n_sensors; ++s) {
    const abyssal_sensor* k = &m->sensors[s];
    if (k->n_y < 1 || !k->h.eval || !k->H.eval || !k->h_soa || k->p_offset < 0 || k->n_q < 0 ||
        k->p_offset + k->n_q > m->n_p)
      return 0;
  }
  return 1;
}

static abyssal_algebra algebra_of(const abyssal_kalman_options* o) {
  abyssal_algebra a;
  a.filter = o->filter;
  a.alpha = o->alpha;
  a.beta = o->beta;
  a.kappa = o->kappa;
  a.sigma = o->sigma;
  a.gamma = o->gamma;
  a.huber_iterations = o->huber_iterations;
  return a;
}

int abyssal_kalman_check_options(const abyssal_model* model, const abyssal_kalman_options* o) {
  if (!model_usable(model)) return ABYSSAL_E_MODEL;
  if (!o) return ABYSSAL_E_FILTER;
  if (o->filter < ABYSSAL_EKF || o->filter > ABYSSAL_HUBER_UKF) return ABYSSAL_E_FILTER;
  if (o->filter != ABYSSAL_EKF && o->filter != ABYSSAL_CKF) {
    double c = o->alpha * o->alpha * (model->n_x + o->kappa);
    if (!isfinite(o->alpha) || !isfinite(o->beta) || !isfinite(o->kappa) || !(c > 0.0 && c < INFINITY) ||
        !isfinite((c - model->n_x) / c + 1.0 - o->alpha * o->alpha + o->beta) || !isfinite(1.0 / (2.0 * c)))
      return ABYSSAL_E_SIGMA_POINTS;
  }
  if ((o->filter == ABYSSAL_MCUKF && !(o->sigma > 0.0)) ||
      (o->filter == ABYSSAL_HUBER_UKF && (!(o->gamma > 0.0) || o->huber_iterations < 1)))
    return ABYSSAL_E_ROBUST;
  if (!(o->gate_probability >= 0.0 && o->gate_probability < 1.0) || o->gate_patience < 1 ||
      !(o->gate_inflation >= 1.0 && o->gate_inflation < INFINITY) || o->gate_max_inflations < 0)
    return ABYSSAL_E_GATE;
  if (!(o->growth_limit > 1.0) || o->max_substeps < 1 || !(o->repair_floor > 0.0 && o->repair_floor < 1.0))
    return ABYSSAL_E_SUBSTEPS;
  if (o->noise < ABYSSAL_NOISE_STEP || o->noise > ABYSSAL_NOISE_INPUTS || o->history_entries < 0 ||
      o->history_entries > 1 << 24 || !(o->history_seconds >= 0.0 && o->history_seconds < INFINITY) ||
      (o->smoothing != 0 && o->smoothing != 1) ||
      (o->noise == ABYSSAL_NOISE_INPUTS && (model->n_w < 1 || !model->G.eval)))
    return ABYSSAL_E_OPTIONS;
  return ABYSSAL_OK;
}

/* The layout of a filter object (offsets into `f`, which may be a stack copy of the header only). */
static void lay_out(struct abyssal_kalman* f, const abyssal_model* model, const abyssal_kalman_options* o) {
  int n = model->n_x, m = model->n_y, k, cap = o->history_entries;
  size_t at = ROUND8(sizeof(struct abyssal_kalman)), gate = abyssal_gate_size(m), scratch;
  abyssal_algebra a = algebra_of(o);
  f->n = n;
  f->n_u = model->n_u;
  f->n_p = model->n_p;
  f->n_w = model->n_w;
  f->n_y = m;
  f->n_sensors = model->n_sensors;
  f->points = abyssal_sigma_points(o->filter, n);
  f->q_rows = o->noise == ABYSSAL_NOISE_INPUTS ? model->n_w : n;
  /* a history record: the head, u, p, z, R, x, P, the gate, the sensors, and the smoother gain */
  f->rec_u = REC_HEAD;
  f->rec_p = f->rec_u + f->n_u;
  f->rec_z = f->rec_p + f->n_p;
  f->rec_R = f->rec_z + m;
  f->rec_x = f->rec_R + (long long)m * m;
  f->rec_P = f->rec_x + n;
  f->rec_gate = f->rec_P + (long long)n * n;
  f->rec_sensors = f->rec_gate + (long long)(gate / 8);
  f->rec_G = f->rec_sensors + (long long)model->n_sensors * ABYSSAL_SENSOR_FIELDS;
  f->rec_doubles = f->rec_G + (o->smoothing ? (long long)n * n : 0);
#define TAKE(field, bytes) do { f->field = (long long)at; at += ROUND8(bytes); } while (0)
  TAKE(gate, gate);
  TAKE(sensors, sizeof(double) * (size_t)model->n_sensors * ABYSSAL_SENSOR_FIELDS);
  for (k = 0; k < SETS; ++k) TAKE(x[k], sizeof(double) * n);
  for (k = 0; k < SETS; ++k) TAKE(P[k], sizeof(double) * n * n);
  for (k = 0; k < 2; ++k) TAKE(innovation[k], sizeof(double) * m);
  for (k = 0; k < 2; ++k) TAKE(S[k], sizeof(double) * m * m);
  TAKE(Q, sizeof(double) * f->q_rows * f->q_rows);
  TAKE(R, sizeof(double) * m * m);
  TAKE(wm, sizeof(double) * f->points);
  TAKE(wc, sizeof(double) * f->points);
  TAKE(u_held, sizeof(double) * (f->n_u + 1));
  TAKE(p_held, sizeof(double) * (f->n_p + 1));
  TAKE(ring, sizeof(double) * (size_t)cap * (size_t)f->rec_doubles);
  f->state_bytes = (long long)at;
  TAKE(gate_copy, gate);
  TAKE(sensors_copy, sizeof(double) * (size_t)model->n_sensors * ABYSSAL_SENSOR_FIELDS);
  TAKE(records, sizeof(double) * (size_t)(cap > 0 ? cap + 3 : 0) * (size_t)f->rec_doubles);
  TAKE(u_work, sizeof(double) * (f->n_u + 1));
  TAKE(p_work, sizeof(double) * (f->n_p + 1));
  TAKE(p_call, sizeof(double) * (f->n_p + 1));
  TAKE(z_sel, sizeof(double) * m);
  TAKE(R_sel, sizeof(double) * m * m);
  TAKE(present, m);
  TAKE(present0, m);
  TAKE(gated, m);
  TAKE(full_present, m);
  TAKE(full_gated, m);
  TAKE(nu_full, sizeof(double) * m);
  TAKE(S_full, sizeof(double) * m * m);
  TAKE(Pxz0, sizeof(double) * n * m);
  TAKE(Pzz0, sizeof(double) * m * m);
  TAKE(cross, sizeof(double) * n * n);
  TAKE(G_acc, sizeof(double) * n * n);
  TAKE(G_piece, sizeof(double) * n * n);
  TAKE(Qk, sizeof(double) * n * n);
  TAKE(steps, abyssal_steps_scratch_bytes(model, &a, m));
  /* the largest user: the repair (3 n^2 + n, and its output n^2), the gate's embedding (3 m^2 + 3 m), the inflation
   * (2 m^2 + m n + n^2 + m), the noise inputs' G Q G^T (2 n n_w), the smoother gain (2 n^2) */
  scratch = 4 * (size_t)n * n + n;
  if (3 * (size_t)m * m + 3 * (size_t)m > scratch) scratch = 3 * (size_t)m * m + 3 * (size_t)m;
  if (2 * (size_t)m * m + (size_t)m * n + (size_t)n * n + m > scratch) scratch = 2 * (size_t)m * m + (size_t)m * n + (size_t)n * n + m;
  if (2 * (size_t)n * model->n_w > scratch) scratch = 2 * (size_t)n * model->n_w;
  TAKE(scratch, sizeof(double) * scratch);
#undef TAKE
  f->bytes = (long long)at;
}

size_t abyssal_kalman_work_size(const abyssal_model* model, const abyssal_kalman_options* options) {
  struct abyssal_kalman layout;
  if (abyssal_kalman_check_options(model, options) != ABYSSAL_OK) return 0;
  lay_out(&layout, model, options);
  return (size_t)layout.bytes;
}

/* ------------------------------------------------------------------ small helpers */

static int valid(const abyssal_kalman* f) { return f && f->magic == KALMAN_MAGIC; }

/* ABYSSAL_OK when `model` is the filter's model. */
static int check_model(const abyssal_kalman* f, const abyssal_model* model) {
  if (!valid(f)) return ABYSSAL_E_MEMORY;
  if (!model || model->version != ABYSSAL_MODEL_VERSION || model->id != f->model_id || model->n_x != f->n ||
      model->n_u != f->n_u || model->n_p != f->n_p || model->n_y != f->n_y || model->n_sensors != f->n_sensors ||
      model->n_w != f->n_w)
    return ABYSSAL_E_MODEL;
  return ABYSSAL_OK;
}

static double* record_at(const abyssal_kalman* f, int index) { /* index 0: the oldest in the ring */
  int slot = (f->ring_head + index) % f->options.history_entries;
  return DOUBLES(f, f->ring) + (size_t)slot * (size_t)f->rec_doubles;
}

static double* new_record(const abyssal_kalman* f, int k) {
  return DOUBLES(f, f->records) + (size_t)k * (size_t)f->rec_doubles;
}

static int other_set(int a, int b, int c) { /* a buffer set that is none of a, b, c (c may repeat a or b) */
  int k;
  for (k = 0; k < SETS; ++k)
    if (k != a && k != b && k != c) return k;
  return -1;
}

/* ------------------------------------------------------------------ repair and growth */

/* The covariance of set src repaired into set dst (x copied). 0 when the state is not finite. */
static int repair_into(abyssal_kalman* f, int src, int dst) {
  int n = f->n;
  double* scratch = DOUBLES(f, f->scratch);
  double* out = scratch + 3 * n * n + n;
  if (!abyssal_all_finite(n, XS(f, src)) ||
      abyssal_repair_covariance(n, PS(f, src), f->q_rows == n ? DOUBLES(f, f->Q) : PS(f, src), f->options.repair_floor,
                                out, scratch) != 0)
    return 0;
  if (src != dst) memcpy(XS(f, dst), XS(f, src), sizeof(double) * n);
  memcpy(PS(f, dst), out, sizeof(double) * n * n);
  return 1;
}

/* Whether P is numerically positive definite (its guarded Cholesky factor passes). */
static int positive_definite(abyssal_kalman* f, const double* P) {
  double* L = DOUBLES(f, f->scratch);
  return abyssal_cholesky(f->n, P, L);
}

/* ------------------------------------------------------------------ the predict */

/* The process noise of one piece of length `piece` (out of a predict call of length dt) into Qk. 0 when it is not
 * finite (inputs noise: G not finite). */
static int piece_noise(abyssal_kalman* f, const abyssal_model* model, int src, const double* u, const double* p,
                       double dt, double piece, double* Qk) {
  int n = f->n, k;
  const double* Q = DOUBLES(f, f->Q);
  if (f->options.noise == ABYSSAL_NOISE_STEP) {
    if (piece == dt) memcpy(Qk, Q, sizeof(double) * n * n);
    else for (k = 0; k < n * n; ++k) Qk[k] = Q[k] * (piece / dt);
  } else if (f->options.noise == ABYSSAL_NOISE_RATE) {
    for (k = 0; k < n * n; ++k) Qk[k] = Q[k] * piece;
  } else { /* G (Qw / piece) G^T */
    int nw = f->n_w, i, j, l;
    double* G = DOUBLES(f, f->scratch);
    double* GQ = G + n * nw;
    if (!abyssal_noise_jacobian(model, &f->algebra, XS(f, src), u, p, piece, G, DOUBLES(f, f->steps))) return 0;
    for (j = 0; j < nw; ++j)
      for (i = 0; i < n; ++i) {
        double v = 0.0;
        for (l = 0; l < nw; ++l) v += AT(G, n, i, l) * AT(Q, nw, l, j);
        AT(GQ, n, i, j) = v / piece;
      }
    for (j = 0; j < n; ++j)
      for (i = 0; i <= j; ++i) {
        double v = 0.0;
        for (l = 0; l < nw; ++l) v += AT(GQ, n, i, l) * AT(G, n, j, l);
        AT(Qk, n, i, j) = v;
        AT(Qk, n, j, i) = v;
      }
  }
  return abyssal_all_finite(n * n, Qk);
}

static int predict_piece(abyssal_kalman* f, const abyssal_model* model, int src, int dst, const double* u,
                         const double* p, double piece, const double* Qk, double* cross) {
  return abyssal_predict_gaussian(model, &f->algebra, DOUBLES(f, f->wm), DOUBLES(f, f->wc), XS(f, src), PS(f, src), u,
                                  p, piece, Qk, XS(f, dst), PS(f, dst), cross, DOUBLES(f, f->steps));
}

/* G = C P_pred^-1 (the smoother's gain of one piece) into out; 0 when it is not finite. A singular P_pred (a state
 * known exactly: zero P0 and Q along it) is not a failure: the guarded factor's tiny pivots meet zero entries of C
 * along those directions (C = P F^T is zero there too), so the gain is zero along them: nothing to smooth. */
static int smoother_gain(abyssal_kalman* f, const double* C, const double* P_pred, double* out) {
  int n = f->n, i, j;
  double* L = DOUBLES(f, f->scratch);
  double* B = L + n * n;
  (void)abyssal_cholesky(n, P_pred, L);
  for (j = 0; j < n; ++j) /* B = C^T, then G^T = P^-1 C^T */
    for (i = 0; i < n; ++i) AT(B, n, i, j) = AT(C, n, j, i);
  abyssal_solve_lower(n, L, n, B);
  abyssal_solve_lower_transposed(n, L, n, B);
  for (j = 0; j < n; ++j)
    for (i = 0; i < n; ++i) AT(out, n, i, j) = AT(B, n, j, i);
  return abyssal_all_finite(n * n, out);
}

/* G_acc <- G_acc G_piece (the gain over several pieces is the product of the pieces' gains). */
static void chain_gain(abyssal_kalman* f, double* acc, const double* piece) {
  int n = f->n, i, j, k;
  double* tmp = DOUBLES(f, f->scratch);
  for (j = 0; j < n; ++j)
    for (i = 0; i < n; ++i) {
      double v = 0.0;
      for (k = 0; k < n; ++k) v += AT(acc, n, i, k) * AT(piece, n, k, j);
      AT(tmp, n, i, j) = v;
    }
  memcpy(acc, tmp, sizeof(double) * n * n);
}

static long long cached_pieces(const abyssal_kalman* f, double dt) {
  int k;
  for (k = 0; k < DT_CACHE; ++k)
    if (f->cache_pieces[k] > 0 && f->cache_dt[k] == dt) return f->cache_pieces[k];
  return 1;
}

/* Predict the working state over dt with u, p; the result becomes the working set. */
static int predict_event(abyssal_kalman* f, const abyssal_model* model, work_t* w, const double* u, const double* p,
                         double dt) {
  const int c = f->current, src0 = w->set, n = f->n, smoothing = f->options.smoothing && w->recording;
  const int a = other_set(c, src0, -1), b = other_set(c, src0, a);
  const double limit = f->options.growth_limit;
  double* Qk = DOUBLES(f, f->Qk);
  double* cross = smoothing ? DOUBLES(f, f->cross) : 0;
  double* Gacc = DOUBLES(f, f->G_acc);
  long long pieces;
  int known_dt = dt <= f->checked_dt;
  if (known_dt) {
    int prior = src0, ok, repaired = 0;
    ok = piece_noise(f, model, src0, u, p, dt, dt, Qk) && predict_piece(f, model, src0, a, u, p, dt, Qk, cross);
    if (!ok) { /* maybe only a covariance to repair */
      if (!repair_into(f, src0, b)) return ABYSSAL_E_STATE;
      prior = b;
      ok = piece_noise(f, model, b, u, p, dt, dt, Qk) && predict_piece(f, model, b, a, u, p, dt, Qk, cross);
      repaired = 1;
    }
    if (ok && !abyssal_grew_beyond(n, limit, PS(f, prior), PS(f, a), Qk) &&
        (!smoothing || smoother_gain(f, cross, PS(f, a), Gacc))) {
      w->set = a;
      w->repairs += repaired;
      return ABYSSAL_OK;
    }
    /* it blew up at this state and input (a glitch of u accepted as finite): subdivided like a long dt, but not
     * remembered for this dt */
    pieces = 2;
  } else {
    pieces = cached_pieces(f, dt);
  }
  for (; pieces <= f->options.max_substeps; pieces *= 2) {
    double piece = dt / (double)pieces;
    int src = src0, stable = 1, repaired = 0, k;
    for (k = 0; k < pieces; ++k) {
      int dst = src == a ? b : a, prior = src;
      int ok = piece_noise(f, model, src, u, p, dt, piece, Qk) && predict_piece(f, model, src, dst, u, p, piece, Qk, cross);
      if (!ok && pieces == 1) { /* maybe only a covariance to repair: into dst, then predict dst -> the other */
        if (!repair_into(f, src, dst)) return ABYSSAL_E_STATE;
        prior = dst;
        dst = dst == a ? b : a;
        ok = piece_noise(f, model, prior, u, p, dt, piece, Qk) &&
             predict_piece(f, model, prior, dst, u, p, piece, Qk, cross);
        repaired = ok;
      }
      if (!ok || abyssal_grew_beyond(n, limit, PS(f, prior), PS(f, dst), Qk)) {
        stable = 0;
        break;
      }
      if (smoothing) {
        if (k == 0) {
          if (!smoother_gain(f, cross, PS(f, dst), Gacc)) { stable = 0; break; }
        } else {
          double* Gp = DOUBLES(f, f->G_piece);
          if (!smoother_gain(f, cross, PS(f, dst), Gp)) { stable = 0; break; }
          chain_gain(f, Gacc, Gp);
        }
      }
      src = dst;
    }
    if (stable) {
      w->set = src;
      w->repairs += repaired;
      if (pieces == 1) {
        if (dt > w->checked_dt) w->checked_dt = dt;
      } else {
        if (!known_dt) {
          w->cache_dt = dt;
          w->cache_pieces = pieces;
        }
        w->substeps += 1;
      }
      return ABYSSAL_OK;
    }
  }
  if (w->fresh) return ABYSSAL_E_UNSTABLE_STATE;
  return known_dt ? ABYSSAL_E_UNSTABLE_INPUT : ABYSSAL_E_UNSTABLE;
}

/* ------------------------------------------------------------------ the update */

/* P += (f - 1) Pxz_g Pzz_g^-1 Pxz_g^T over the rows g (flags, rows of the selection); 0 when Pzz_g is not
 * positive definite or the result is not finite (P is then unchanged). */
static int inflate_along(abyssal_kalman* f, double* P, const unsigned char* g, int rows, const double* Pxz,
                         const double* Pzz, double factor) {
  int n = f->n, m = 0, i, j, k, *idx;
  double* scratch = DOUBLES(f, f->scratch);
  double *Pg, *L, *W, *out;
  idx = (int*)(void*)scratch; /* rows ints in the first rows doubles */
  scratch += rows;
  for (i = 0; i < rows; ++i)
    if (g[i]) idx[m++] = i;
  if (m == 0) return 0;
  Pg = scratch;
  L = Pg + m * m;
  W = L + m * m;
  out = W + m * n;
  for (j = 0; j < m; ++j)
    for (i = 0; i < m; ++i) AT(Pg, m, i, j) = AT(Pzz, rows, idx[i], idx[j]);
  if (!abyssal_cholesky(m, Pg, L)) return 0;
  for (j = 0; j < n; ++j) /* W = L^-1 Pxz_g^T */
    for (i = 0; i < m; ++i) AT(W, m, i, j) = AT(Pxz, n, j, idx[i]);
  abyssal_solve_lower(m, L, n, W);
  for (j = 0; j < n; ++j)
    for (i = 0; i <= j; ++i) {
      double v = AT(P, n, i, j) + (factor - 1.0) * abyssal_dot(m, W + (size_t)i * m, W + (size_t)j * m);
      AT(out, n, i, j) = v;
      AT(out, n, j, i) = v;
    }
  for (k = 0; k < n * n; ++k)
    if (!isfinite(out[k])) return 0;
  memcpy(P, out, sizeof(double) * n * n);
  return 1;
}

/* P *= factor; 0 (P unchanged) when that is not finite. */
static int inflate_whole(abyssal_kalman* f, double* P, double factor) {
  int k, n2 = f->n * f->n;
  for (k = 0; k < n2; ++k)
    if (!isfinite(P[k] * factor)) return 0;
  for (k = 0; k < n2; ++k) P[k] *= factor;
  return 1;
}

/* Update the working state with a selection's measurement (z and R in the selection's layout, already checked;
 * present flags in f->present). The report goes to buffer rb unless replaying. */
static int update_event(abyssal_kalman* f, const abyssal_model* model, work_t* w, int sensor, const double* p) {
  const int c = f->current, src = w->set, n = f->n, n_y = f->n_y;
  int count, rows, first, first_sensor, dst, spare, prior = src, round, verdict, dof, i, k, s, rb;
  unsigned char *present = BYTES(f, f->present), *present0 = BYTES(f, f->present0), *gated = BYTES(f, f->gated);
  unsigned char *fp = BYTES(f, f->full_present), *fg = BYTES(f, f->full_gated);
  double *z = DOUBLES(f, f->z_sel), *R = DOUBLES(f, f->R_sel), *nu_full = DOUBLES(f, f->nu_full);
  double *S_full = DOUBLES(f, f->S_full), *Pxz0 = DOUBLES(f, f->Pxz0), *Pzz0 = DOUBLES(f, f->Pzz0);
  double *sensors = DOUBLES(f, f->sensors_copy), nis = INFINITY, *innovation, *S;
  abyssal_gate* gate = GATE_COPY(f);
  first_sensor = sensor >= 0 ? sensor : 0;
  count = sensor >= 0 ? 1 : f->n_sensors;
  rows = sensor >= 0 ? model->sensors[sensor].n_y : n_y;
  first = sensor >= 0 ? model->sensors[sensor].offset : 0;
  rb = w->replaying ? -1 : (f->reported == 0 ? 1 : 0);
  /* a replayed update computes its innovation in the other report buffer's place only if it is not the call's; use
   * S_full's tail space: nu_full / S_full are free until the gate embeds them */
  innovation = rb >= 0 ? DOUBLES(f, f->innovation[rb]) : nu_full;
  S = rb >= 0 ? DOUBLES(f, f->S[rb]) : S_full;
  for (dof = 0, i = 0; i < rows; ++i) {
    present0[i] = present[i];
    gated[i] = 0;
    dof += present[i];
  }
  if (dof == 0) return ABYSSAL_OK; /* nothing to update, nothing to count */
  dst = other_set(c, src, -1);
  spare = other_set(c, src, dst);
  verdict = ABYSSAL_GATE_REJECT;
  for (round = 0; round < 2; ++round) {
    int ok = abyssal_update_gaussian(model, &f->algebra, DOUBLES(f, f->wm), DOUBLES(f, f->wc), first_sensor, count,
                                     XS(f, prior), PS(f, prior), z, present, p, R, XS(f, dst), PS(f, dst), innovation, S,
                                     round == 0 ? Pxz0 : 0, round == 0 ? Pzz0 : 0, DOUBLES(f, f->steps));
    if (!ok) {
      if (!repair_into(f, prior, spare)) return ABYSSAL_E_STATE;
      prior = spare;
      w->repairs += 1;
      ok = abyssal_update_gaussian(model, &f->algebra, DOUBLES(f, f->wm), DOUBLES(f, f->wc), first_sensor, count,
                                   XS(f, prior), PS(f, prior), z, present, p, R, XS(f, dst), PS(f, dst), innovation, S,
                                   round == 0 ? Pxz0 : 0, round == 0 ? Pzz0 : 0, DOUBLES(f, f->steps));
      if (!ok) return ABYSSAL_E_DIVERGED;
    }
    /* the gate works on the stacked layout: embed the selection's rows */
    for (i = 0; i < n_y; ++i) {
      fp[i] = 0;
      fg[i] = 0;
    }
    {
      double* nuf = DOUBLES(f, f->scratch);
      double* Sf = nuf + n_y;
      double* gs = Sf + n_y * n_y;
      int jj;
      for (i = 0; i < n_y * n_y; ++i) Sf[i] = 0.0;
      for (i = 0; i < n_y; ++i) {
        nuf[i] = 0.0;
        AT(Sf, n_y, i, i) = 1.0;
      }
      for (jj = 0; jj < rows; ++jj) {
        nuf[first + jj] = innovation[jj];
        fp[first + jj] = present[jj];
        for (i = 0; i < rows; ++i) AT(Sf, n_y, first + i, first + jj) = AT(S, rows, i, jj);
      }
      verdict = abyssal_gate_judge(gate, round, nuf, Sf, fp, fg, &nis, gs);
      for (jj = 0; jj < rows; ++jj) {
        present[jj] = fp[first + jj];
        gated[jj] |= fg[first + jj];
      }
    }
    if (verdict != ABYSSAL_GATE_RETRY) break;
  }
  for (i = 0; i < n_y; ++i) { /* the gate's streaks: the selection's entries */
    fp[i] = 0;
    fg[i] = 0;
  }
  for (i = 0; i < rows; ++i) {
    fp[first + i] = present0[i];
    fg[first + i] = gated[i];
  }
  abyssal_gate_note(gate, fg, fp);
  if (verdict == ABYSSAL_GATE_ACCEPT) {
    int used = 0;
    for (i = 0; i < rows; ++i) used += present[i];
    w->set = dst;
    if (!positive_definite(f, PS(f, dst))) { /* a tiny R can leave P - K S K^T indefinite: repaired now */
      if (!repair_into(f, dst, spare)) return ABYSSAL_E_DIVERGED;
      w->set = spare;
      w->repairs += 1;
    }
    if (rb >= 0) {
      w->updated = 1;
      w->reported_buf = rb;
      w->reported_rows = rows;
      w->reported_sensor = sensor;
      w->nis = nis;
      w->nis_dof = used;
    }
  } else {
    w->set = prior;
  }
  /* per sensor: used / gated counts, and the bounded inflation after gate_patience gates of an entry. Which P
   * it inflates depends on who is wrong: when other entries (of any sensor) were accepted while this sensor's
   * streak ran, the filter follows them and this sensor is stuck or lost: P is inflated along its gated entries'
   * directions only (the others keep the state); when nothing was accepted during the streak, the filter itself is
   * probably wrong (a jump it cannot follow): the whole P is inflated. */
  {
    unsigned char* inflate = BYTES(f, f->full_present); /* reused: the selection rows to inflate along */
    double accepted_before = 0.0, accepted_now;
    int any = 0, whole = 0, o = 0, accepted_entries = 0;
    for (k = 0; k < f->n_sensors; ++k) accepted_before += sensors[(size_t)k * ABYSSAL_SENSOR_FIELDS + ABYSSAL_SENSOR_ACCEPTED];
    for (i = 0; i < rows; ++i) {
      inflate[i] = 0;
      accepted_entries += present[i] && !gated[i] && verdict == ABYSSAL_GATE_ACCEPT;
    }
    accepted_now = accepted_before + accepted_entries;
    for (k = first_sensor; k < first_sensor + count; ++k) {
      const abyssal_sensor* sk = &model->sensors[k];
      double* rec = sensors + (size_t)k * ABYSSAL_SENSOR_FIELDS;
      int used = 0, n_gated = 0, beyond = 0, present_k = 0, longest = 0;
      for (s = 0; s < sk->n_y; ++s) {
        int r = o + s;
        long long streak = abyssal_gate_streak(gate, sk->offset + s);
        present_k += present0[r];
        used += present[r] && !gated[r] && verdict == ABYSSAL_GATE_ACCEPT;
        n_gated += gated[r];
        if (gated[r] && streak > longest) longest = (int)streak;
        if (gated[r] && streak >= f->options.gate_patience) beyond = 1;
      }
      rec[ABYSSAL_SENSOR_ACCEPTED] += used;
      if (longest == 1) rec[ABYSSAL_SENSOR_ACCEPTED_AT_STREAK] = accepted_before; /* its streak begins */
      if (used) {
        rec[ABYSSAL_SENSOR_USED] += 1;
        if (verdict == ABYSSAL_GATE_ACCEPT) {
          rec[ABYSSAL_SENSOR_NIS] = nis;
          rec[ABYSSAL_SENSOR_NIS_DOF] = used;
        }
      }
      rec[ABYSSAL_SENSOR_GATED] += n_gated;
      if (present_k && !n_gated) { /* its present entries passed: its streak and rejection end */
        rec[ABYSSAL_SENSOR_STREAK_INFLATIONS] = 0;
        rec[ABYSSAL_SENSOR_REJECTED] = 0;
      }
      if (beyond) {
        if (rec[ABYSSAL_SENSOR_STREAK_INFLATIONS] < f->options.gate_max_inflations) {
          for (s = 0; s < sk->n_y; ++s)
            if (gated[o + s]) inflate[o + s] = 1;
          rec[ABYSSAL_SENSOR_STREAK_INFLATIONS] += 1;
          rec[ABYSSAL_SENSOR_INFLATIONS] += 1;
          any = 1;
          whole |= !(accepted_now > rec[ABYSSAL_SENSOR_ACCEPTED_AT_STREAK]);
        } else {
          rec[ABYSSAL_SENSOR_REJECTED] = 1;
        }
      }
      o += sk->n_y;
    }
    if (any && f->options.gate_inflation > 1.0) {
      int target = w->set;
      if (target == c || target == src) { /* never write the committed set or the prior: copy into a free set */
        int free_set = other_set(c, src, -1);
        if (free_set == target) free_set = other_set(c, src, target);
        memcpy(XS(f, free_set), XS(f, target), sizeof(double) * n);
        memcpy(PS(f, free_set), PS(f, target), sizeof(double) * n * n);
        target = free_set;
      }
      if (whole ? inflate_whole(f, PS(f, target), f->options.gate_inflation)
                : inflate_along(f, PS(f, target), inflate, rows, Pxz0, Pzz0, f->options.gate_inflation)) {
        w->set = target;
        w->inflations += 1;
      } else {
        w->set = target; /* the copy equals the result: nothing inflated */
      }
    }
  }
  return verdict == ABYSSAL_GATE_ACCEPT ? ABYSSAL_UPDATED : ABYSSAL_OK;
}

/* ------------------------------------------------------------------ history records */

static void write_record(abyssal_kalman* f, double* rec, int kind, double t, double dt, int sensor, int has_R,
                         const double* u, const double* p, const double* z, const double* R, int rows,
                         const work_t* w) {
  int n = f->n;
  rec[REC_KIND] = kind;
  rec[REC_T] = t;
  rec[REC_DT] = dt;
  rec[REC_SENSOR] = sensor;
  rec[REC_HAS_R] = has_R;
  rec[REC_HAS_INPUT] = w->has_input;
  rec[REC_REPAIRS] = (double)w->repairs;
  rec[REC_SUBSTEPS] = (double)w->substeps;
  if (f->n_u) memcpy(rec + f->rec_u, u, sizeof(double) * f->n_u);
  if (f->n_p) memcpy(rec + f->rec_p, p, sizeof(double) * f->n_p);
  if (z) memcpy(rec + f->rec_z, z, sizeof(double) * rows);
  if (R) memcpy(rec + f->rec_R, R, sizeof(double) * rows * rows);
  memcpy(rec + f->rec_x, XS(f, w->set), sizeof(double) * n);
  memcpy(rec + f->rec_P, PS(f, w->set), sizeof(double) * n * n);
  memcpy(rec + f->rec_gate, GATE_COPY(f), (size_t)GATE_COPY(f)->bytes);
  memcpy(rec + f->rec_sensors, DOUBLES(f, f->sensors_copy), sizeof(double) * f->n_sensors * ABYSSAL_SENSOR_FIELDS);
  if (f->options.smoothing) {
    if (kind == EVENT_PREDICT) memcpy(rec + f->rec_G, DOUBLES(f, f->G_acc), sizeof(double) * n * n);
    else memset(rec + f->rec_G, 0, sizeof(double) * n * n);
  }
}

static double* append_record(abyssal_kalman* f, work_t* w) {
  if (!w->recording) return 0;
  return new_record(f, w->n_new++);
}

/* ------------------------------------------------------------------ the events of a call */

/* The held input (u, p) of the working state into u_work / p_work (used by a predict to a measurement's stamp). */

static int do_predict(abyssal_kalman* f, const abyssal_model* model, work_t* w, const double* u, const double* p,
                      double dt) {
  int rc = predict_event(f, model, w, u, p, dt);
  double* rec;
  if (rc != ABYSSAL_OK) return rc;
  w->t += dt;
  w->fresh = 0;
  w->has_input = 1;
  if (u != DOUBLES(f, f->u_work) && f->n_u) memcpy(DOUBLES(f, f->u_work), u, sizeof(double) * f->n_u);
  if (p != DOUBLES(f, f->p_work) && f->n_p) memcpy(DOUBLES(f, f->p_work), p, sizeof(double) * f->n_p);
  rec = append_record(f, w);
  if (rec) write_record(f, rec, EVENT_PREDICT, w->t, dt, -1, 0, u, p, 0, 0, 0, w);
  return ABYSSAL_OK;
}

/* An update event of the selection `sensor` (-1: stacked) from z (rows; NaN missing), mask (may be NULL), R (rows x
 * rows), p (the model's parameters with the sensor's own). */
static int do_update(abyssal_kalman* f, const abyssal_model* model, work_t* w, int sensor, const double* z,
                     const unsigned char* mask, const double* R, int has_R, const double* p) {
  int rows = sensor >= 0 ? model->sensors[sensor].n_y : f->n_y, i, rc;
  unsigned char* present = BYTES(f, f->present);
  double *zs = DOUBLES(f, f->z_sel), *Rs = DOUBLES(f, f->R_sel), *rec;
  for (i = 0; i < rows; ++i) {
    present[i] = (unsigned char)((!mask || mask[i]) && !isnan(z[i]));
    zs[i] = present[i] ? z[i] : NAN;
  }
  if (zs != R) memcpy(Rs, R, sizeof(double) * rows * rows);
  rc = update_event(f, model, w, sensor, p);
  if (rc < 0) return rc;
  rec = append_record(f, w);
  if (rec) write_record(f, rec, sensor >= 0 ? EVENT_SENSOR : EVENT_STACKED, w->t, 0.0, sensor, has_R,
                        DOUBLES(f, f->u_work), p, zs, Rs, rows, w);
  return rc;
}

/* The filter's R of a selection (rows x rows) into out. */
static void selection_R(const abyssal_kalman* f, const abyssal_model* model, int sensor, double* out) {
  const double* R = DOUBLES(f, f->R);
  int rows = sensor >= 0 ? model->sensors[sensor].n_y : f->n_y, first = sensor >= 0 ? model->sensors[sensor].offset : 0;
  int i, j;
  for (j = 0; j < rows; ++j)
    for (i = 0; i < rows; ++i) AT(out, rows, i, j) = AT(R, f->n_y, first + i, first + j);
}

static void begin(abyssal_kalman* f, work_t* w) {
  memset(w, 0, sizeof *w);
  w->set = f->current;
  w->t = f->t;
  w->has_input = f->has_input;
  w->fresh = f->fresh;
  w->repairs = f->repairs;
  w->substeps = f->substeps;
  w->inflations = f->inflations;
  w->checked_dt = f->checked_dt;
  w->reported_buf = -1;
  w->keep = f->ring_count;
  w->late_sensor = -1;
  w->recording = f->options.history_entries > 0;
  memcpy(GATE_COPY(f), GATE(f), (size_t)GATE(f)->bytes);
  memcpy(DOUBLES(f, f->sensors_copy), DOUBLES(f, f->sensors), sizeof(double) * f->n_sensors * ABYSSAL_SENSOR_FIELDS);
  if (f->n_u) memcpy(DOUBLES(f, f->u_work), DOUBLES(f, f->u_held), sizeof(double) * f->n_u);
  if (f->n_p) memcpy(DOUBLES(f, f->p_work), DOUBLES(f, f->p_held), sizeof(double) * f->n_p);
}

/* Drop the oldest records beyond the capacity, and those the lag no longer needs (the newest record at or before
 * t - history_seconds stays: it is the state a measurement at the lag's edge starts from). */
static void trim_history(abyssal_kalman* f) {
  int cap = f->options.history_entries;
  while (f->ring_count > cap) {
    f->ring_head = (f->ring_head + 1) % cap;
    f->ring_count -= 1;
  }
  while (f->ring_count > 1 && record_at(f, 1)[REC_T] <= f->t - f->options.history_seconds) {
    f->ring_head = (f->ring_head + 1) % cap;
    f->ring_count -= 1;
  }
}

static void commit(abyssal_kalman* f, const work_t* w) {
  int k;
  f->current = w->set;
  f->t = w->t;
  f->has_input = w->has_input;
  f->fresh = w->fresh;
  f->repairs = w->repairs;
  f->substeps = w->substeps;
  f->inflations = w->inflations;
  if (w->checked_dt > f->checked_dt) f->checked_dt = w->checked_dt;
  if (w->cache_pieces > 0) {
    int slot = -1;
    for (k = 0; k < DT_CACHE; ++k)
      if (f->cache_pieces[k] > 0 && f->cache_dt[k] == w->cache_dt) slot = k;
    if (slot < 0) {
      slot = (int)(f->cache_next % DT_CACHE);
      f->cache_next += 1;
    }
    f->cache_dt[slot] = w->cache_dt;
    f->cache_pieces[slot] = w->cache_pieces;
  }
  if (w->updated) {
    f->reported = w->reported_buf;
    f->reported_rows = w->reported_rows;
    f->reported_sensor = w->reported_sensor;
    f->nis = w->nis;
    f->nis_dof = w->nis_dof;
  }
  memcpy(GATE(f), GATE_COPY(f), (size_t)GATE(f)->bytes);
  memcpy(DOUBLES(f, f->sensors), DOUBLES(f, f->sensors_copy), sizeof(double) * f->n_sensors * ABYSSAL_SENSOR_FIELDS);
  if (f->n_u) memcpy(DOUBLES(f, f->u_held), DOUBLES(f, f->u_work), sizeof(double) * f->n_u);
  if (f->n_p) memcpy(DOUBLES(f, f->p_held), DOUBLES(f, f->p_work), sizeof(double) * f->n_p);
  if (w->late_sensor >= 0) f->late += 1;
  if (f->options.history_entries > 0) { /* the ring keeps its oldest `keep` records; the new ones follow */
    int cap = f->options.history_entries;
    f->ring_count = w->keep;
    for (k = 0; k < w->n_new; ++k) {
      if (f->ring_count == cap) {
        f->ring_head = (f->ring_head + 1) % cap;
        f->ring_count -= 1;
      }
      memcpy(record_at(f, f->ring_count), new_record(f, k), sizeof(double) * (size_t)f->rec_doubles);
      f->ring_count += 1;
    }
    trim_history(f);
  }
}

/* ------------------------------------------------------------------ input checks */

static int check_inputs(const abyssal_kalman* f, const double* u, const double* dt, const double* p) {
  if (u && f->n_u > 0 && !abyssal_all_finite(f->n_u, u)) return ABYSSAL_E_U;
  if (!u && f->n_u > 0 && dt) return ABYSSAL_E_U;
  if (dt && !(*dt > 0.0 && *dt < INFINITY)) return ABYSSAL_E_DT;
  if (p && !abyssal_all_finite(f->n_p, p)) return ABYSSAL_E_P;
  return ABYSSAL_OK;
}

static int check_z(int rows, const double* z, const unsigned char* mask) {
  int i;
  for (i = 0; i < rows; ++i)
    if ((!mask || mask[i]) && isinf(z[i])) return ABYSSAL_E_Z;
  return ABYSSAL_OK;
}

/* p of a call: the given p, or the model's defaults, copied into p_call. */
static double* call_parameters(abyssal_kalman* f, const abyssal_model* model, const double* p) {
  double* out = DOUBLES(f, f->p_call);
  if (f->n_p) memcpy(out, p ? p : model->p_default, sizeof(double) * f->n_p);
  return out;
}

/* ------------------------------------------------------------------ the fixed-rate calls */

int abyssal_kalman_step(abyssal_kalman* f, const abyssal_model* model, const double* u, double dt, const double* z,
                        const unsigned char* mask, const double* p) {
  work_t w;
  int rc = check_model(f, model), i;
  if (rc != ABYSSAL_OK) return rc;
  rc = check_inputs(f, u, &dt, p);
  if (rc == ABYSSAL_OK && z) rc = check_z(f->n_y, z, mask);
  if (rc == ABYSSAL_OK && !(isfinite(f->t + dt))) rc = ABYSSAL_E_DT;
  if (rc != ABYSSAL_OK) return rc;
  p = call_parameters(f, model, p);
  begin(f, &w);
  rc = do_predict(f, model, &w, u ? u : DOUBLES(f, f->u_work), p, dt);
  if (rc == ABYSSAL_OK && z) {
    selection_R(f, model, -1, DOUBLES(f, f->R_sel));
    rc = do_update(f, model, &w, -1, z, mask, DOUBLES(f, f->R_sel), 0, p);
    if (rc >= 0)
      for (i = 0; i < f->n_sensors; ++i)
        DOUBLES(f, f->sensors_copy)[(size_t)i * ABYSSAL_SENSOR_FIELDS + ABYSSAL_SENSOR_LAST_T] = w.t;
  }
  if (rc < 0) return rc;
  commit(f, &w);
  return w.updated ? ABYSSAL_UPDATED : ABYSSAL_OK;
}

int abyssal_kalman_predict(abyssal_kalman* f, const abyssal_model* model, const double* u, double dt, const double* p) {
  return abyssal_kalman_step(f, model, u, dt, 0, 0, p);
}

int abyssal_kalman_update(abyssal_kalman* f, const abyssal_model* model, const double* z, const unsigned char* mask,
                          const double* p) {
  work_t w;
  int rc = check_model(f, model), i;
  if (rc != ABYSSAL_OK) return rc;
  rc = check_inputs(f, 0, 0, p);
  if (rc == ABYSSAL_OK && z) rc = check_z(f->n_y, z, mask);
  if (rc != ABYSSAL_OK || !z) return rc;
  p = call_parameters(f, model, p);
  begin(f, &w);
  selection_R(f, model, -1, DOUBLES(f, f->R_sel));
  rc = do_update(f, model, &w, -1, z, mask, DOUBLES(f, f->R_sel), 0, p);
  if (rc < 0) return rc;
  for (i = 0; i < f->n_sensors; ++i)
    DOUBLES(f, f->sensors_copy)[(size_t)i * ABYSSAL_SENSOR_FIELDS + ABYSSAL_SENSOR_LAST_T] = w.t;
  commit(f, &w);
  return w.updated ? ABYSSAL_UPDATED : ABYSSAL_OK;
}

int abyssal_kalman_run(abyssal_kalman* f, const abyssal_model* model, long long T, const double* U, const double* dt,
                       int dt_step, const double* Z, const double* P_rows, int p_step, double* X, double* P_out,
                       double* nis, int* dof, long long* row) {
  long long k;
  int rc = check_model(f, model);
  if (row) *row = -1;
  if (rc != ABYSSAL_OK) return rc;
  for (k = 0; k < T; ++k) {
    const double* z = Z ? Z + k * f->n_y : 0;
    const double* p = P_rows ? P_rows + k * p_step * f->n_p : 0;
    int i, any = 0;
    if (z) {
      for (i = 0; i < f->n_y; ++i) any |= !isnan(z[i]);
      if (!any) z = 0;
    }
#if defined(__GNUC__) /* this row's outputs' cache lines, for writing, while the step runs */
    if (P_out) {
      const char* row_P = (const char*)(P_out + k * f->n * f->n);
      size_t b, bytes = sizeof(double) * (size_t)f->n * (size_t)f->n;
      for (b = 0; b < bytes; b += 64) __builtin_prefetch(row_P + b, 1, 3);
    }
    if (X) __builtin_prefetch(X + k * f->n, 1, 3);
#endif
    rc = abyssal_kalman_step(f, model, U + k * f->n_u, dt[k * dt_step], z, 0, p);
    if (rc < 0) {
      if (row) *row = k;
      return rc;
    }
    if (X) memcpy(X + k * f->n, XS(f, f->current), sizeof(double) * f->n);
    if (P_out) memcpy(P_out + k * f->n * f->n, PS(f, f->current), sizeof(double) * f->n * f->n);
    if (nis) nis[k] = rc == ABYSSAL_UPDATED ? f->nis : NAN;
    if (dof) dof[k] = rc == ABYSSAL_UPDATED ? f->nis_dof : 0;
  }
  return ABYSSAL_OK;
}

/* ------------------------------------------------------------------ the stamped calls */

int abyssal_kalman_predict_to(abyssal_kalman* f, const abyssal_model* model, double t, const double* u,
                              const double* p) {
  work_t w;
  int rc = check_model(f, model);
  if (rc != ABYSSAL_OK) return rc;
  if (!isfinite(t) || t < f->t) return ABYSSAL_E_TIME;
  rc = check_inputs(f, u, 0, p);
  if (rc == ABYSSAL_OK && !u && f->n_u > 0) rc = ABYSSAL_E_U;
  if (rc != ABYSSAL_OK) return rc;
  p = call_parameters(f, model, p);
  begin(f, &w);
  if (t > f->t) {
    double dt = t - f->t;
    if (!(dt > 0.0 && dt < INFINITY)) return ABYSSAL_E_TIME;
    rc = do_predict(f, model, &w, u, p, dt);
    if (rc != ABYSSAL_OK) return rc;
    w.t = t; /* exactly the stamp (f->t + dt may round) */
    if (w.recording) new_record(f, w.n_new - 1)[REC_T] = t;
  } else { /* only the held input changes */
    if (f->n_u) memcpy(DOUBLES(f, f->u_work), u, sizeof(double) * f->n_u);
    if (f->n_p) memcpy(DOUBLES(f, f->p_work), p, sizeof(double) * f->n_p);
    w.has_input = 1;
  }
  commit(f, &w);
  return ABYSSAL_OK;
}

/* Replay the ring's records from index `from` on (their inputs; the state is the working one). */
static int replay(abyssal_kalman* f, const abyssal_model* model, work_t* w, int from) {
  int k, rc;
  for (k = from; k < f->ring_count; ++k) {
    const double* rec = record_at(f, k);
    int kind = (int)rec[REC_KIND], sensor = (int)rec[REC_SENSOR];
    if (kind == EVENT_PREDICT) {
      rc = do_predict(f, model, w, rec + f->rec_u, rec + f->rec_p, rec[REC_DT]);
      if (rc != ABYSSAL_OK) return rc;
      w->t = rec[REC_T];
      new_record(f, w->n_new - 1)[REC_T] = rec[REC_T];
    } else {
      int rows = kind == EVENT_SENSOR ? model->sensors[sensor].n_y : f->n_y;
      double* p = DOUBLES(f, f->p_call);
      if (f->n_p) memcpy(p, rec + f->rec_p, sizeof(double) * f->n_p);
      memcpy(DOUBLES(f, f->R_sel), rec + f->rec_R, sizeof(double) * rows * rows);
      rc = do_update(f, model, w, kind == EVENT_SENSOR ? sensor : -1, rec + f->rec_z, 0, DOUBLES(f, f->R_sel),
                     (int)rec[REC_HAS_R], p);
      if (rc < 0) return rc;
    }
  }
  return ABYSSAL_OK;
}

/* Load the state after ring record k into a free buffer set of the working state. */
static void restore_record(abyssal_kalman* f, work_t* w, int k) {
  const double* rec = record_at(f, k);
  int set = other_set(f->current, -1, -1), i;
  double* copy = DOUBLES(f, f->sensors_copy);
  memcpy(XS(f, set), rec + f->rec_x, sizeof(double) * f->n);
  memcpy(PS(f, set), rec + f->rec_P, sizeof(double) * f->n * f->n);
  memcpy(GATE_COPY(f), rec + f->rec_gate, (size_t)GATE(f)->bytes);
  for (i = 0; i < f->n_sensors; ++i) /* the fields that follow the measurements (not LAST_T, LATE) */
    memcpy(copy + (size_t)i * ABYSSAL_SENSOR_FIELDS, rec + f->rec_sensors + (size_t)i * ABYSSAL_SENSOR_FIELDS,
           sizeof(double) * ABYSSAL_SENSOR_LAST_T);
  if (f->n_u) memcpy(DOUBLES(f, f->u_work), rec + f->rec_u, sizeof(double) * f->n_u);
  if (f->n_p) memcpy(DOUBLES(f, f->p_work), rec + f->rec_p, sizeof(double) * f->n_p);
  w->set = set;
  w->t = rec[REC_T];
  w->has_input = (int)rec[REC_HAS_INPUT];
  w->repairs = (long long)rec[REC_REPAIRS];
  w->substeps = (long long)rec[REC_SUBSTEPS];
  w->fresh = 0;
  w->keep = k + 1;
}

int abyssal_kalman_update_sensor(abyssal_kalman* f, const abyssal_model* model, int sensor, double t, const double* z,
                                 const unsigned char* mask, const double* R, const double* q) {
  work_t w;
  const abyssal_sensor* s;
  double *Rs, *p, *stream;
  int rc = check_model(f, model), rows;
  if (rc != ABYSSAL_OK) return rc;
  if (sensor < 0 || sensor >= f->n_sensors) return ABYSSAL_E_SENSOR;
  s = &model->sensors[sensor];
  rows = s->n_y;
  stream = DOUBLES(f, f->sensors) + (size_t)sensor * ABYSSAL_SENSOR_FIELDS;
  if (!isfinite(t) || t <= stream[ABYSSAL_SENSOR_LAST_T]) return ABYSSAL_E_TIME;
  if (!z) return ABYSSAL_E_Z;
  rc = check_z(rows, z, mask);
  if (rc != ABYSSAL_OK) return rc;
  if (q && !abyssal_all_finite(s->n_q, q)) return ABYSSAL_E_P;
  Rs = DOUBLES(f, f->R_sel);
  if (R) {
    if (abyssal_covariance_problem(rows, R, 1, DOUBLES(f, f->scratch)) != 0) return ABYSSAL_E_R;
    abyssal_symmetrise(rows, R, Rs);
  } else {
    selection_R(f, model, sensor, Rs);
  }
  if (t < f->t && (f->options.history_entries == 0 || f->ring_count == 0 || t < record_at(f, 0)[REC_T]))
    return ABYSSAL_E_TOO_LATE;
  if (t > f->t && !f->has_input && f->n_u > 0) return ABYSSAL_E_U; /* no input held to predict with */
  begin(f, &w);
  p = DOUBLES(f, f->p_call);
  if (t >= f->t) {
    if (t > f->t) {
      rc = do_predict(f, model, &w, DOUBLES(f, f->u_work), DOUBLES(f, f->p_work), t - f->t);
      if (rc != ABYSSAL_OK) return rc;
      w.t = t;
      if (w.recording) new_record(f, w.n_new - 1)[REC_T] = t;
    }
    if (f->n_p) memcpy(p, DOUBLES(f, f->p_work), sizeof(double) * f->n_p);
    if (q && s->n_q) memcpy(p + s->p_offset, q, sizeof(double) * s->n_q);
    rc = do_update(f, model, &w, sensor, z, mask, Rs, R != 0, p);
    if (rc < 0) return rc;
  } else { /* late: from the last event at or before t, with the predict that spans t split there */
    int k = f->ring_count - 1, updated;
    const double* next;
    double piece;
    while (k > 0 && record_at(f, k)[REC_T] > t) --k;
    restore_record(f, &w, k);
    next = record_at(f, k + 1); /* a predict: every later event starts with one (the filter's time moved past t) */
    piece = t - w.t;
    if (piece > 0.0) {
      rc = do_predict(f, model, &w, next + f->rec_u, next + f->rec_p, piece);
      if (rc != ABYSSAL_OK) return rc;
      w.t = t;
      new_record(f, w.n_new - 1)[REC_T] = t;
    }
    if (f->n_p) memcpy(p, next + f->rec_p, sizeof(double) * f->n_p);
    if (q && s->n_q) memcpy(p + s->p_offset, q, sizeof(double) * s->n_q);
    rc = do_update(f, model, &w, sensor, z, mask, Rs, R != 0, p);
    if (rc < 0) return rc;
    updated = w.updated;
    piece = next[REC_T] - t;
    w.replaying = 1;
    if (piece > 0.0) {
      rc = do_predict(f, model, &w, next + f->rec_u, next + f->rec_p, piece);
      if (rc != ABYSSAL_OK) return rc;
      w.t = next[REC_T];
      new_record(f, w.n_new - 1)[REC_T] = next[REC_T];
    }
    rc = replay(f, model, &w, k + 2);
    if (rc != ABYSSAL_OK) return rc;
    w.updated = updated;
    w.late_sensor = sensor;
    DOUBLES(f, f->sensors_copy)[(size_t)sensor * ABYSSAL_SENSOR_FIELDS + ABYSSAL_SENSOR_LATE] += 1;
  }
  DOUBLES(f, f->sensors_copy)[(size_t)sensor * ABYSSAL_SENSOR_FIELDS + ABYSSAL_SENSOR_LAST_T] = t;
  commit(f, &w);
  return w.updated ? ABYSSAL_UPDATED : ABYSSAL_OK;
}

int abyssal_kalman_sensor_index(const abyssal_model* model, const char* name) {
  int k;
  if (!model || !name) return -1;
  for (k = 0; k < model->n_sensors; ++k)
    if (model->sensors[k].name && strcmp(model->sensors[k].name, name) == 0) return k;
  return -1;
}

/* ------------------------------------------------------------------ construction and state */

static int covariance_code(abyssal_kalman* f, int n, const double* A, int definite, int code) {
  if (!A || abyssal_covariance_problem(n, A, definite, DOUBLES(f, f->scratch)) != 0) return code;
  return ABYSSAL_OK;
}

/* The history restarts from the current state: one origin record. */
static void restart_history(abyssal_kalman* f) {
  work_t w;
  double* rec;
  f->ring_head = 0;
  f->ring_count = 0;
  if (f->options.history_entries == 0) return;
  begin(f, &w);
  rec = record_at(f, 0);
  write_record(f, rec, EVENT_ORIGIN, f->t, 0.0, -1, 0, DOUBLES(f, f->u_held), DOUBLES(f, f->p_held), 0, 0, 0, &w);
  f->ring_count = 1;
}

int abyssal_kalman_init(void* memory, size_t bytes, const abyssal_model* model, const abyssal_kalman_options* options,
                        const double* x0, const double* P0, const double* Q, const double* R, double t0,
                        abyssal_kalman** filter) {
  abyssal_kalman* f = (abyssal_kalman*)memory;
  size_t size;
  int rc, k, s;
  if (filter) *filter = 0;
  rc = abyssal_kalman_check_options(model, options);
  if (rc != ABYSSAL_OK) return rc;
  size = abyssal_kalman_work_size(model, options);
  if (!memory || ((size_t)memory & 7u) || bytes < size) return ABYSSAL_E_MEMORY;
  if (f->magic == KALMAN_MAGIC) return ABYSSAL_E_LIVE; /* never overwrite a live filter */
  if (!isfinite(t0)) return ABYSSAL_E_TIME;
  if (!x0 || !abyssal_all_finite(model->n_x, x0)) return ABYSSAL_E_X0;
  memset(memory, 0, size);
  f->options = *options;
  f->algebra = algebra_of(options);
  f->model_id = model->id;
  lay_out(f, model, options);
  rc = covariance_code(f, f->n, P0, 0, ABYSSAL_E_P0);
  if (rc == ABYSSAL_OK) rc = covariance_code(f, f->q_rows, Q, 0, ABYSSAL_E_Q);
  if (rc == ABYSSAL_OK) {
    if (R) {
      rc = covariance_code(f, f->n_y, R, 1, ABYSSAL_E_R);
      if (rc == ABYSSAL_OK) abyssal_symmetrise(f->n_y, R, DOUBLES(f, f->R));
    } else { /* every sensor's declared noise, block-diagonal */
      double* Rf = DOUBLES(f, f->R);
      for (s = 0; s < model->n_sensors && rc == ABYSSAL_OK; ++s) {
        const abyssal_sensor* k2 = &model->sensors[s];
        int i, j;
        if (!k2->R_default || covariance_code(f, k2->n_y, k2->R_default, 1, ABYSSAL_E_R) != ABYSSAL_OK) {
          rc = ABYSSAL_E_R;
          break;
        }
        for (j = 0; j < k2->n_y; ++j)
          for (i = 0; i < k2->n_y; ++i)
            AT(Rf, f->n_y, k2->offset + i, k2->offset + j) =
                0.5 * AT(k2->R_default, k2->n_y, i, j) + 0.5 * AT(k2->R_default, k2->n_y, j, i);
      }
    }
  }
  if (rc == ABYSSAL_OK &&
      abyssal_gate_init((char*)f + f->gate, abyssal_gate_size(f->n_y), f->n_y, options->gate_probability,
                        options->gate_patience, options->gate_inflation, 0) != 0)
    rc = ABYSSAL_E_GATE;
  if (rc == ABYSSAL_OK && f->points > 0 && !abyssal_sigma_weights(&f->algebra, f->n, DOUBLES(f, f->wm), DOUBLES(f, f->wc)))
    rc = ABYSSAL_E_SIGMA_POINTS;
  if (rc != ABYSSAL_OK) {
    memset(memory, 0, sizeof(struct abyssal_kalman));
    return rc;
  }
  memcpy(XS(f, 0), x0, sizeof(double) * f->n);
  abyssal_symmetrise(f->n, P0, PS(f, 0));
  abyssal_symmetrise(f->q_rows, Q, DOUBLES(f, f->Q));
  for (k = 0; k < f->n_y * f->n_y; k += f->n_y + 1) DOUBLES(f, f->S[0])[k] = DOUBLES(f, f->S[1])[k] = 1.0;
  for (s = 0; s < f->n_sensors; ++s) {
    double* rec = DOUBLES(f, f->sensors) + (size_t)s * ABYSSAL_SENSOR_FIELDS;
    rec[ABYSSAL_SENSOR_NIS] = NAN;
    rec[ABYSSAL_SENSOR_LAST_T] = -INFINITY;
  }
  if (f->n_p) memcpy(DOUBLES(f, f->p_held), model->p_default, sizeof(double) * f->n_p);
  f->current = 0;
  f->reported = -1;
  f->reported_sensor = -1;
  f->nis = NAN;
  f->t = t0;
  f->fresh = 1;
  f->magic = KALMAN_MAGIC;
  restart_history(f);
  if (filter) *filter = f;
  return ABYSSAL_OK;
}

void abyssal_kalman_release(abyssal_kalman* f) {
  if (valid(f)) f->magic = 0;
}

int abyssal_kalman_reset(abyssal_kalman* f, const double* x, const double* P) {
  if (!valid(f)) return ABYSSAL_E_MEMORY;
  if (!x || !abyssal_all_finite(f->n, x)) return ABYSSAL_E_X0;
  if (covariance_code(f, f->n, P, 0, ABYSSAL_E_P0) != ABYSSAL_OK) return ABYSSAL_E_P0;
  memcpy(XS(f, f->current), x, sizeof(double) * f->n);
  abyssal_symmetrise(f->n, P, PS(f, f->current));
  f->fresh = 1;
  restart_history(f);
  return ABYSSAL_OK;
}

int abyssal_kalman_set_Q(abyssal_kalman* f, const double* Q) {
  if (!valid(f)) return ABYSSAL_E_MEMORY;
  if (covariance_code(f, f->q_rows, Q, 0, ABYSSAL_E_Q) != ABYSSAL_OK) return ABYSSAL_E_Q;
  abyssal_symmetrise(f->q_rows, Q, DOUBLES(f, f->Q));
  restart_history(f);
  return ABYSSAL_OK;
}

int abyssal_kalman_set_R(abyssal_kalman* f, const double* R) {
  if (!valid(f)) return ABYSSAL_E_MEMORY;
  if (covariance_code(f, f->n_y, R, 1, ABYSSAL_E_R) != ABYSSAL_OK) return ABYSSAL_E_R;
  abyssal_symmetrise(f->n_y, R, DOUBLES(f, f->R));
  return ABYSSAL_OK;
}

int abyssal_kalman_set_sensor_R(abyssal_kalman* f, const abyssal_model* model, int sensor, const double* R) {
  int rc = check_model(f, model), rows, first, i, j;
  double* Rf;
  if (rc != ABYSSAL_OK) return rc;
  if (sensor < 0 || sensor >= f->n_sensors) return ABYSSAL_E_SENSOR;
  rows = model->sensors[sensor].n_y;
  first = model->sensors[sensor].offset;
  if (covariance_code(f, rows, R, 1, ABYSSAL_E_R) != ABYSSAL_OK) return ABYSSAL_E_R;
  Rf = DOUBLES(f, f->R);
  for (j = 0; j < rows; ++j)
    for (i = 0; i < rows; ++i) AT(Rf, f->n_y, first + i, first + j) = 0.5 * AT(R, rows, i, j) + 0.5 * AT(R, rows, j, i);
  return ABYSSAL_OK;
}

const double* abyssal_kalman_x(const abyssal_kalman* f) { return valid(f) ? XS(f, f->current) : 0; }
const double* abyssal_kalman_P(const abyssal_kalman* f) { return valid(f) ? PS(f, f->current) : 0; }
double abyssal_kalman_time(const abyssal_kalman* f) { return valid(f) ? f->t : NAN; }
unsigned long long abyssal_kalman_model_id(const abyssal_kalman* f) { return valid(f) ? f->model_id : 0; }

void abyssal_kalman_get_report(const abyssal_kalman* f, abyssal_kalman_report* r) {
  const abyssal_gate* gate;
  if (!r) return;
  memset(r, 0, sizeof *r);
  r->nis = NAN;
  r->t = NAN;
  r->sensor = -1;
  if (!valid(f)) return;
  gate = (const abyssal_gate*)(const void*)((const char*)f + f->gate);
  if (f->reported >= 0) {
    r->innovation = DOUBLES(f, f->innovation[f->reported]);
    r->S = DOUBLES(f, f->S[f->reported]);
    r->rows = f->reported_rows;
    r->sensor = f->reported_sensor;
    r->nis = f->nis;
    r->nis_dof = f->nis_dof;
  }
  r->t = f->t;
  r->gated = gate->gated;
  r->inflations = f->inflations;
  r->repairs = f->repairs;
  r->substeps = f->substeps;
  r->late = f->late;
  r->history = f->ring_count;
}

int abyssal_kalman_get_sensor_report(const abyssal_kalman* f, int sensor, abyssal_sensor_report* r) {
  const double* rec;
  const abyssal_gate* gate;
  if (!valid(f)) return ABYSSAL_E_MEMORY;
  if (sensor < 0 || sensor >= f->n_sensors) return ABYSSAL_E_SENSOR;
  if (!r) return ABYSSAL_OK;
  rec = DOUBLES(f, f->sensors) + (size_t)sensor * ABYSSAL_SENSOR_FIELDS;
  gate = (const abyssal_gate*)(const void*)((const char*)f + f->gate);
  memset(r, 0, sizeof *r);
  r->used = (long long)rec[ABYSSAL_SENSOR_USED];
  r->gated = (long long)rec[ABYSSAL_SENSOR_GATED];
  r->late = (long long)rec[ABYSSAL_SENSOR_LATE];
  r->inflations = (long long)rec[ABYSSAL_SENSOR_INFLATIONS];
  r->rejected = (int)rec[ABYSSAL_SENSOR_REJECTED];
  r->last_t = rec[ABYSSAL_SENSOR_LAST_T] == -INFINITY ? NAN : rec[ABYSSAL_SENSOR_LAST_T];
  r->nis = rec[ABYSSAL_SENSOR_NIS];
  r->nis_dof = (int)rec[ABYSSAL_SENSOR_NIS_DOF];
  (void)gate;
  return ABYSSAL_OK;
}

/* ------------------------------------------------------------------ smoothing */

int abyssal_rts_step(int n, const unsigned char* angle_states, const double* x, const double* P, const double* x_pred,
                     const double* P_pred, const double* G, const double* xs, const double* Ps, double* xs_out,
                     double* Ps_out, double* scratch) {
  double* D = scratch;      /* Ps - P_pred */
  double* GD = scratch + n * n;
  int i, j, k;
  for (i = 0; i < n; ++i) {
    double v = 0.0;
    for (k = 0; k < n; ++k) {
      double d = xs[k] - x_pred[k];
      if (angle_states && angle_states[k]) d = abyssal_wrap_angle(d);
      v += AT(G, n, i, k) * d;
    }
    xs_out[i] = x[i] + v;
  }
  for (k = 0; k < n * n; ++k) D[k] = Ps[k] - P_pred[k];
  for (j = 0; j < n; ++j) /* GD = G D */
    for (i = 0; i < n; ++i) {
      double v = 0.0;
      for (k = 0; k < n; ++k) v += AT(G, n, i, k) * AT(D, n, k, j);
      AT(GD, n, i, j) = v;
    }
  for (j = 0; j < n; ++j) /* P + (G D) G^T, upper, mirrored */
    for (i = 0; i <= j; ++i) {
      double v = 0.0;
      for (k = 0; k < n; ++k) v += AT(GD, n, i, k) * AT(G, n, j, k);
      v += AT(P, n, i, j);
      AT(Ps_out, n, i, j) = v;
      AT(Ps_out, n, j, i) = v;
    }
  for (k = 0; k < n; ++k)
    if (!isfinite(xs_out[k])) return 0;
  for (k = 0; k < n * n; ++k)
    if (!isfinite(Ps_out[k])) return 0;
  return 1;
}

int abyssal_kalman_smooth(abyssal_kalman* f, double* t, double* x, double* P, int capacity, int* count) {
  int n, k, nn;
  double* scratch;
  if (count) *count = 0;
  if (!valid(f)) return ABYSSAL_E_MEMORY;
  if (!f->options.smoothing || f->options.history_entries == 0) return ABYSSAL_E_OPTIONS;
  if (!t || !x || !P || capacity < f->ring_count) return ABYSSAL_E_MEMORY;
  n = f->n;
  nn = n * n;
  scratch = DOUBLES(f, f->scratch); /* scratch: never part of the committed state */
  k = f->ring_count - 1;
  if (k < 0) return ABYSSAL_OK;
  t[k] = record_at(f, k)[REC_T];
  memcpy(x + (size_t)k * n, XS(f, f->current), sizeof(double) * n);
  memcpy(P + (size_t)k * nn, PS(f, f->current), sizeof(double) * nn);
  for (; k > 0; --k) {
    const double* rec = record_at(f, k);
    const double* prev = record_at(f, k - 1);
    double* xs = x + (size_t)k * n;
    double* Ps = P + (size_t)k * nn;
    t[k - 1] = prev[REC_T];
    if ((int)rec[REC_KIND] == EVENT_PREDICT) {
      if (!abyssal_rts_step(n, 0, prev + f->rec_x, prev + f->rec_P, rec + f->rec_x, rec + f->rec_P, rec + f->rec_G, xs,
                            Ps, x + (size_t)(k - 1) * n, P + (size_t)(k - 1) * nn, scratch))
        return ABYSSAL_E_DIVERGED;
    } else { /* an update: the smoothed state is the same just before it */
      memcpy(x + (size_t)(k - 1) * n, xs, sizeof(double) * n);
      memcpy(P + (size_t)(k - 1) * nn, Ps, sizeof(double) * nn);
    }
  }
  if (count) *count = f->ring_count;
  return ABYSSAL_OK;
}

/* ------------------------------------------------------------------ offsets and messages */

long long abyssal_kalman_offset(const abyssal_kalman* f, int item) {
  if (!valid(f)) return -1;
  if (item >= ABYSSAL_AT_X && item < ABYSSAL_AT_X + SETS) return f->x[item - ABYSSAL_AT_X];
  if (item >= ABYSSAL_AT_P && item < ABYSSAL_AT_P + SETS) return f->P[item - ABYSSAL_AT_P];
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
    case ABYSSAL_AT_TIME: return (long long)offsetof(struct abyssal_kalman, t);
    case ABYSSAL_AT_SENSORS: return f->sensors;
    case ABYSSAL_AT_REPORTED_ROWS: return (long long)offsetof(struct abyssal_kalman, reported_rows);
    case ABYSSAL_AT_REPORTED_SENSOR: return (long long)offsetof(struct abyssal_kalman, reported_sensor);
    case ABYSSAL_AT_INFLATIONS: return (long long)offsetof(struct abyssal_kalman, inflations);
    case ABYSSAL_AT_LATE: return (long long)offsetof(struct abyssal_kalman, late);
    case ABYSSAL_AT_HISTORY: return (long long)offsetof(struct abyssal_kalman, ring_count);
    default: return -1;
  }
}

const char* abyssal_kalman_message(int code) {
  switch (code) {
    case ABYSSAL_UPDATED: return "updated: a measurement was used";
    case ABYSSAL_OK: return "ok: predicted (no measurement entry present, or every entry gated)";
    case ABYSSAL_E_MEMORY: return "memory: NULL, not 8-byte aligned, smaller than abyssal_kalman_work_size(), or not an "
                                  "initialised filter";
    case ABYSSAL_E_MODEL: return "model: NULL, a descriptor of another layout version, lacking the generated functions "
                                 "the filter needs, or not the model this filter was built for (another id or size)";
    case ABYSSAL_E_FILTER: return "options.filter is not an abyssal_filter";
    case ABYSSAL_E_SIGMA_POINTS: return "the sigma points need finite alpha, beta, kappa with 0 < alpha^2 (n + kappa) "
                                        "< inf";
    case ABYSSAL_E_ROBUST: return "the robust update needs sigma (MCUKF) or gamma (Huber) > 0 (inf gives the plain "
                                  "UKF update) and huber_iterations >= 1";
    case ABYSSAL_E_GATE: return "gate options: 0 <= gate_probability < 1 (0: no gate), gate_patience >= 1, "
                                "1 <= gate_inflation < inf and gate_max_inflations >= 0 are required";
    case ABYSSAL_E_SUBSTEPS: return "growth_limit > 1, max_substeps >= 1 and 0 < repair_floor < 1 are required";
    case ABYSSAL_E_X0: return "x0: not finite";
    case ABYSSAL_E_P0: return "P0: not a finite symmetric positive semi-definite matrix";
    case ABYSSAL_E_Q: return "Q: not a finite symmetric positive semi-definite matrix";
    case ABYSSAL_E_R: return "R: not a finite symmetric positive definite matrix (or R not given and a sensor declares "
                             "no noise)";
    case ABYSSAL_E_U: return "u has non-finite entries (or no input is held yet to predict a measurement's stamp with)";
    case ABYSSAL_E_DT: return "dt must be a positive finite number of seconds";
    case ABYSSAL_E_Z: return "z has infinite entries; use NaN for a missing entry";
    case ABYSSAL_E_P: return "p (or the sensor's own parameters) has non-finite entries";
    case ABYSSAL_E_DIVERGED: return "the step failed (non-finite outputs or a covariance that is not positive definite) "
                                    "even after repairing P; the filter diverged or Q, R, dt do not suit the model. "
                                    "State left unchanged.";
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
    case ABYSSAL_E_SENSOR: return "sensor: not one of the model's sensors";
    case ABYSSAL_E_TIME: return "t: not finite, before the filter's time (predict_to), or not after the sensor's "
                                "previous stamp (each sensor's stamps must increase)";
    case ABYSSAL_E_TOO_LATE: return "t: the measurement is older than the filter's history holds (history_seconds, "
                                    "history_entries); nothing changed";
    case ABYSSAL_E_LIVE: return "memory: it holds an initialised filter; abyssal_kalman_release() it before init";
    case ABYSSAL_E_UNSTABLE_STATE: return "x or P: the first predict from the state given to init or reset blew up even "
                                          "in max_substeps substeps (the state is outside the model's stable range). "
                                          "State left unchanged.";
    case ABYSSAL_E_OPTIONS: return "options: noise must be an abyssal_noise (inputs needs a model with noise inputs), "
                                   "history_entries >= 0, history_seconds >= 0 and finite, smoothing 0 or 1";
    default: return "unknown return code";
  }
}
