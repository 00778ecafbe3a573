/* abyssal_proposal.c: see abyssal_proposal.h. Hand-written C99.
 *
 * The particles' Kalman steps run ABYSSAL_BLOCK at a time, structure-of-arrays across them (abyssal_kalman_block.h:
 * the runtime's sigma-point algebra in the same order of operations, the model's f and h once per block over all its
 * points); a particle whose guard fails is redone alone by the runtime's one-Gaussian step on its repaired covariance
 * (abyssal_predict_gaussian, abyssal_update_gaussian), as the batched steps were. The carried covariances are kept
 * exactly symmetric (the steps write them so, and the caller starts them so), which is what the batched steps'
 * symmetrising of their inputs assumed. The rest of the proposal runs per particle: the gate on the cloud, the update
 * redone for the kept entries from the kept predictions, each particle's draw and log importance ratio.
 */
#include "abyssal_proposal.h"

#include <math.h>
#include <string.h>

#include "abyssal_kalman_block.h"
#include "abyssal_kalman_covariance.h"
#include "abyssal_kalman_gate.h"
#include "abyssal_kalman_steps.h"
#include "abyssal_linalg.h"

#define AT(a, ld, i, j) ((a)[(i) + (j) * (ld)])
#define LOG_2PI 1.8378770664093453 /* log(2 pi), as numpy rounds it */
/* the repair's eigenvalue floor (numerics.REPAIR_FLOOR) */
#define REPAIR_FLOOR 1e-10

typedef long long idx;

/* ------------------------------------------------------------------------------------------ work */

/* the step's view of its work buffer */
typedef struct {
  const abyssal_proposal* s;
  abyssal_algebra a;
  int n, nu, m, r, points;
  idx count, ld;
  const double *x_in, *w_in, *P_in, *u, *z, *present_in, *admit_in;
  double *x_out, *P_out;
  double dt;
  /* per particle (capacity): the predictions by blocks, structure-of-arrays (block b's at b n ABYSSAL_BLOCK and
   * b n^2 ABYSSAL_BLOCK); the rest particle after particle */
  double *U, *F, *Y, *x_pred, *P_pred, *x_post, *innovation, *S, *ok;
  /* one block's inputs and outputs, and its scratch */
  double *bx, *bP, *bx_out, *bP_out, *bnu, *bS, *bok;
  void* block;
  /* shared */
  double *wm, *wc, *Qs, *Rs, *zc, *xj, *Pj, *Prep, *repair, *centre, *nu_c, *S_cloud, *S_e, *nu_e, *gate_scratch;
  double *Rp, *dv, *mean_y, *C_y, *L, *y;
  unsigned char *present, *kept, *gated, *entries, *mask;
  void* steps;
} ctx_t;

static idx round8(idx doubles) { return (doubles + 7) & ~(idx)7; }

/* doubles of the regions, in the order take() hands them out */
static idx shared_doubles(const abyssal_model* m, int points) {
  const idx n = m->n_x, y = m->n_y > 0 ? m->n_y : 1, r = n, regions = 32;
  return 2 * points + 6 * n * n + 3 * n + 5 * y * y + 5 * y + 3 * r + 2 * r * r + 5 * (y / 8 + 1) + 8 * regions;
}

static idx blocks_of(idx capacity) { return (capacity + ABYSSAL_BLOCK - 1) / ABYSSAL_BLOCK; }

long long abyssal_proposal_work_size(const abyssal_model* model, int filter, long long capacity, long long ld) {
  abyssal_algebra a;
  const idx n = model->n_x, y = model->n_y > 0 ? model->n_y : 1, u = model->n_u > 0 ? model->n_u : 1;
  const idx slots = blocks_of(capacity) * ABYSSAL_BLOCK;
  memset(&a, 0, sizeof a);
  a.filter = (abyssal_filter)filter;
  return round8(u * ld) + round8(n * ld) + round8(y * ld) + round8(n * slots) + round8(n * n * slots) +
         round8(n * capacity) + round8(y * capacity) + round8(y * y * capacity) + round8(capacity) +
         round8(ABYSSAL_BLOCK * (2 * n + 2 * n * n + y + y * y + 1)) + 8 * 8 +
         (idx)(abyssal_block_scratch_bytes(model, a.filter) / sizeof(double)) + 8 +
         shared_doubles(model, abyssal_sigma_points(a.filter, model->n_x)) +
         (idx)(abyssal_steps_scratch_bytes(model, &a, model->n_y) / sizeof(double)) + 16;
}

static double* take(double** at, idx doubles) {
  double* out = *at;
  *at += round8(doubles);
  return out;
}

static unsigned char* take_flags(double** at, int count) { return (unsigned char*)(void*)take(at, count / 8 + 1); }

static int bind(const abyssal_proposal* s, ctx_t* c) {
  const abyssal_model* m = s->model;
  const double* in = s->in;
  double* at = s->work;
  idx cur, side, carried, k;
  memset(c, 0, sizeof *c);
  c->s = s;
  c->n = m->n_x;
  c->nu = m->n_u;
  c->m = m->n_y;
  c->r = s->rank;
  c->count = (idx)in[ABYSSAL_PROPOSAL_IN_COUNT];
  c->ld = s->ld;
  if (!(s->filter == ABYSSAL_CKF || s->filter == ABYSSAL_UKF || s->filter == ABYSSAL_MCUKF ||
        s->filter == ABYSSAL_HUBER_UKF) ||
      c->count < 1 || c->count > s->capacity || s->ld < s->capacity || c->r < 0 || c->r > c->n || !s->gate ||
      s->work_size < abyssal_proposal_work_size(m, s->filter, s->capacity, s->ld))
    return 0;
  cur = (idx)in[ABYSSAL_PROPOSAL_IN_CUR];
  side = (idx)in[ABYSSAL_PROPOSAL_IN_SIDE];
  carried = (idx)in[ABYSSAL_PROPOSAL_IN_CARRIED];
  if (cur < 0 || cur > 2 || side < 0 || side > 1 || carried < 0 || carried > 1) return 0;
  c->x_in = s->particles[cur];
  c->x_out = s->particles[(cur + 1) % 3];
  c->w_in = in[ABYSSAL_PROPOSAL_IN_PRIOR] != 0.0 ? s->w[side] : 0;
  c->P_in = s->carried[carried];
  c->P_out = s->carried[1 - carried];
  c->dt = in[ABYSSAL_PROPOSAL_IN_DT];
  c->u = in + ABYSSAL_PROPOSAL_IN_HEAD;
  c->z = c->u + c->nu;
  c->present_in = c->z + c->m;
  c->admit_in = c->present_in + c->m;
  c->a.filter = (abyssal_filter)s->filter;
  c->a.alpha = s->alpha;
  c->a.beta = s->beta;
  c->a.kappa = s->kappa;
  c->a.sigma = s->filter == ABYSSAL_MCUKF ? s->sigma : INFINITY;
  c->a.gamma = s->filter == ABYSSAL_HUBER_UKF ? s->gamma : INFINITY;
  c->a.huber_iterations = 3; /* the batched steps' */
  c->points = abyssal_sigma_points(c->a.filter, c->n);
  {
    const idx n = c->n, y = c->m > 0 ? c->m : 1, cap = s->capacity, r = c->n;
    c->U = take(&at, (c->nu > 0 ? c->nu : 1) * c->ld);
    c->F = take(&at, n * c->ld);
    c->Y = take(&at, y * c->ld);
    const idx slots = blocks_of(cap) * ABYSSAL_BLOCK, lanes = ABYSSAL_BLOCK;
    c->x_pred = take(&at, n * slots);
    c->P_pred = take(&at, n * n * slots);
    c->x_post = take(&at, n * cap);
    c->innovation = take(&at, y * cap);
    c->S = take(&at, y * y * cap);
    c->ok = take(&at, cap);
    c->bx = take(&at, n * lanes);
    c->bP = take(&at, n * n * lanes);
    c->bx_out = take(&at, n * lanes);
    c->bP_out = take(&at, n * n * lanes);
    c->bnu = take(&at, y * lanes);
    c->bS = take(&at, y * y * lanes);
    c->bok = take(&at, lanes);
    c->block = at;
    at += (idx)(abyssal_block_scratch_bytes(m, c->a.filter) / sizeof(double)) + 8;
    c->wm = take(&at, c->points);
    c->wc = take(&at, c->points);
    c->Qs = take(&at, n * n);
    c->Rs = take(&at, y * y);
    c->zc = take(&at, y);
    c->xj = take(&at, n);
    c->Pj = take(&at, n * n);
    c->Prep = take(&at, n * n);
    c->repair = take(&at, 3 * n * n + n);
    c->centre = take(&at, y);
    c->nu_c = take(&at, y);
    c->S_cloud = take(&at, y * y);
    c->S_e = take(&at, y * y);
    c->Rp = take(&at, y * y);
    c->nu_e = take(&at, y);
    c->gate_scratch = take(&at, y * y + y);
    c->dv = take(&at, n);
    c->mean_y = take(&at, r);
    c->C_y = take(&at, r * r);
    c->L = take(&at, r * r);
    c->y = take(&at, r);
    c->present = take_flags(&at, c->m);
    c->kept = take_flags(&at, c->m);
    c->gated = take_flags(&at, c->m);
    c->entries = take_flags(&at, c->m);
    c->mask = take_flags(&at, c->m);
    c->steps = at;
  }
  for (k = 0; k < c->m; ++k) c->present[k] = c->present_in[k] != 0.0;
  return 1;
}

/* ------------------------------------------------------------------------------------------ helpers */

/* out = (A + A^T) / 2 entry by entry, as the batched steps symmetrise their inputs */
static void symmetrised(int n, const double* A, double* out) {
  int i, j;
  for (j = 0; j < n; ++j)
    for (i = 0; i <= j; ++i) {
      double v = i == j ? AT(A, n, i, i) : (AT(A, n, i, j) + AT(A, n, j, i)) / 2;
      AT(out, n, i, j) = v;
      AT(out, n, j, i) = v;
    }
}

/* f of every particle at u: the transition means, rows of stride ld */
static void transition_means(ctx_t* c) {
  const abyssal_proposal* s = c->s;
  const double* arg[4];
  double* res[1];
  int i;
  idx j;
  for (i = 0; i < c->nu; ++i)
    for (j = 0; j < c->count; ++j) c->U[(idx)i * c->ld + j] = c->u[i];
  arg[0] = c->x_in;
  arg[1] = c->U;
  arg[2] = s->p;
  arg[3] = &c->dt;
  res[0] = c->F;
  s->model->f_soa(c->count, c->ld, arg, res);
}

/* the block and lane of particle j */
#define BLOCK_OF(j) ((j) / ABYSSAL_BLOCK)
#define LANE_OF(j) ((j) % ABYSSAL_BLOCK)

/* lane `lane` of count block entries (structure-of-arrays) into a vector, and back */
static void lane_out(const double* block, int count, idx lane, double* v) {
  int e;
  for (e = 0; e < count; ++e) v[e] = block[(idx)e * ABYSSAL_BLOCK + lane];
}

static void lane_in(double* block, int count, idx lane, const double* v) {
  int e;
  for (e = 0; e < count; ++e) block[(idx)e * ABYSSAL_BLOCK + lane] = v[e];
}

/* particle j's prediction (m^j_-, P^j_-) out of the block storage */
static void prediction_of(const ctx_t* c, idx j, double* x, double* P) {
  const idx b = BLOCK_OF(j), lane = LANE_OF(j);
  lane_out(c->x_pred + b * c->n * ABYSSAL_BLOCK, c->n, lane, x);
  lane_out(c->P_pred + b * c->n * c->n * ABYSSAL_BLOCK, c->n * c->n, lane, P);
}

/* Particle j's predict alone, from its repaired covariance (its guard failed in the block); returns ok. */
static int predict_alone(ctx_t* c, idx j) {
  const abyssal_proposal* s = c->s;
  const int n = c->n;
  const double* P = c->P_in + j * n * n;
  const idx b = BLOCK_OF(j), lane = LANE_OF(j);
  int i, ok = 0;
  if (!abyssal_all_finite(n * n, P) || abyssal_repair_covariance(n, P, c->Qs, REPAIR_FLOOR, c->Prep, c->repair) != 0)
    return 0; /* nothing to repair: the block's result stands, ok = 0 */
  for (i = 0; i < n; ++i) c->xj[i] = c->x_in[(idx)i * c->ld + j];
  ok = abyssal_predict_gaussian(s->model, &c->a, c->wm, c->wc, c->xj, c->Prep, c->u, s->p, c->dt, c->Qs, c->dv, c->Pj,
                                0, c->steps);
  lane_in(c->x_pred + b * n * ABYSSAL_BLOCK, n, lane, c->dv);
  lane_in(c->P_pred + b * n * n * ABYSSAL_BLOCK, n * n, lane, c->Pj);
  return ok;
}

/* Every particle's predict, by blocks (lanes past the last particle repeat the block's first). */
static void predict_all(ctx_t* c) {
  const int n = c->n;
  idx b, j0;
  int i, e, lane;
  for (b = 0, j0 = 0; j0 < c->count; ++b, j0 += ABYSSAL_BLOCK) {
    const idx nb = c->count - j0 < ABYSSAL_BLOCK ? c->count - j0 : ABYSSAL_BLOCK;
    for (lane = 0; lane < ABYSSAL_BLOCK; ++lane) {
      const idx j = j0 + (lane < nb ? lane : 0);
      for (i = 0; i < n; ++i) c->bx[i * ABYSSAL_BLOCK + lane] = c->x_in[(idx)i * c->ld + j];
      for (e = 0; e < n * n; ++e) c->bP[e * ABYSSAL_BLOCK + lane] = c->P_in[j * n * n + e];
    }
    abyssal_block_predict(c->s->model, &c->a, c->wm, c->wc, c->bx, c->bP, c->u, c->s->p, c->dt, c->Qs,
                          c->x_pred + b * n * ABYSSAL_BLOCK, c->P_pred + b * n * n * ABYSSAL_BLOCK, c->bok, c->block);
    for (lane = 0; lane < nb; ++lane) c->ok[j0 + lane] = c->bok[lane] != 0.0 ? 1.0 : predict_alone(c, j0 + lane);
  }
}

/* Particle j's update alone over `mask` by the one-Gaussian step: plainly first when `plain`, then from its repaired
 * covariance when that fails; its outputs written; returns ok. */
static int update_alone(ctx_t* c, idx j, const unsigned char* mask, int plain) {
  const abyssal_proposal* s = c->s;
  const int n = c->n, m = c->m;
  double* xo = c->x_post + j * n;
  double* Po = c->P_out + j * n * n;
  double* nu = c->innovation + j * m;
  double* S = c->S + j * m * m;
  int ok = 0;
  prediction_of(c, j, c->xj, c->Pj);
  if (plain)
    ok = abyssal_update_gaussian(s->model, &c->a, c->wm, c->wc, 0, s->model->n_sensors, c->xj, c->Pj, c->zc, mask,
                                 s->p, c->Rs, xo, Po, nu, S, 0, 0, c->steps);
  if (!ok && abyssal_all_finite(n * n, c->Pj) &&
      abyssal_repair_covariance(n, c->Pj, c->Qs, REPAIR_FLOOR, c->Prep, c->repair) == 0)
    ok = abyssal_update_gaussian(s->model, &c->a, c->wm, c->wc, 0, s->model->n_sensors, c->xj, c->Prep, c->zc, mask,
                                 s->p, c->Rs, xo, Po, nu, S, 0, 0, c->steps);
  return ok;
}

/* Particle j's own outlier guard (guard_sigma finite): its entries beyond guard_sigma standard deviations of its S
 * are left out of its update, which is redone alone; returns its ok. */
static int guarded(ctx_t* c, idx j, const unsigned char* mask, int ok) {
  const int m = c->m;
  const double* nu = c->innovation + j * m;
  const double* S = c->S + j * m * m;
  int i, outliers = 0;
  for (i = 0; i < m; ++i) {
    c->mask[i] = mask[i];
    if (mask[i] && fabs(nu[i]) > c->s->guard_sigma * sqrt(AT(S, m, i, i))) {
      c->mask[i] = 0;
      outliers = 1;
    }
  }
  return outliers ? update_alone(c, j, c->mask, 1) : ok;
}

/* Every particle's update over `mask` from its prediction, by blocks; the outputs particle after particle. */
static void update_all(ctx_t* c, const unsigned char* mask) {
  const int n = c->n, m = c->m;
  idx b, j0;
  int lane;
  for (b = 0, j0 = 0; j0 < c->count; ++b, j0 += ABYSSAL_BLOCK) {
    const idx nb = c->count - j0 < ABYSSAL_BLOCK ? c->count - j0 : ABYSSAL_BLOCK;
    abyssal_block_update(c->s->model, &c->a, c->wm, c->wc, c->x_pred + b * n * ABYSSAL_BLOCK,
                         c->P_pred + b * n * n * ABYSSAL_BLOCK, c->zc, mask, c->s->p, c->Rs, c->bx_out, c->bP_out,
                         c->bnu, c->bS, c->bok, c->block);
    for (lane = 0; lane < nb; ++lane) {
      const idx j = j0 + lane;
      int ok = c->bok[lane] != 0.0;
      lane_out(c->bx_out, n, lane, c->x_post + j * n);
      lane_out(c->bP_out, n * n, lane, c->P_out + j * n * n);
      lane_out(c->bnu, m, lane, c->innovation + j * m);
      lane_out(c->bS, m * m, lane, c->S + j * m * m);
      if (!ok) ok = update_alone(c, j, mask, 0);
      if (isfinite(c->s->guard_sigma)) ok = guarded(c, j, mask, ok);
      c->ok[j] = ok ? 1.0 : 0.0;
    }
  }
}

/* Every particle's prediction as its proposal's covariance (the next carried P^i) */
static void predictions_carried(ctx_t* c) {
  idx j;
  for (j = 0; j < c->count; ++j) prediction_of(c, j, c->dv, c->P_out + j * c->n * c->n);
}

/* ------------------------------------------------------------------------------------------ the gate */

/* nu_p^T R_pp^-1 nu_p on the present entries (+inf when R_pp does not factor) */
static double noise_bound(ctx_t* c, const double* nu, const unsigned char* present) {
  const int m = c->m;
  int rows = 0, i, k;
  int idx_[64];
  double v[64];
  for (i = 0; i < m && rows < 64; ++i)
    if (present[i]) idx_[rows++] = i;
  for (k = 0; k < rows; ++k) {
    v[k] = nu[idx_[k]];
    for (i = 0; i < rows; ++i) AT(c->Rp, rows, i, k) = AT(c->Rs, m, idx_[i], idx_[k]);
  }
  return abyssal_nis(rows, v, c->Rp, c->gate_scratch);
}

/* The engine's screen (engine.py): the entries of z to use (kept), and those the gate left out (gated), from the
 * residuals res (m per particle at res + j stride, rows of absent entries ignored) minus offset (NULL: none) and the
 * particles' predicted measurement covariances S (m * m per particle; NULL: R for every particle). Returns whether
 * an entry is kept. */
static int screen(ctx_t* c, const double* res, idx res_row, idx res_col, const double* S, const double* offset) {
  abyssal_gate* gate = (abyssal_gate*)c->s->gate;
  const int m = c->m;
  const idx N = c->count;
  const double uniform = 1.0 / (double)N;
  int i, k, dof = 0, all = 1, any = 0, round_, accepted = 0;
  idx j;
  double threshold;
  for (i = 0; i < m; ++i) {
    c->gated[i] = 0;
    c->kept[i] = c->present[i];
    dof += c->present[i];
    all = all && c->present[i];
  }
  if (gate->probability == 0.0) return dof > 0;
  for (i = 0; i < m; ++i) { /* the centre: the prior-weighted mean residual */
    double v = 0.0;
    for (j = 0; j < N; ++j) v += (c->w_in ? c->w_in[j] : 1.0) * res[(idx)i * res_row + j * res_col];
    c->centre[i] = c->w_in ? v : v * uniform;
    c->nu_c[i] = offset ? c->centre[i] - offset[i] : c->centre[i];
    if (!all && !c->present[i]) c->nu_c[i] = 0.0;
  }
  threshold = abyssal_gate_threshold(gate, dof);
  if (noise_bound(c, c->nu_c, c->present) <= threshold) return dof > 0; /* S >= R: the bound settles it */
  for (k = 0; k < m; ++k) /* S = the weighted second moment - the centre's outer product + (R or sum w_i S_i) */
    for (i = 0; i < m; ++i) {
      double v = 0.0, t = 0.0;
      for (j = 0; j < N; ++j) {
        const double w = c->w_in ? c->w_in[j] : uniform;
        v += res[(idx)i * res_row + j * res_col] * w * res[(idx)k * res_row + j * res_col];
        if (S) t += S[j * m * m + i + (idx)k * m] * w;
      }
      AT(c->S_cloud, m, i, k) = v - c->centre[i] * c->centre[k] + (S ? t : AT(c->Rs, m, i, k));
    }
  if (all && abyssal_gate_passes(gate, abyssal_nis(m, c->nu_c, c->S_cloud, c->gate_scratch), dof)) return 1;
  for (i = 0; i < m; ++i) { /* judged: a finite innovation and row of S (an overflowing entry is gated outright) */
    int judged = isfinite(c->nu_c[i]);
    for (k = 0; k < m; ++k) judged = judged && isfinite(AT(c->S_cloud, m, i, k));
    c->entries[i] = c->present[i] && judged;
    any = any || c->entries[i];
    c->kept[i] = 0;
  }
  for (round_ = 0; any && round_ < 2; ++round_) { /* the gate's selection (InnovationGate.select) */
    int verdict;
    for (k = 0; k < m; ++k) {
      c->nu_e[k] = c->entries[k] ? c->nu_c[k] : 0.0;
      for (i = 0; i < m; ++i)
        AT(c->S_e, m, i, k) = c->entries[i] && c->entries[k] ? AT(c->S_cloud, m, i, k) : (i == k ? 1.0 : 0.0);
    }
    verdict = abyssal_gate_judge(gate, round_, c->nu_e, c->S_e, c->entries, c->gated, 0, c->gate_scratch);
    if (verdict == ABYSSAL_GATE_ACCEPT) {
      accepted = 1;
      break;
    }
    if (verdict == ABYSSAL_GATE_REJECT) break;
  }
  for (i = 0; i < m; ++i) {
    int judged = isfinite(c->nu_c[i]);
    for (k = 0; k < m; ++k) judged = judged && isfinite(AT(c->S_cloud, m, i, k));
    if (c->present[i] && !judged) c->gated[i] = 1;
    c->kept[i] = accepted && c->entries[i];
  }
  for (i = 0; i < m; ++i) /* the re-acquisition: admitted entries are used while they fail */
    if (c->gated[i] && c->admit_in[i] != 0.0) c->kept[i] = 1;
  for (i = 0, any = 0; i < m; ++i) any = any || c->kept[i];
  return any;
}

/* ------------------------------------------------------------------------------------------ the draw */

/* Cholesky factor as LAPACK's: fails (0) only on a pivot that is not positive (or not finite) */
static int plain_cholesky(int r, const double* A, double* L) {
  int i, j, k;
  for (j = 0; j < r; ++j) {
    double d = AT(A, r, j, j);
    for (k = 0; k < j; ++k) d -= AT(L, r, j, k) * AT(L, r, j, k);
    if (!(d > 0.0) || !isfinite(d)) return 0;
    d = sqrt(d);
    AT(L, r, j, j) = d;
    for (i = j + 1; i < r; ++i) {
      double v = AT(A, r, i, j);
      for (k = 0; k < j; ++k) v -= AT(L, r, i, k) * AT(L, r, j, k);
      AT(L, r, i, j) = v / d;
    }
    for (i = 0; i < j; ++i) AT(L, r, i, j) = 0.0;
  }
  return 1;
}

/* y on the subspace of the process noise of a state-sized vector v: V^T v */
static double coordinate(const ctx_t* c, const double* v, int q) {
  const abyssal_proposal* s = c->s;
  if (s->support) return v[s->support[q]];
  return abyssal_dot(c->n, s->basis + (idx)q * c->n, v);
}

/* Particle j's draw from N(mean, C) restricted to the subspace, into the proposals; its log importance ratio. */
static void draw_particle(ctx_t* c, idx j, const double* mean, const double* C) {
  const abyssal_proposal* s = c->s;
  const int n = c->n, r = c->r;
  const double* xi = s->normals;
  double log_det = 0.0, xi2 = 0.0, q2 = 0.0;
  int a, b, i;
  for (i = 0; i < n; ++i) c->dv[i] = mean[i] - c->F[(idx)i * c->ld + j];
  for (a = 0; a < r; ++a) c->mean_y[a] = coordinate(c, c->dv, a);
  if (s->support) {
    for (b = 0; b < r; ++b)
      for (a = 0; a < r; ++a) AT(c->C_y, r, a, b) = AT(C, n, s->support[a], s->support[b]);
  } else { /* V^T C V */
    for (b = 0; b < r; ++b) {
      for (i = 0; i < n; ++i) c->dv[i] = abyssal_dot(n, C + (idx)i * n, s->basis + (idx)b * n); /* (C V)_ib */
      for (a = 0; a < r; ++a) AT(c->C_y, r, a, b) = abyssal_dot(n, s->basis + (idx)a * n, c->dv);
    }
  }
  if (!plain_cholesky(r, c->C_y, c->L)) {
    if (abyssal_repair_covariance(r, c->C_y, c->C_y, REPAIR_FLOOR, c->Prep, c->repair) != 0 ||
        !plain_cholesky(r, c->Prep, c->L))
      for (a = 0; a < r * r; ++a) c->L[a] = NAN; /* not finite: the SIR step refuses the particle */
  }
  for (a = 0; a < r; ++a) {
    double v = 0.0;
    for (b = 0; b <= a; ++b) v += AT(c->L, r, a, b) * xi[(idx)b * c->count + j];
    c->y[a] = c->mean_y[a] + v;
    log_det += log(AT(c->L, r, a, a));
    xi2 += xi[(idx)a * c->count + j] * xi[(idx)a * c->count + j];
  }
  for (i = 0; i < n; ++i) c->dv[i] = 0.0; /* V y */
  if (s->support) {
    for (a = 0; a < r; ++a) c->dv[s->support[a]] = c->y[a];
  } else {
    for (a = 0; a < r; ++a)
      for (i = 0; i < n; ++i) c->dv[i] += s->basis[(idx)a * n + i] * c->y[a];
  }
  for (i = 0; i < n; ++i) {
    const double f = c->F[(idx)i * c->ld + j];
    const double x = f + c->dv[i];
    c->x_out[(idx)i * c->ld + j] = x;
    c->dv[i] = x - f; /* the noise the particle took, as the engine measures it */
  }
  for (a = 0; a < r; ++a) {
    const double v = coordinate(c, c->dv, a);
    q2 += v * (v / s->variances[a]);
  }
  s->log_ratio[j] = (-0.5 * q2 + s->log_norm) - (-0.5 * xi2 - log_det - 0.5 * r * LOG_2PI);
}

/* Every particle's draw and log ratio from (x_post, P_out) of its slot (the prediction already copied there when its
 * update failed), ABYSSAL_BLOCK at a time on the support of the process noise, draw_particle's operations in its
 * order; a particle whose V^T P V does not factor is drawn alone (draw_particle, which repairs it). A dense basis of
 * the subspace: every particle alone. */
static void draw_all(ctx_t* c) {
  const abyssal_proposal* s = c->s;
  const int n = c->n, r = c->r, B = ABYSSAL_BLOCK;
  double* mean_y = c->bx;  /* the block buffers of the Kalman steps are free now */
  double* C_y = c->bP;
  double* L = c->bP_out;
  double* xb = c->bx_out;
  double* ok = c->bok;
  idx j0;
  int a, b, i, lane;
  if (!s->support) {
    for (j0 = 0; j0 < c->count; ++j0) draw_particle(c, j0, c->x_post + j0 * n, c->P_out + j0 * n * n);
    return;
  }
  for (j0 = 0; j0 < c->count; j0 += B) {
    const idx nb = c->count - j0 < B ? c->count - j0 : B;
    double log_det[ABYSSAL_BLOCK], xi2[ABYSSAL_BLOCK], q2[ABYSSAL_BLOCK], y[ABYSSAL_BLOCK];
    for (lane = 0; lane < B; ++lane) {
      const idx j = j0 + (lane < nb ? lane : 0);
      const double* mean = c->x_post + j * n;
      const double* P = c->P_out + j * n * n;
      for (a = 0; a < r; ++a) {
        const int row = s->support[a];
        mean_y[a * B + lane] = mean[row] - c->F[(idx)row * c->ld + j];
        xb[a * B + lane] = s->normals[(idx)a * c->count + j];
        for (b = 0; b < r; ++b) C_y[(a + b * r) * B + lane] = AT(P, n, row, s->support[b]);
      }
      ok[lane] = 1.0;
      log_det[lane] = xi2[lane] = q2[lane] = 0.0;
    }
    abyssal_block_factor(r, C_y, L, ok);
    for (i = 0; i < n; ++i) /* rows off the support: x = f */
      for (lane = 0; lane < nb; ++lane) c->x_out[(idx)i * c->ld + j0 + lane] = c->F[(idx)i * c->ld + j0 + lane] + 0.0;
    for (a = 0; a < r; ++a) {
      const int row = s->support[a];
      const double variance = s->variances[a];
      for (lane = 0; lane < B; ++lane) y[lane] = 0.0;
      for (b = 0; b <= a; ++b)
        for (lane = 0; lane < B; ++lane) y[lane] += L[(a + b * r) * B + lane] * xb[b * B + lane];
      for (lane = 0; lane < B; ++lane) {
        const double f = c->F[(idx)row * c->ld + j0 + (lane < nb ? lane : 0)];
        const double x = f + (mean_y[a * B + lane] + y[lane]);
        const double w = x - f;
        log_det[lane] += log(L[(a + a * r) * B + lane]);
        xi2[lane] += xb[a * B + lane] * xb[a * B + lane];
        q2[lane] += w * (w / variance);
        if (lane < nb) c->x_out[(idx)row * c->ld + j0 + lane] = x;
      }
    }
    for (lane = 0; lane < nb; ++lane) {
      const idx j = j0 + lane;
      s->log_ratio[j] = (-0.5 * q2[lane] + s->log_norm) - (-0.5 * xi2[lane] - log_det[lane] - 0.5 * r * LOG_2PI);
      if (ok[lane] == 0.0) draw_particle(c, j, c->x_post + j * n, c->P_out + j * n * n);
    }
  }
}

/* Every particle moves by the transition: x = f + V sqrt(Lambda) xi. */
static void transition_draws(ctx_t* c) {
  const abyssal_proposal* s = c->s;
  const int n = c->n, r = c->r;
  int a, i;
  idx j;
  for (j = 0; j < c->count; ++j) {
    for (i = 0; i < n; ++i) c->dv[i] = 0.0;
    for (a = 0; a < r; ++a) {
      const double y = s->normals[(idx)a * c->count + j] * sqrt(s->variances[a]);
      if (s->support)
        c->dv[s->support[a]] = y;
      else
        for (i = 0; i < n; ++i) c->dv[i] += s->basis[(idx)a * n + i] * y;
    }
    for (i = 0; i < n; ++i) c->x_out[(idx)i * c->ld + j] = c->F[(idx)i * c->ld + j] + c->dv[i];
  }
}

/* ------------------------------------------------------------------------------------------ the step */

static void residuals_at_particles(ctx_t* c) {
  const abyssal_model* m = c->s->model;
  const double* arg[2];
  double* res[1];
  int k, i;
  idx j;
  for (k = 0; k < m->n_sensors; ++k) {
    const abyssal_sensor* sensor = &m->sensors[k];
    arg[0] = c->x_in;
    arg[1] = c->s->p;
    res[0] = c->Y + (idx)sensor->offset * c->ld;
    sensor->h_soa(c->count, c->ld, arg, res);
    for (i = 0; i < sensor->n_y; ++i) {
      const int row = sensor->offset + i;
      double* y = c->Y + (idx)row * c->ld;
      double big = 0.0;
      for (j = 0; j < c->count; ++j) {
        y[j] = c->z[row] - y[j];
        big = fabs(y[j]) > big ? fabs(y[j]) : big;
      }
      if (sensor->angle_outputs && sensor->angle_outputs[i] && c->present[row] && big > 3.14159265358979323846)
        for (j = 0; j < c->count; ++j) y[j] = abyssal_wrap_angle(y[j]);
    }
  }
}

int abyssal_proposal_step(const abyssal_proposal* s) {
  ctx_t c;
  const int mode = s && s->in ? (int)s->in[ABYSSAL_PROPOSAL_IN_MODE] : -1;
  int i, any;
  idx j, failed = 0;
  if (!s || !s->model || !s->work || !s->out || mode < ABYSSAL_PROPOSAL_STEP || mode > ABYSSAL_PROPOSAL_SCREEN ||
      !bind(s, &c))
    return ABYSSAL_PROPOSAL_BAD_ARGUMENT;
  if (!abyssal_sigma_weights(&c.a, c.n, c.wm, c.wc)) return ABYSSAL_PROPOSAL_BAD_ARGUMENT;
  symmetrised(c.n, s->Q, c.Qs);
  if (c.m > 0) symmetrised(c.m, s->R, c.Rs);
  for (i = 0; i < c.m; ++i) c.zc[i] = c.present[i] ? c.z[i] - s->r_mean[i] : 0.0;
  s->out[ABYSSAL_PROPOSAL_OUT_FAILED] = 0.0;
  if (mode == ABYSSAL_PROPOSAL_SCREEN) { /* an update alone: the gate on the particles' own residuals */
    residuals_at_particles(&c);
    any = screen(&c, c.Y, c.ld, 1, 0, s->r_mean);
  } else {
    transition_means(&c);
    predict_all(&c);
    if (mode == ABYSSAL_PROPOSAL_PREDICT) {
      predictions_carried(&c);
      if (!abyssal_all_finite((int)(c.count * c.n * c.n), c.P_out)) return ABYSSAL_PROPOSAL_NONFINITE_PREDICTION;
      transition_draws(&c);
      any = 0;
    } else {
      update_all(&c, c.present);
      any = screen(&c, c.innovation, 1, c.m, c.S, 0);
      if (!any) { /* every entry left out: the transition, and P^i its prediction */
        transition_draws(&c);
        predictions_carried(&c);
      } else {
        int changed = 0;
        for (i = 0; i < c.m; ++i) changed = changed || c.kept[i] != c.present[i];
        if (changed) update_all(&c, c.kept); /* the update alone, again, from the kept predictions */
        for (j = 0; j < c.count; ++j)
          if (c.ok[j] == 0.0) { /* proposes from its prediction */
            prediction_of(&c, j, c.x_post + j * c.n, c.P_out + j * c.n * c.n);
            ++failed;
          }
        draw_all(&c);
      }
    }
  }
  s->out[ABYSSAL_PROPOSAL_OUT_KEPT] = 0.0;
  for (i = 0; i < c.m; ++i) {
    s->out[ABYSSAL_PROPOSAL_OUT_HEAD + i] = any && c.kept[i] ? 1.0 : 0.0;
    s->out[ABYSSAL_PROPOSAL_OUT_HEAD + c.m + i] = c.gated[i] ? 1.0 : 0.0;
    s->out[ABYSSAL_PROPOSAL_OUT_KEPT] += any && c.kept[i];
  }
  s->out[ABYSSAL_PROPOSAL_OUT_FAILED] = (double)failed;
  return ABYSSAL_PROPOSAL_OK;
}
