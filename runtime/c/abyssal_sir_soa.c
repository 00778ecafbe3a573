/* One compiled SIR step for any generated model: see abyssal_sir.h for what a step does and its buffers.
 *
 * Hand-written C99 of abyssal's runtime (not generated from equations). The file name ends in _soa.c so the
 * cache builds it with the structure-of-arrays flags (-fopenmp-simd, libmvec's vector exp/log).
 *
 * Inside a step, in three kinds of passes over blocks of ABYSSAL_SIR_BLOCK particles:
 *   1. the block pass (move, pins, h, likelihood, and the block's weighted sums) -- once, or two or three
 *      times when the gate leaves an entry out or every likelihood underflows (the block is then read back);
 *   2. the normalisation pass (log-weights and weights);
 *   3. the gather pass of resampling (when it resamples).
 * Between them, thread 0 combines the blocks' sums in block order (Chan et al.'s pairwise formula for the
 * covariances, each block's sums relative to its own largest log-weight), so sums never depend on the split.
 */
#define _POSIX_C_SOURCE 200809L
#include "abyssal_sir.h"
#include "abyssal_rng.h"

#include <float.h>
#include <math.h>
#include <string.h>
#ifndef ABYSSAL_SIR_NO_THREADS
#include <pthread.h>
#include <sched.h>
#endif

#if defined(__x86_64__) && defined(__GLIBC__) && !defined(ABYSSAL_NO_LIBMVEC)
/* glibc's libmvec has vector variants of these: declaring them lets the particle loops vectorise; const:
 * errno is never read here */
#pragma omp declare simd notinbranch
extern double exp(double) __attribute__((const));
#pragma omp declare simd notinbranch
extern double log(double) __attribute__((const));
#endif

#define BLOCK ABYSSAL_SIR_BLOCK
#define PI 3.14159265358979323846
#define TWO_PI 6.28318530717958647692
typedef abyssal_idx idx;

/* what a block pass does: produce the particles (else read the proposals back), call h, the likelihood, the
 * prior-weighted mean of y (for the gate's innovation), its M2 too (the gate's S), and the posterior sums */
/* block passes (at most four), normalisation, gather */
#define PHASES 6
enum { MODE_MOVE = 1, MODE_H = 2, MODE_LIK = 4, MODE_YMEAN = 8, MODE_YM2 = 16, MODE_POST = 32 };

/* ------------------------------------------------------------------------------------------ layouts */
abyssal_sir_in_offsets abyssal_sir_inputs(int n_x, int n_u, int n_y) {
  abyssal_sir_in_offsets o;
  o.pin_values = ABYSSAL_SIR_IN_HEAD;
  o.pin_rows = o.pin_values + n_x;
  o.u = o.pin_rows + n_x;
  o.u_std = o.u + n_u;
  o.z = o.u_std + n_u;
  o.present = o.z + n_y;
  o.thresholds = o.present + n_y;
  o.settings = o.thresholds + n_y + 1;
  o.size = o.settings + ABYSSAL_SIR_SET_COUNT;
  return o;
}

abyssal_sir_report_offsets abyssal_sir_report(int n_x, int n_y, int n_extra) {
  abyssal_sir_report_offsets o;
  o.gated = ABYSSAL_SIR_R_HEAD;
  o.mean = o.gated + n_y;
  o.cov = o.mean + n_x;
  o.extra = o.cov + (idx)n_x * n_x;
  o.nu = o.extra + n_extra;
  o.S = o.nu + n_y;
  o.size = o.S + (idx)n_y * n_y;
  return o;
}

/* one block's sums: status, weights relative to the block's largest log-weight, the particles' mean and
 * packed upper M2, extra rows' means, and the same over y with the prior weights (for the gate) */
typedef struct {
  idx status, peak, W, Q, max_ll, prior_peak, prior_W, w_sum, mean, m2, extra, ybar, m2y, stride;
} block_layout;

static idx packed(int d) { return (idx)d * (d + 1) / 2; }

static block_layout block_offsets(int n_x, int n_y, int n_extra) {
  block_layout o;
  o.status = 0; o.peak = 1; o.W = 2; o.Q = 3; o.max_ll = 4; o.prior_peak = 5; o.prior_W = 6; o.w_sum = 7;
  o.mean = 8;
  o.m2 = o.mean + n_x;
  o.extra = o.m2 + packed(n_x);
  o.ybar = o.extra + n_extra;
  o.m2y = o.ybar + n_y;
  o.stride = o.m2y + packed(n_y);
  return o;
}

static idx blocks_of(idx n) { return (n + BLOCK - 1) / BLOCK; }
static int draw_rows(int n_u, int rank) { return n_u + rank; }
static int y_rows(int n_y, int n_extra, int has_valid) { return n_y + n_extra + (has_valid ? 1 : 0); }

/* per-thread scratch, in doubles (multiples of 8). The inputs u and the measurement y are rows of stride ld (the
 * particle buffers' row stride), as the generated kernels take one stride for every per-particle argument: only
 * their first BLOCK columns are ever touched (the rest is address space, never written). */
static idx rows_at_stride(int rows, idx ld) { return rows > 0 ? (idx)(rows - 1) * ld + BLOCK : 0; }

static idx scratch_size(int n_x, int n_u, int n_y, int n_extra, int has_valid, int rank, int r_components, idx ld) {
  const int rows = draw_rows(n_u, rank);
  idx size = 2 * (idx)n_x * BLOCK;                      /* xa, xb: substeps, and the shifted rows of the moments */
  size += (idx)n_u * BLOCK;                             /* per-particle inputs of the substep path (stride BLOCK) */
  size += (rows_at_stride(n_u, ld) + 7) / 8 * 8;        /* per-particle inputs (stride ld) */
  size += (rows_at_stride(y_rows(n_y, n_extra, has_valid), ld) + 7) / 8 * 8; /* y (stride ld) */
  size += (idx)(n_y > 0 ? n_y : 1) * BLOCK;             /* the shifted rows of y */
  size += (idx)(rows > 0 ? rows : 1) * BLOCK;           /* normals */
  size += 2 * (idx)BLOCK;                               /* 4 uint32 per particle */
  size += (idx)(n_y > 0 ? n_y : 1) * BLOCK;             /* residuals */
  size += (idx)(r_components > 1 ? r_components : 1) * BLOCK; /* per-component log-densities */
  size += 8 * (idx)BLOCK;                               /* lp, l, ll, s, e, ancestors (two), uniforms */
  return size;
}

/* the likelihood plan (see lik_plan), its entries, and two n_y x n_y temporaries */
static idx plan_size(int n_y, int r_components) {
  return (idx)r_components * ((idx)n_y * n_y + n_y + 1) + n_y + 2 * (idx)n_y * n_y;
}

/* Each thread's scratch starts on a 64-byte boundary (and its arrays, multiples of BLOCK doubles, too): a
 * vectorised sum then groups the same elements whichever thread runs it (its alignment peeling is the same). */
#define ALIGN_DOUBLES 8
static double* aligned(double* p) {
  const uintptr_t a = (uintptr_t)p, mask = (uintptr_t)(ALIGN_DOUBLES * sizeof(double) - 1);
  return (double*)((a + mask) & ~mask);
}

abyssal_idx abyssal_sir_work_size(abyssal_idx n, abyssal_idx ld, int n_x, int n_u, int n_y, int n_extra, int has_valid,
                                  int rank, int r_components, int threads) {
  const idx nb = blocks_of(n);
  const block_layout L = block_offsets(n_x, n_y, n_extra);
  if (threads < 1) threads = 1;
  return nb * L.stride + (nb + 1) + plan_size(n_y, r_components < 1 ? 1 : r_components) + ALIGN_DOUBLES +
         (idx)threads * scratch_size(n_x, n_u, n_y, n_extra, has_valid, rank, r_components, ld);
}

const char* abyssal_sir_message(int code) {
  switch (code) {
    case ABYSSAL_SIR_OK: return "ok";
    case ABYSSAL_SIR_NONFINITE_PARTICLE: return "a particle left the finite range";
    case ABYSSAL_SIR_NONFINITE_MEASUREMENT: return "the measurement function gave a non-finite value";
    case ABYSSAL_SIR_NONFINITE_WEIGHT: return "a log-weight is NaN or +inf";
    case ABYSSAL_SIR_MODEL_FAILED: return "the model's generated function failed";
    case ABYSSAL_SIR_BAD_ARGUMENT: return "sizes, buffers or inputs of the step are out of range";
    case ABYSSAL_SIR_NONFINITE_MOMENTS: return "the weighted mean or covariance of the particles is not finite";
    default: return "unknown return code";
  }
}

/* ------------------------------------------------------------------------------------------ random numbers */
/* The Box-Muller transform of two 32-bit words a, b in single precision, written out so that the particle loops
 * vectorise on any SIMD target without a vector libm, and faster than through libmvec's logf/sinf/cosf on AVX2
 * (benchmarks/README.md, bench_tan). Radius sqrt(-2 ln u) for u = (a + 1/2) 2^-32 in (0, 1],
 * rounded once: u = 2^e m with m in [sqrt(1/2), sqrt(2)), ln m = 2 atanh(s) with s = (m - 1)/(m + 1),
 * |s| < 0.172, summed to s^9 (the next term is below 2e-9 relative). Angle 2 pi b 2^-32 = k pi/2 + x with k the
 * nearest quadrant and x in [-pi/4, pi/4): sin x to x^9 and cos x to x^8 (below 3e-8), then the quadrant's swap
 * and signs. Each normal to ~1e-7 relative against the transform in double of the same u (tests), the tail
 * reaching sqrt(-2 ln 2^-33) = 6.8. */
static inline float box_muller_radius(uint32_t a) {
  /* two exact 16-bit halves: one rounding, and no unsigned conversion (which AVX2 does not have) */
  const float u = (float)(int32_t)(a >> 16) * 0x1p-16f + ((float)(int32_t)(a & 0xFFFFu) * 0x1p-32f + 0x1p-33f);
  uint32_t bits;
  memcpy(&bits, &u, sizeof bits);
  const int32_t e = (int32_t)((bits + (0x3F800000u - 0x3F3504F3u)) >> 23) - 127; /* 0x3F3504F3: sqrt(1/2) */
  const uint32_t m_bits = bits - ((uint32_t)e << 23);
  float m;
  memcpy(&m, &m_bits, sizeof m);
  const float s = (m - 1.0f) / (m + 1.0f), z = s * s;
  const float atanh2 = 2.0f + z * (2.0f / 3.0f + z * (2.0f / 5.0f + z * (2.0f / 7.0f + z * (2.0f / 9.0f))));
  return sqrtf(-2.0f * ((float)e * 0.693147180559945309f + s * atanh2));
}

static inline void box_muller(uint32_t a, uint32_t b, double* cos_out, double* sin_out) {
  const float r = box_muller_radius(a);
  const uint32_t w = b + 0x20000000u; /* + 1/8 turn: quadrant k = w >> 30, x from the rest */
  const uint32_t k = w >> 30;
  const float x = (float)((int32_t)(w & 0x3FFFFFFFu) - 0x20000000) * (float)(PI / 2 * 0x1p-30), z = x * x;
  const float sx = x + x * z * (-1.0f / 6 + z * (1.0f / 120 + z * (-1.0f / 5040 + z * (1.0f / 362880))));
  const float cx = 1.0f + z * (-1.0f / 2 + z * (1.0f / 24 + z * (-1.0f / 720 + z * (1.0f / 40320))));
  const float c = (k & 1u) ? sx : cx, sn = (k & 1u) ? cx : sx; /* cos, sin of k pi/2 + x up to sign */
  *cos_out = (double)(r * (((k + 1u) & 2u) ? -c : c));         /* negative in quadrants 1, 2 */
  *sin_out = (double)(r * ((k & 2u) ? -sn : sn));              /* negative in quadrants 2, 3 */
}

/* Normal rows row0..rows-1 (row0 a multiple of 4) of particles i0..i0+n-1 (n <= BLOCK) into
 * out[(row - row0) * ld + j]: group g of four rows is
 * Philox4x32-10 of the counter (particle, tag << 16 | g, step counter) under the key, two Box-Muller pairs. */
static void normals_block(uint64_t key, uint64_t counter, uint32_t tag, idx i0, idx n, int row0, int rows,
                          double* restrict out, idx ld, uint32_t* restrict bits) {
  const uint32_t key0 = (uint32_t)key, key1 = (uint32_t)(key >> 32);
  const uint32_t ctr2 = (uint32_t)counter, ctr3 = (uint32_t)(counter >> 32);
  uint32_t* restrict b0 = bits;
  uint32_t* restrict b1 = bits + BLOCK;
  uint32_t* restrict b2 = bits + 2 * BLOCK;
  uint32_t* restrict b3 = bits + 3 * BLOCK;
  for (int g = row0 / 4; 4 * g < rows; ++g) {
    const int words = rows - 4 * g; /* Box-Muller pairs need 2 or 4 words */
    abyssal_philox_run((uint32_t)i0, (tag << 16) | (uint32_t)g, ctr2, ctr3, key0, key1, n, b0, b1,
                       words > 2 ? b2 : NULL, words > 2 ? b3 : NULL);
    for (int pair = 0; pair < 2; ++pair) {
      const int row = 4 * g + 2 * pair;
      if (row >= rows) break;
      const uint32_t* restrict ua = pair ? b2 : b0;
      const uint32_t* restrict ub = pair ? b3 : b1;
      double* restrict a = out + (idx)(row - row0) * ld;
      if (row + 1 < rows) {
        double* restrict c = out + (idx)(row + 1 - row0) * ld;
#pragma omp simd
        for (idx j = 0; j < n; ++j) {
          double cj, sj;
          box_muller(ua[j], ub[j], &cj, &sj);
          a[j] = cj;
          c[j] = sj;
        }
      } else {
#pragma omp simd
        for (idx j = 0; j < n; ++j) {
          double cj, sj;
          box_muller(ua[j], ub[j], &cj, &sj);
          a[j] = cj;
        }
      }
    }
  }
}

/* Uniforms in (0, 1) of particles i0..i0+n-1: word 0 of Philox4x32-10 of (particle, tag << 16, step counter). */
static void uniforms_block(uint64_t key, uint64_t counter, uint32_t tag, idx i0, idx n, double* restrict out) {
  uint32_t bits[BLOCK];
  abyssal_philox_run((uint32_t)i0, tag << 16, (uint32_t)counter, (uint32_t)(counter >> 32), (uint32_t)key,
                     (uint32_t)(key >> 32), n, bits, NULL, NULL, NULL);
#pragma omp simd
  for (idx j = 0; j < n; ++j) out[j] = ((double)bits[j] + 0.5) * 0x1p-32;
}

/* (through aligned scratch, like a step: the same values whatever the alignment of out) */
void abyssal_sir_normals(uint64_t key, uint64_t counter, uint32_t tag, abyssal_idx i0, abyssal_idx n, int rows,
                         double* out, abyssal_idx ld) {
  uint32_t bits[4 * BLOCK];
  double scratch[4 * BLOCK + ALIGN_DOUBLES];
  double* four = aligned(scratch);
  for (idx j0 = 0; j0 < n; j0 += BLOCK) {
    const idx nb = n - j0 < BLOCK ? n - j0 : BLOCK;
    for (int g = 0; 4 * g < rows; ++g) {
      const int count = rows - 4 * g < 4 ? rows - 4 * g : 4;
      normals_block(key, counter, tag, i0 + j0, nb, 4 * g, 4 * g + count, four, BLOCK, bits);
      for (int r = 0; r < count; ++r) memcpy(out + (idx)(4 * g + r) * ld + j0, four + (idx)r * BLOCK, (size_t)nb * sizeof(double));
    }
  }
}

void abyssal_sir_uniforms(uint64_t key, uint64_t counter, uint32_t tag, abyssal_idx i0, abyssal_idx n, double* out) {
  for (idx j0 = 0; j0 < n; j0 += BLOCK) uniforms_block(key, counter, tag, i0 + j0, n - j0 < BLOCK ? n - j0 : BLOCK, out + j0);
}

void abyssal_sir_philox(const uint32_t counter[4], const uint32_t key[2], uint32_t out[4]) {
  abyssal_philox4x32_10(counter, key, out);
}

void abyssal_sir_box_muller(const uint32_t* a, const uint32_t* b, abyssal_idx n, double* cos_out, double* sin_out) {
#pragma omp simd
  for (idx j = 0; j < n; ++j) box_muller(a[j], b[j], cos_out + j, sin_out + j);
}

int abyssal_sir_soa_measure(const void* ctx, abyssal_idx n, abyssal_idx ld, const double* x, const double* p,
                            double* y) {
  const abyssal_soa_measure* m = (const abyssal_soa_measure*)ctx;
  const double* arg[2];
  double* res[1];
  arg[0] = x;
  arg[1] = p;
  res[0] = y;
  return m->h(n, ld, arg, res);
}

/* ------------------------------------------------------------------------------------------ the step's context */
typedef struct {
  double *xa, *xb, *ub, *u, *y, *yd, *nrm, *res, *lk, *lp, *l, *ll, *s, *e, *uni;
  uint32_t* bits;
  idx* anc;
  int u_filled, ub_filled; /* the inputs without input noise are the same for every block: filled once per pass */
} scratch;

typedef struct {
  int m;             /* entries used */
  int rows[ABYSSAL_SIR_MAX_OUTPUTS]; /* (m) their indices in z */
  double* linv;      /* (K, m, m) inverse lower Cholesky factors of the components' covariances on them */
  double* mu;        /* (K, m) the components' means on them */
  double* cst;       /* (K) log weight - log det / 2 - m log(2 pi) / 2 */
} lik_plan;

typedef struct step_ctx {
  const abyssal_sir* s;
  abyssal_sir_in_offsets io;
  abyssal_sir_report_offsets ro;
  block_layout bl;
  idx n, ld, nblocks;
  int T;
  /* this step's buffers */
  const double* x_in;
  double *x_prop, *x_out;
  const double *lw_in, *w_in;
  double *lw_next, *w_next, *rep, *stats, *offsets;
  const double *u, *u_std, *z, *thresholds, *pin_values;
  int n_pins, pin_rows[ABYSSAL_SIR_MAX_STATES];
  double dt_piece;
  int pieces, move, ratio, prior_w, draws;
  uint64_t key, counter;
  lik_plan plan;
  int present_rows[ABYSSAL_SIR_MAX_OUTPUTS], n_present;
  double *tmp_a, *tmp_l; /* n_y x n_y temporaries of thread 0 */
  /* decisions of thread 0, read by every thread after a barrier */
  int mode, status, resample, stage;
  idx next[PHASES]; /* next block of each phase (blocks are handed out one at a time: any thread may take any) */
  double peak, W, log_z, u0, total;
  double* scratch_base;
  idx scratch_stride;
#ifndef ABYSSAL_SIR_NO_THREADS
  int arrived, sense; /* the barrier's count and phase (atomic) */
  pthread_mutex_t lock;
  pthread_cond_t go_cond, barrier_cond;
  int go;
#endif
} step_ctx;

static scratch scratch_of(const step_ctx* c, int t) {
  const abyssal_sir* s = c->s;
  double* p = c->scratch_base + (idx)t * c->scratch_stride;
  scratch sc;
  const int rows = draw_rows(s->n_u, s->rank);
  sc.xa = p; p += (idx)s->n_x * BLOCK;
  sc.xb = p; p += (idx)s->n_x * BLOCK;
  sc.ub = p; p += (idx)s->n_u * BLOCK;
  sc.u = p; p += (rows_at_stride(s->n_u, c->ld) + 7) / 8 * 8;
  sc.y = p; p += (rows_at_stride(y_rows(s->n_y, s->n_extra, s->has_valid), c->ld) + 7) / 8 * 8;
  sc.yd = p; p += (idx)(s->n_y > 0 ? s->n_y : 1) * BLOCK;
  sc.nrm = p; p += (idx)(rows > 0 ? rows : 1) * BLOCK;
  sc.bits = (uint32_t*)p; p += 2 * (idx)BLOCK;
  sc.res = p; p += (idx)(s->n_y > 0 ? s->n_y : 1) * BLOCK;
  sc.lk = p; p += (idx)(s->r_components > 1 ? s->r_components : 1) * BLOCK;
  sc.lp = p; p += BLOCK;
  sc.l = p; p += BLOCK;
  sc.ll = p; p += BLOCK;
  sc.s = p; p += BLOCK;
  sc.e = p; p += BLOCK;
  sc.anc = (idx*)p; p += 2 * BLOCK;
  sc.uni = p;
  sc.u_filled = sc.ub_filled = 0;
  return sc;
}

#ifndef ABYSSAL_SIR_NO_THREADS
/* The threads of a step meet at a barrier a few times per step, and a step can be as short as ~100 us: a thread
 * that arrives first spins on the barrier's phase for up to SPINS checks (~0.1-0.2 ms; a pause between checks,
 * a sched_yield every 64th) before it sleeps on a condition variable (waking a sleeping thread takes tens of
 * microseconds in a virtual machine: sleeping at once, 2 threads took 0.69 of one thread's time at N = 10^4,
 * spinning first 0.55-0.60). The phase flips under the lock, so a thread about to sleep cannot miss it. With
 * the other core busy, 2 threads are slower than one whatever the barrier: the SIR engine's timing then picks 1. */
#define SPINS 2000
static void pause_briefly(void) {
#if defined(__x86_64__) || defined(__i386__)
  __builtin_ia32_pause();
#endif
}
#endif

static void sync_threads(step_ctx* c) {
#ifndef ABYSSAL_SIR_NO_THREADS
  if (c->T <= 1) return;
  const int sense = __atomic_load_n(&c->sense, __ATOMIC_ACQUIRE);
  if (__atomic_add_fetch(&c->arrived, 1, __ATOMIC_ACQ_REL) == c->T) { /* the last: open the barrier */
    __atomic_store_n(&c->arrived, 0, __ATOMIC_RELAXED);
    pthread_mutex_lock(&c->lock);
    __atomic_store_n(&c->sense, !sense, __ATOMIC_RELEASE);
    pthread_cond_broadcast(&c->barrier_cond);
    pthread_mutex_unlock(&c->lock);
    return;
  }
  for (int spins = 0; spins < SPINS; ++spins) {
    if (__atomic_load_n(&c->sense, __ATOMIC_ACQUIRE) != sense) return;
    if (spins % 64 == 63) sched_yield(); else pause_briefly();
  }
  pthread_mutex_lock(&c->lock);
  while (__atomic_load_n(&c->sense, __ATOMIC_ACQUIRE) == sense) pthread_cond_wait(&c->barrier_cond, &c->lock);
  pthread_mutex_unlock(&c->lock);
#else
  (void)c;
#endif
}

/* ------------------------------------------------------------------------------------------ small algebra */
/* Lower Cholesky factor of the m x m matrix a (row-major, stride m) into l; 0 if not positive definite. */
static int cholesky(const double* a, int m, double* l) {
  for (int i = 0; i < m; ++i) {
    for (int j = 0; j <= i; ++j) {
      double v = a[i * m + j];
      for (int k = 0; k < j; ++k) v -= l[i * m + k] * l[j * m + k];
      if (i == j) {
        if (!(v > 0.0) || !isfinite(v)) return 0;
        l[i * m + i] = sqrt(v);
      } else {
        l[i * m + j] = v / l[j * m + j];
      }
    }
    for (int j = i + 1; j < m; ++j) l[i * m + j] = 0.0;
  }
  return 1;
}

/* inverse of a lower-triangular l (m x m) into v (lower) */
static void lower_inverse(const double* l, int m, double* v) {
  for (int j = 0; j < m; ++j) {
    for (int i = 0; i < m; ++i) v[i * m + j] = 0.0;
    v[j * m + j] = 1.0 / l[j * m + j];
    for (int i = j + 1; i < m; ++i) {
      double acc = 0.0;
      for (int k = j; k < i; ++k) acc += l[i * m + k] * v[k * m + j];
      v[i * m + j] = -acc / l[i * m + i];
    }
  }
}

/* numpy's wrap_to_pi: pi - remainder(pi - a, 2 pi) (remainder with the divisor's sign) */
static double wrap_pi(double a) {
  double r = fmod(PI - a, TWO_PI);
  if (r != 0.0 && r < 0.0) r += TWO_PI;
  return PI - r;
}

/* wrap_pi of the entries of r beyond pi (big: the largest |r|). With a fused multiply-add in hardware, vectorised
 * with the same bits: fmod(t, 2 pi) is exact, t - q 2 pi for its quotient q, which one fma then gives exactly;
 * q = trunc(t / 2 pi), less one in magnitude where the rounded division went up across an integer (the first fma's
 * sign tells). Exact integers q need |t| < 2^52 (beyond that, the scalar wrap). */
static void wrap_residuals(double* restrict r, idx nb, double big) {
#ifdef FP_FAST_FMA
  if (big < 0x1p50) {
#pragma omp simd
    for (idx j = 0; j < nb; ++j) {
      const double t = PI - r[j], q0 = trunc(t / TWO_PI), m0 = fma(-q0, TWO_PI, t);
      const double q = t * m0 < 0.0 ? q0 - copysign(1.0, t) : q0; /* (t * m0 neither overflows nor underflows) */
      double m = fma(-q, TWO_PI, t); /* fmod(t, 2 pi) */
      m = m < 0.0 ? m + TWO_PI : m;
      r[j] = fabs(r[j]) > PI ? PI - m : r[j];
    }
    return;
  }
#endif
  (void)big;
  for (idx j = 0; j < nb; ++j)
    if (fabs(r[j]) > PI) r[j] = wrap_pi(r[j]);
}

void abyssal_sir_wrap_residuals(double* r, abyssal_idx n) {
  double big = 0.0;
  for (idx j = 0; j < n; ++j) big = fabs(r[j]) > big ? fabs(r[j]) : big;
  if (big > PI) wrap_residuals(r, n, big);
}

static int is_angle(const abyssal_sir* s, int row) {
  for (int i = 0; i < s->n_angles; ++i)
    if (s->angle_outputs[i] == row) return 1;
  return 0;
}

/* The likelihood plan of the entries rows[0..m-1]: 0 if a component's covariance is not positive definite. */
static int make_plan(step_ctx* c, const int* rows, int m) {
  const abyssal_sir* s = c->s;
  lik_plan* plan = &c->plan;
  double* tmp_a = c->tmp_a;
  double* tmp_l = c->tmp_l;
  const int K = s->r_components, ny = s->n_y;
  plan->m = m;
  for (int i = 0; i < m; ++i) plan->rows[i] = rows[i];
  for (int k = 0; k < K; ++k) {
    const double* cov = s->r_covs + (idx)k * ny * ny;
    for (int i = 0; i < m; ++i)
      for (int j = 0; j < m; ++j) tmp_a[i * m + j] = cov[rows[i] * ny + rows[j]];
    if (!cholesky(tmp_a, m, tmp_l)) return 0;
    double* linv = plan->linv + (idx)k * m * m;
    lower_inverse(tmp_l, m, linv);
    double log_det = 0.0;
    for (int i = 0; i < m; ++i) log_det += 2.0 * log(tmp_l[i * m + i]);
    for (int i = 0; i < m; ++i) plan->mu[k * m + i] = s->r_means[k * ny + rows[i]];
    plan->cst[k] = log(s->r_weights[k]) - 0.5 * log_det - 0.5 * m * log(TWO_PI);
  }
  return 1;
}

/* ------------------------------------------------------------------------------------------ block sums */
/* e = exp(l - peak) over a block; peak = max l (-inf: every weight zero, e = 0); W = sum e, Q = sum e^2. A block
 * of equal log-weights (after resampling) has e = 1 exactly: no exp. */
static void block_weights(const double* restrict l, idx nb, double* restrict e, double* peak_out, double* W_out,
                          double* Q_out) {
  double peak = -INFINITY, low = INFINITY;
#pragma omp simd reduction(max : peak) reduction(min : low)
  for (idx j = 0; j < nb; ++j) {
    peak = l[j] > peak ? l[j] : peak;
    low = l[j] < low ? l[j] : low;
  }
  double W = 0.0, Q = 0.0;
  if (peak == low && peak > -INFINITY) {
#pragma omp simd
    for (idx j = 0; j < nb; ++j) e[j] = 1.0;
    W = Q = (double)nb;
  } else if (peak > -INFINITY) {
#pragma omp simd reduction(+ : W, Q)
    for (idx j = 0; j < nb; ++j) {
      e[j] = exp(l[j] - peak);
      W += e[j];
      Q += e[j] * e[j];
    }
  } else {
    for (idx j = 0; j < nb; ++j) e[j] = 0.0;
  }
  *peak_out = peak;
  *W_out = W;
  if (Q_out) *Q_out = Q;
}

/* the weighted mean of d rows (stride ld) of a block (0 when W = 0) */
static void block_mean(const double* restrict e, double W, idx nb, const double* rows, idx ld, int d, double* mean) {
  for (int r = 0; r < d; ++r) {
    const double* restrict x = rows + (idx)r * ld;
    double acc = 0.0;
#pragma omp simd reduction(+ : acc)
    for (idx j = 0; j < nb; ++j) acc += e[j] * x[j];
    mean[r] = W > 0.0 ? acc / W : 0.0;
  }
}

/* block_moments for d <= 4 in one pass (all sums in registers; rows beyond d read row 0 and are discarded) */
static void block_moments_small(const double* restrict e, double W, idx nb, const double* rows, idx ld, int d,
                                double* mean, double* m2) {
  const double* restrict x0 = rows;
  const double* restrict x1 = d > 1 ? rows + ld : rows;
  const double* restrict x2 = d > 2 ? rows + 2 * ld : rows;
  const double* restrict x3 = d > 3 ? rows + 3 * ld : rows;
  const double c0 = x0[0], c1 = x1[0], c2 = x2[0], c3 = x3[0];
  double s0 = 0, s1 = 0, s2 = 0, s3 = 0, p00 = 0, p01 = 0, p02 = 0, p03 = 0, p11 = 0, p12 = 0, p13 = 0, p22 = 0, p23 = 0,
         p33 = 0;
#pragma omp simd reduction(+ : s0, s1, s2, s3, p00, p01, p02, p03, p11, p12, p13, p22, p23, p33)
  for (idx j = 0; j < nb; ++j) {
    const double d0 = x0[j] - c0, d1 = x1[j] - c1, d2 = x2[j] - c2, d3 = x3[j] - c3, ej = e[j];
    const double e0 = ej * d0, e1 = ej * d1, e2 = ej * d2, e3 = ej * d3;
    s0 += e0; s1 += e1; s2 += e2; s3 += e3;
    p00 += e0 * d0; p01 += e0 * d1; p02 += e0 * d2; p03 += e0 * d3;
    p11 += e1 * d1; p12 += e1 * d2; p13 += e1 * d3;
    p22 += e2 * d2; p23 += e2 * d3;
    p33 += e3 * d3;
  }
  const double c[4] = {c0, c1, c2, c3}, s[4] = {s0, s1, s2, s3};
  const double pr[4][4] = {{p00, p01, p02, p03}, {p01, p11, p12, p13}, {p02, p12, p22, p23}, {p03, p13, p23, p33}};
  idx k = 0;
  for (int r = 0; r < d; ++r) {
    mean[r] = c[r] + s[r] / W;
    for (int q = r; q < d; ++q) m2[k++] = pr[r][q] - s[r] * s[q] / W;
  }
}

/* Weighted mean and packed upper M2 = sum e (x - mean)(x - mean)^T of d rows (stride ld) of a block, in one
 * pass over the rows shifted by the block's first particle (a point of the cloud: the subtraction of the mean's
 * outer product then cancels no more digits than the spread itself has) into dev (d rows of stride BLOCK), then M2
 * from dev in tiles. Nothing when W = 0. */
static void block_moments(const double* restrict e, double W, idx nb, const double* rows, idx ld, int d, double* mean,
                          double* m2, double* dev) {
  if (!(W > 0.0)) {
    for (int r = 0; r < d; ++r) mean[r] = 0.0;
    for (idx k = 0; k < packed(d); ++k) m2[k] = 0.0;
    return;
  }
  if (d <= 4) {
    block_moments_small(e, W, nb, rows, ld, d, mean, m2);
    return;
  }
  double s1[ABYSSAL_SIR_MAX_STATES > ABYSSAL_SIR_MAX_OUTPUTS ? ABYSSAL_SIR_MAX_STATES : ABYSSAL_SIR_MAX_OUTPUTS];
  /* Four sums per loop keep four independent chains of additions in flight (one alone waits for each add); the
   * last group of rows or columns is the last four (d > 4 here), recomputing some with the same bits: each sum
   * runs over the block in the same order whichever group it is in. */
  for (int g = 0; g < d; g += 4) {
    const int r = g + 4 <= d ? g : d - 4;
    const double* restrict x0 = rows + (idx)r * ld;
    const double* restrict x1 = x0 + ld;
    const double* restrict x2 = x1 + ld;
    const double* restrict x3 = x2 + ld;
    double* restrict d0 = dev + (idx)r * BLOCK;
    double* restrict d1 = d0 + BLOCK;
    double* restrict d2 = d1 + BLOCK;
    double* restrict d3 = d2 + BLOCK;
    const double h0 = x0[0], h1 = x1[0], h2 = x2[0], h3 = x3[0]; /* the shifts */
    double a0 = 0.0, a1 = 0.0, a2 = 0.0, a3 = 0.0;
#pragma omp simd reduction(+ : a0, a1, a2, a3)
    for (idx j = 0; j < nb; ++j) {
      const double ej = e[j];
      d0[j] = x0[j] - h0;
      d1[j] = x1[j] - h1;
      d2[j] = x2[j] - h2;
      d3[j] = x3[j] - h3;
      a0 += ej * d0[j];
      a1 += ej * d1[j];
      a2 += ej * d2[j];
      a3 += ej * d3[j];
    }
    const double h[4] = {h0, h1, h2, h3}, a[4] = {a0, a1, a2, a3};
    for (int i = 0; i < 4; ++i) {
      s1[r + i] = a[i];
      mean[r + i] = h[i] + a[i] / W;
    }
  }
  /* M2 in tiles of two rows by four columns (eight sums in flight, each row's weighted deviations formed once per
   * tile); the last pair of rows and the last group of columns are clamped inside d as above, recomputing with the
   * same bits; entries below the diagonal are computed and not stored */
  idx start[ABYSSAL_SIR_MAX_STATES > ABYSSAL_SIR_MAX_OUTPUTS ? ABYSSAL_SIR_MAX_STATES : ABYSSAL_SIR_MAX_OUTPUTS];
  for (int r = 0, k = 0; r < d; k += d - r, ++r) start[r] = k - r; /* packed (r, c), c >= r, at start[r] + c */
  for (int p = 0; p < d; p += 2) {
    const int r = p + 2 <= d ? p : d - 2;
    const double* restrict y0 = dev + (idx)r * BLOCK;
    const double* restrict y1 = y0 + BLOCK;
    for (int c = r; c < d; c += 4) {
      const int c0 = c + 4 <= d ? c : d - 4;
      const double* restrict x0 = dev + (idx)c0 * BLOCK;
      const double* restrict x1 = x0 + BLOCK;
      const double* restrict x2 = x1 + BLOCK;
      const double* restrict x3 = x2 + BLOCK;
      double a0 = 0.0, a1 = 0.0, a2 = 0.0, a3 = 0.0, b0 = 0.0, b1 = 0.0, b2 = 0.0, b3 = 0.0;
#pragma omp simd reduction(+ : a0, a1, a2, a3, b0, b1, b2, b3)
      for (idx j = 0; j < nb; ++j) {
        const double v = e[j] * y0[j], w = e[j] * y1[j];
        a0 += v * x0[j];
        a1 += v * x1[j];
        a2 += v * x2[j];
        a3 += v * x3[j];
        b0 += w * x0[j];
        b1 += w * x1[j];
        b2 += w * x2[j];
        b3 += w * x3[j];
      }
      const double a[2][4] = {{a0, a1, a2, a3}, {b0, b1, b2, b3}};
      for (int i = 0; i < 2; ++i)
        for (int q = 0; q < 4; ++q) {
          const int row = r + i, col = c0 + q;
          if (col >= row) m2[start[row] + col] = a[i][q] - s1[row] * s1[col] / W;
        }
    }
  }
}

/* 0 when every entry of the d rows (stride ld) of a block lies in [-bound, bound] (NaN does not) */
static int outside_rows(const double* rows, int d, idx ld, idx nb, double bound) {
  double count = 0.0;
  for (int r = 0; r < d; ++r) {
    const double* restrict x = rows + (idx)r * ld;
#pragma omp simd reduction(+ : count)
    for (idx j = 0; j < nb; ++j) count += fabs(x[j]) <= bound ? 0.0 : 1.0;
  }
  return count != 0.0;
}

/* 0 when every entry of the d rows (stride ld) of a block is finite */
static int nonfinite_rows(const double* rows, int d, idx ld, idx nb) {
  double check = 0.0; /* x - x is NaN exactly when x is inf or NaN */
  for (int r = 0; r < d; ++r) {
    const double* restrict x = rows + (idx)r * ld;
#pragma omp simd reduction(+ : check)
    for (idx j = 0; j < nb; ++j) check += x[j] - x[j];
  }
  return check != 0.0;
}

/* ------------------------------------------------------------------------------------------ the block pass */
/* Per-particle inputs of a block into rows of the given stride: u + u_std n (input noise), or u in every column
 * (filled once per pass: *filled). */
static void fill_inputs(const step_ctx* c, const scratch* sc, double* u, idx ld, idx nb, int* filled) {
  const abyssal_sir* s = c->s;
  for (int r = 0; r < s->n_u; ++r) {
    double* restrict ur = u + (idx)r * ld;
    const double mean = c->u[r];
    if (s->input_noise) {
      const double sd = c->u_std[r];
      const double* restrict noise = sc->nrm + (idx)r * BLOCK;
#pragma omp simd
      for (idx j = 0; j < nb; ++j) ur[j] = mean + sd * noise[j];
    } else if (!*filled) {
#pragma omp simd
      for (idx j = 0; j < BLOCK; ++j) ur[j] = mean;
    }
  }
  *filled = !s->input_noise;
}

/* x_k = f(x_{k-1}, u) + w of the block's particles, written into the proposals (x_prop + j0, stride ld): the
 * kernel reads the committed particles and writes the proposals itself; with substeps it ping-pongs between the
 * thread's xa and xb (stride BLOCK). Returns a status. */
static int move_block(const step_ctx* c, scratch* sc, idx j0, idx nb) {
  const abyssal_sir* s = c->s;
  const int nx = s->n_x;
  const idx ld = c->ld;
  double* x = c->x_prop + j0;
  if (c->draws > 0) normals_block(c->key, c->counter, 0, j0, nb, 0, c->draws, sc->nrm, BLOCK, sc->bits);
  const double* arg[4];
  double* res[1];
  arg[2] = s->p;
  arg[3] = &c->dt_piece;
  if (c->pieces == 1) {
    fill_inputs(c, sc, sc->u, ld, nb, &sc->u_filled);
    arg[0] = c->x_in + j0;
    arg[1] = sc->u;
    res[0] = x;
    if (s->f(nb, ld, arg, res)) return ABYSSAL_SIR_MODEL_FAILED;
  } else {
    fill_inputs(c, sc, sc->ub, BLOCK, nb, &sc->ub_filled);
    for (int r = 0; r < nx; ++r) memcpy(sc->xa + (idx)r * BLOCK, c->x_in + (idx)r * ld + j0, (size_t)nb * sizeof(double));
    double* from = sc->xa;
    double* to = sc->xb;
    arg[1] = sc->ub;
    for (int piece = 0; piece < c->pieces; ++piece) {
      arg[0] = from;
      res[0] = to;
      if (s->f(nb, BLOCK, arg, res)) return ABYSSAL_SIR_MODEL_FAILED;
      double* tmp = from;
      from = to;
      to = tmp;
    }
    for (int r = 0; r < nx; ++r) memcpy(x + (idx)r * ld, from + (idx)r * BLOCK, (size_t)nb * sizeof(double));
  }
  /* process noise */
  const double* restrict y = sc->nrm + (idx)(s->input_noise ? s->n_u : 0) * BLOCK;
  if (s->q_components > 1) {
    double* restrict uni = sc->uni;
    uniforms_block(c->key, c->counter, 1, j0, nb, uni);
    for (int k = 0; k < s->q_components; ++k) {
      const double lo = k == 0 ? 0.0 : s->q_cumulative[k - 1];
      const double hi = k == s->q_components - 1 ? 2.0 : s->q_cumulative[k];
      const double* mean = s->q_means + (idx)k * nx;
      const double* L = s->q_factors + (idx)k * nx * nx;
      for (int r = 0; r < nx; ++r) {
        double* restrict xr = x + (idx)r * ld;
        for (idx j = 0; j < nb; ++j) {
          if (!(uni[j] >= lo && uni[j] < hi)) continue;
          double acc = mean[r];
          for (int q = 0; q <= r; ++q) acc += L[r * nx + q] * y[(idx)q * BLOCK + j];
          xr[j] += acc;
        }
      }
    }
  } else if (s->support) {
    for (int q = 0; q < s->rank; ++q) {
      double* restrict xr = x + (idx)s->support[q] * ld;
      const double* restrict yq = y + (idx)q * BLOCK;
      const double sd = s->factor[q];
#pragma omp simd
      for (idx j = 0; j < nb; ++j) xr[j] += sd * yq[j];
    }
  } else {
    for (int r = 0; r < nx; ++r) {
      double* restrict xr = x + (idx)r * ld;
      for (int q = 0; q < s->rank; ++q) {
        const double a = s->factor[(idx)r * s->rank + q];
        if (a == 0.0) continue;
        const double* restrict yq = y + (idx)q * BLOCK;
#pragma omp simd
        for (idx j = 0; j < nb; ++j) xr[j] += a * yq[j];
      }
    }
  }
  if (s->noise_mean && s->q_components <= 1) {
    for (int r = 0; r < nx; ++r) {
      const double m = s->noise_mean[r];
      if (m == 0.0) continue;
      double* restrict xr = x + (idx)r * ld;
#pragma omp simd
      for (idx j = 0; j < nb; ++j) xr[j] += m;
    }
  }
  return ABYSSAL_SIR_OK;
}

/* log-likelihood of the plan's entries at the block's particles (y in sc->y) into sc->ll */
/* the residuals z - h(x) of the plan's entries into sc->res (rows in plan order, stride BLOCK), an angle entry's
 * wrapped to (-pi, pi] where it lies beyond */
static void residuals_block(const step_ctx* c, const scratch* sc, idx nb) {
  const abyssal_sir* s = c->s;
  const lik_plan* plan = &c->plan;
  for (int i = 0; i < plan->m; ++i) {
    const int row = plan->rows[i];
    const double z = c->z[row];
    const double* restrict y = sc->y + (idx)row * c->ld;
    double* restrict r = sc->res + (idx)i * BLOCK;
    double big = 0.0;
#pragma omp simd reduction(max : big)
    for (idx j = 0; j < nb; ++j) {
      r[j] = z - y[j];
      const double a = fabs(r[j]);
      big = a > big ? a : big;
    }
    if (big > PI && is_angle(s, row)) wrap_residuals(r, nb, big);
  }
}

/* One component's log-density cst - |L^-1 (r - mu)|^2 / 2 of m <= 4 entries (residual rows of stride BLOCK) into
 * q, in one pass with every row in registers. The same sums in the same order as the row-by-row loop below (a zero
 * of L^-1 adds a signed zero to t, which squaring forgets; rows beyond m have zeros and add +0 to q), so both give
 * the same bits; a diagonal L^-1 skips the zero products. */
static void component_small(const double* res, int m, const double* linv, const double* mu, double cst, idx nb,
                            double* restrict q) {
  double v[4][4] = {{0.0}}, shift[4] = {0.0};
  int diagonal = 1;
  for (int i = 0; i < m; ++i) {
    shift[i] = mu[i];
    for (int a = 0; a <= i; ++a) {
      v[i][a] = linv[i * m + a];
      if (a < i && v[i][a] != 0.0) diagonal = 0;
    }
  }
  const double* restrict r0 = res;
  const double* restrict r1 = m > 1 ? res + BLOCK : res;
  const double* restrict r2 = m > 2 ? res + 2 * BLOCK : res;
  const double* restrict r3 = m > 3 ? res + 3 * BLOCK : res;
  const double v00 = v[0][0], v10 = v[1][0], v11 = v[1][1], v20 = v[2][0], v21 = v[2][1], v22 = v[2][2], v30 = v[3][0],
               v31 = v[3][1], v32 = v[3][2], v33 = v[3][3];
  const double m0 = shift[0], m1 = shift[1], m2 = shift[2], m3 = shift[3];
  if (diagonal) {
#pragma omp simd
    for (idx j = 0; j < nb; ++j) {
      const double t0 = v00 * (r0[j] - m0), t1 = v11 * (r1[j] - m1), t2 = v22 * (r2[j] - m2), t3 = v33 * (r3[j] - m3);
      double acc = t0 * t0;
      acc += t1 * t1;
      acc += t2 * t2;
      acc += t3 * t3;
      q[j] = cst - 0.5 * acc;
    }
  } else {
#pragma omp simd
    for (idx j = 0; j < nb; ++j) {
      const double d0 = r0[j] - m0, d1 = r1[j] - m1, d2 = r2[j] - m2, d3 = r3[j] - m3;
      double t1 = v10 * d0, t2 = v20 * d0, t3 = v30 * d0;
      t1 += v11 * d1;
      t2 += v21 * d1;
      t2 += v22 * d2;
      t3 += v31 * d1;
      t3 += v32 * d2;
      t3 += v33 * d3;
      const double t0 = v00 * d0;
      double acc = t0 * t0;
      acc += t1 * t1;
      acc += t2 * t2;
      acc += t3 * t3;
      q[j] = cst - 0.5 * acc;
    }
  }
}

/* log-likelihood of the plan's entries at the block's particles (residuals in sc->res) into sc->ll */
static void likelihood_block(const step_ctx* c, const scratch* sc, idx nb) {
  const abyssal_sir* s = c->s;
  const lik_plan* plan = &c->plan;
  const int m = plan->m, K = s->r_components;
  if (m == 1 && K == 1) { /* one Gaussian entry (a depth, a range): one pass */
    const double v = plan->linv[0], shift = plan->mu[0], cst = plan->cst[0];
    const double* restrict r = sc->res;
    double* restrict ll = sc->ll;
    if (s->has_valid) {
      const double* restrict valid = sc->y + (idx)(s->n_y + s->n_extra) * c->ld;
      const double out = s->invalid_log_lik;
#pragma omp simd
      for (idx j = 0; j < nb; ++j) {
        const double q = v * (r[j] - shift);
        ll[j] = valid[j] != 0.0 ? cst - 0.5 * q * q : out;
      }
    } else {
#pragma omp simd
      for (idx j = 0; j < nb; ++j) {
        const double q = v * (r[j] - shift);
        ll[j] = cst - 0.5 * q * q;
      }
    }
    return;
  }
  for (int k = 0; k < K; ++k) {
    double* restrict q = K > 1 ? sc->lk + (idx)k * BLOCK : sc->ll;
    const double* linv = plan->linv + (idx)k * m * m;
    const double* mu = plan->mu + (idx)k * m;
    if (m <= 4) {
      component_small(sc->res, m, linv, mu, plan->cst[k], nb, q);
      continue;
    }
    double* restrict t = sc->s;
    for (int i = 0; i < m; ++i) { /* q = |L^-1 (r - mu)|^2, row by row of L^-1 */
      {
        const double v = linv[i * m], shift = mu[0];
        const double* restrict r = sc->res;
#pragma omp simd
        for (idx j = 0; j < nb; ++j) t[j] = v * (r[j] - shift);
      }
      for (int a = 1; a <= i; ++a) {
        const double v = linv[i * m + a], shift = mu[a];
        if (v == 0.0) continue; /* (a diagonal covariance: one product per entry) */
        const double* restrict r = sc->res + (idx)a * BLOCK;
#pragma omp simd
        for (idx j = 0; j < nb; ++j) t[j] += v * (r[j] - shift);
      }
      if (i == 0) {
#pragma omp simd
        for (idx j = 0; j < nb; ++j) q[j] = t[j] * t[j];
      } else {
#pragma omp simd
        for (idx j = 0; j < nb; ++j) q[j] += t[j] * t[j];
      }
    }
    const double cst = plan->cst[k];
#pragma omp simd
    for (idx j = 0; j < nb; ++j) q[j] = cst - 0.5 * q[j];
  }
  if (K == 2) { /* log(exp(a) + exp(b)) = max + log(1 + exp(-|a - b|)): one exp and one log per particle */
    const double* restrict a = sc->lk;
    const double* restrict b = sc->lk + BLOCK;
    double* restrict top = sc->ll;
    double* restrict rest = sc->s;
#pragma omp simd
    for (idx j = 0; j < nb; ++j) {
      const double hi = a[j] > b[j] ? a[j] : b[j], lo = a[j] > b[j] ? b[j] : a[j];
      top[j] = hi;
      rest[j] = hi > -INFINITY ? lo - hi : -INFINITY; /* (both -inf: the sum is 0) */
    }
#pragma omp simd
    for (idx j = 0; j < nb; ++j) rest[j] = log(1.0 + exp(rest[j]));
#pragma omp simd
    for (idx j = 0; j < nb; ++j) top[j] += rest[j];
  } else if (K > 1) { /* log sum_k exp(lk_k), per particle, component by component (vectorised over particles) */
    double* restrict top = sc->ll;
    double* restrict sum = sc->s;
    memcpy(top, sc->lk, (size_t)nb * sizeof(double));
    for (int k = 1; k < K; ++k) {
      const double* restrict lk = sc->lk + (idx)k * BLOCK;
#pragma omp simd
      for (idx j = 0; j < nb; ++j) top[j] = lk[j] > top[j] ? lk[j] : top[j];
    }
#pragma omp simd
    for (idx j = 0; j < nb; ++j) { /* every component -inf: then sum = 0 and the result -inf */
      top[j] = top[j] > -INFINITY ? top[j] : 0.0;
      sum[j] = 0.0;
    }
    for (int k = 0; k < K; ++k) {
      const double* restrict lk = sc->lk + (idx)k * BLOCK;
#pragma omp simd
      for (idx j = 0; j < nb; ++j) sum[j] += exp(lk[j] - top[j]);
    }
#pragma omp simd
    for (idx j = 0; j < nb; ++j) top[j] += log(sum[j]);
  }
  if (s->has_valid) {
    const double* restrict valid = sc->y + (idx)(s->n_y + s->n_extra) * c->ld;
    double* restrict ll = sc->ll;
    const double out = s->invalid_log_lik;
#pragma omp simd
    for (idx j = 0; j < nb; ++j) ll[j] = valid[j] != 0.0 ? ll[j] : out;
  }
}

static void block_pass(step_ctx* c, scratch* sc, idx b, int mode) {
  const abyssal_sir* s = c->s;
  const idx n = c->n, ld = c->ld, j0 = b * BLOCK, nb = n - j0 < BLOCK ? n - j0 : BLOCK;
  const int nx = s->n_x;
  double* st = c->stats + b * c->bl.stride;
  double* x = c->x_prop + j0; /* the block's particles: rows of stride ld */
  int status = ABYSSAL_SIR_OK;
  st[c->bl.status] = 0.0;
  if (mode & MODE_MOVE) {
    if (c->move == ABYSSAL_SIR_MOVE_TRANSITION)
      status = move_block(c, sc, j0, nb);
    else if (c->move == ABYSSAL_SIR_MOVE_NONE)
      for (int r = 0; r < nx; ++r) memcpy(x + (idx)r * ld, c->x_in + (idx)r * ld + j0, (size_t)nb * sizeof(double));
    for (int i = 0; i < c->n_pins; ++i) {
      double* restrict xr = x + (idx)c->pin_rows[i] * ld;
      const double v = c->pin_values[i];
      for (idx j = 0; j < nb; ++j) xr[j] = v;
    }
  }
  if (status == ABYSSAL_SIR_OK && outside_rows(x, nx, ld, nb, s->max_abs)) status = ABYSSAL_SIR_NONFINITE_PARTICLE;
  if (status != ABYSSAL_SIR_OK) {
    st[c->bl.status] = status;
    return;
  }
  /* prior log-weights: the committed ones, plus a proposal's log ratios (in scratch when a sum or exp needs them:
   * those run on aligned scratch only) */
  const double* lp = c->lw_in + j0;
  const int prior_exp = (mode & (MODE_YMEAN | MODE_YM2)) && !c->prior_w;
  if (c->ratio) {
    const double* restrict lw = c->lw_in + j0;
    const double* restrict lr = s->log_ratio + j0;
    double* restrict sum = sc->lp;
#pragma omp simd
    for (idx j = 0; j < nb; ++j) sum[j] = lw[j] + lr[j];
    lp = sc->lp;
  } else if (prior_exp) {
    memcpy(sc->lp, lp, (size_t)nb * sizeof(double));
    lp = sc->lp;
  }
  const int yr = y_rows(s->n_y, s->n_extra, s->has_valid);
  if (mode & MODE_H) {
    if (s->h(s->h_ctx, nb, ld, x, s->p, sc->y)) {
      st[c->bl.status] = ABYSSAL_SIR_MODEL_FAILED;
      return;
    }
    if (nonfinite_rows(sc->y, yr, ld, nb)) {
      st[c->bl.status] = ABYSSAL_SIR_NONFINITE_MEASUREMENT;
      return;
    }
  }
  /* posterior log-weights l = lp (+ log-likelihood) into scratch and into lw_next (normalised later); NaN or +inf
   * is an error (a -inf is a zero weight) */
  double* restrict l = sc->l;
  double* restrict l_out = c->lw_next + j0;
  double bad = 0.0;
  if (mode & (MODE_LIK | MODE_YMEAN | MODE_YM2)) residuals_block(c, sc, nb);
  if (mode & MODE_LIK) {
    likelihood_block(c, sc, nb);
    const double* restrict ll = sc->ll;
    const double* restrict prior = lp;
    double max_ll = -INFINITY;
#pragma omp simd reduction(max : max_ll) reduction(+ : bad)
    for (idx j = 0; j < nb; ++j) {
      const double v = prior[j] + ll[j];
      l[j] = v;
      l_out[j] = v;
      max_ll = ll[j] > max_ll ? ll[j] : max_ll;
      bad += (v != v || v == INFINITY) ? 1.0 : 0.0;
    }
    st[c->bl.max_ll] = max_ll;
  } else if (mode & MODE_POST) {
    const double* restrict prior = lp;
#pragma omp simd reduction(+ : bad)
    for (idx j = 0; j < nb; ++j) {
      const double v = prior[j];
      l[j] = v;
      l_out[j] = v;
      bad += (v != v || v == INFINITY) ? 1.0 : 0.0;
    }
    st[c->bl.max_ll] = -INFINITY;
  }
  if (mode & (MODE_YMEAN | MODE_YM2)) { /* the cloud's mean residual (z - its predicted measurement) and spread */
    double W = 0.0;
    if (c->prior_w) { /* the committed weights themselves (exp(log_w) with peak 0), through aligned scratch */
      double* restrict e = sc->e;
      memcpy(e, c->w_in + j0, (size_t)nb * sizeof(double));
#pragma omp simd reduction(+ : W)
      for (idx j = 0; j < nb; ++j) W += e[j];
      st[c->bl.prior_peak] = 0.0;
    } else {
      block_weights(lp, nb, sc->e, st + c->bl.prior_peak, &W, NULL);
    }
    st[c->bl.prior_W] = W;
    if (mode & MODE_YM2)
      block_moments(sc->e, W, nb, sc->res, BLOCK, c->plan.m, st + c->bl.ybar, st + c->bl.m2y, sc->yd);
    else
      block_mean(sc->e, W, nb, sc->res, BLOCK, c->plan.m, st + c->bl.ybar);
  }
  if (!(mode & MODE_POST)) return;
  if (bad != 0.0) {
    st[c->bl.status] = ABYSSAL_SIR_NONFINITE_WEIGHT;
    return;
  }
  double W;
  block_weights(l, nb, sc->e, st + c->bl.peak, &W, st + c->bl.Q);
  st[c->bl.W] = W;
  memcpy(c->w_next + j0, sc->e, (size_t)nb * sizeof(double)); /* exp(l - the block's peak): normalised later */
  block_moments(sc->e, W, nb, x, ld, nx, st + c->bl.mean, st + c->bl.m2, sc->xa);
  block_mean(sc->e, W, nb, sc->y + (idx)s->n_y * ld, ld, s->n_extra, st + c->bl.extra);
}

/* Combine the blocks' sums of d rows (mean at offset `mo`, packed M2 at `m2o`, weights peak/W at `po`/`wo`):
 * the global peak, W = sum exp(l - peak), mean and covariance (full, row-major); Q likewise when qo >= 0. */
static void combine(const step_ctx* c, idx po, idx wo, idx qo, idx mo, idx m2o, int d, double* peak_out, double* W_out,
                    double* Q_out, double* mean, double* cov, idx eo, int n_extra, double* extra) {
  const double* stats = c->stats;
  const idx stride = c->bl.stride;
  double peak = -INFINITY;
  for (idx b = 0; b < c->nblocks; ++b) {
    const double p = stats[b * stride + po];
    peak = p > peak ? p : peak;
  }
  double W = 0.0, Q = 0.0;
  for (int r = 0; r < d; ++r) mean[r] = 0.0;
  for (int r = 0; r < n_extra; ++r) extra[r] = 0.0;
  if (peak > -INFINITY) {
    for (idx b = 0; b < c->nblocks; ++b) {
      const double* st = stats + b * stride;
      if (!(st[po] > -INFINITY)) continue;
      const double scale = exp(st[po] - peak), wb = scale * st[wo];
      W += wb;
      if (qo >= 0) Q += scale * scale * st[qo];
      for (int r = 0; r < d; ++r) mean[r] += wb * st[mo + r];
      for (int r = 0; r < n_extra; ++r) extra[r] += wb * st[eo + r];
    }
    for (int r = 0; r < d; ++r) mean[r] /= W;
    for (int r = 0; r < n_extra; ++r) extra[r] /= W;
  }
  if (cov) {
    for (idx k = 0; k < (idx)d * d; ++k) cov[k] = 0.0;
    if (peak > -INFINITY) {
      for (idx b = 0; b < c->nblocks; ++b) {
        const double* st = stats + b * stride;
        if (!(st[po] > -INFINITY)) continue;
        const double scale = exp(st[po] - peak), wb = scale * st[wo];
        idx k = 0;
        for (int r = 0; r < d; ++r) {
          const double dr = st[mo + r] - mean[r];
          for (int q = r; q < d; ++q) cov[r * d + q] += scale * st[m2o + k++] + wb * dr * (st[mo + q] - mean[q]);
        }
      }
      for (int r = 0; r < d; ++r)
        for (int q = r; q < d; ++q) {
          cov[r * d + q] /= W;
          cov[q * d + r] = cov[r * d + q];
        }
    }
  }
  *peak_out = peak;
  *W_out = W;
  if (Q_out) *Q_out = Q;
}

static int first_error(const step_ctx* c) {
  for (idx b = 0; b < c->nblocks; ++b) {
    const int status = (int)c->stats[b * c->bl.stride + c->bl.status];
    if (status) return status;
  }
  return ABYSSAL_SIR_OK;
}

/* ------------------------------------------------------------------------------------------ the gate */
/* nu^T S^-1 nu <= threshold over the entries rows[0..m-1] (S from the full n_y x n_y matrix) */
static int gate_passes(const double* nu, const double* S, int ny, const int* rows, int m, double threshold, double* a,
                       double* l) {
  if (!(threshold < INFINITY)) return 1;
  for (int i = 0; i < m; ++i)
    for (int j = 0; j < m; ++j) a[i * m + j] = S[rows[i] * ny + rows[j]];
  if (!cholesky(a, m, l)) return 0;
  double nis = 0.0;
  double v[ABYSSAL_SIR_MAX_OUTPUTS];
  for (int i = 0; i < m; ++i) { /* forward substitution: L v = nu */
    double acc = nu[rows[i]];
    for (int k = 0; k < i; ++k) acc -= l[i * m + k] * v[k];
    v[i] = acc / l[i * m + i];
    nis += v[i] * v[i];
  }
  return isfinite(nis) && nis <= threshold;
}

/* InnovationGate.select (runtime/filters/kalman/gate.py) on the present entries: the entries used (rows, count),
 * gated[] flags the entries left out. */
static int gate_select(const step_ctx* c, const double* nu, const double* S, int* rows, int m, double* gated, double* a,
                       double* l) {
  const abyssal_sir* s = c->s;
  const int ny = s->n_y;
  const double* thr = c->thresholds;
  for (int attempt = 0; attempt < 2; ++attempt) {
    if (gate_passes(nu, S, ny, rows, m, thr[m], a, l)) return m;
    int outliers = 0;
    for (int i = 0; i < m; ++i) {
      const int r = rows[i];
      if (!(nu[r] * nu[r] <= thr[1] * S[r * ny + r])) ++outliers; /* NaN and inf count as outliers */
    }
    if (outliers == 0 || outliers == m) break;
    int kept = 0;
    for (int i = 0; i < m; ++i) {
      const int r = rows[i];
      if (!(nu[r] * nu[r] <= thr[1] * S[r * ny + r]))
        gated[r] = 1.0;
      else
        rows[kept++] = r;
    }
    m = kept;
  }
  for (int i = 0; i < m; ++i) gated[rows[i]] = 1.0;
  return 0;
}

/* ------------------------------------------------------------------------------------------ thread 0's decisions */
/* The stages of the weighing, decided by thread 0 after each block pass (next_pass). Usually one pass does all:
 * the move, the likelihood of every present entry, the prior-weighted mean of y and the posterior's sums, and
 * the gate's bound (S >= R, so nu^T R^-1 nu <= threshold passes without S) settles it. Otherwise a pass forms S,
 * the gate selects the entries (gate_select), and a pass weighs again without the entries it left out; a pass
 * without the likelihood follows when every likelihood underflowed. */
enum { STAGE_FIRST, STAGE_S, STAGE_REWEIGHED, STAGE_KEPT };

/* nu^T R^-1 nu <= threshold over the present entries (R their measurement covariance, S >= R) */
static int gate_bound_passes(step_ctx* c, const double* nu) {
  const abyssal_sir* s = c->s;
  const int m = c->n_present;
  double* a = c->tmp_a;
  double* l = c->tmp_l;
  const double threshold = c->thresholds[m];
  for (int i = 0; i < m; ++i)
    for (int j = 0; j < m; ++j) a[i * m + j] = s->R[c->present_rows[i] * s->n_y + c->present_rows[j]];
  if (!cholesky(a, m, l)) return 0;
  double q = 0.0, v[ABYSSAL_SIR_MAX_OUTPUTS];
  for (int i = 0; i < m; ++i) {
    double acc = nu[c->present_rows[i]];
    for (int k = 0; k < i; ++k) acc -= l[i * m + k] * v[k];
    v[i] = acc / l[i * m + i];
    q += v[i] * v[i];
  }
  return q <= threshold;
}

/* the mode of the pass that weighs again with the likelihood plan's entries (none: no likelihood) */
static int reweigh_mode(const step_ctx* c) {
  const abyssal_sir* s = c->s;
  return (c->plan.m > 0 ? MODE_H | MODE_LIK : ((s->n_extra || s->has_valid) ? MODE_H : 0)) | MODE_POST;
}

static double max_log_lik(const step_ctx* c) {
  double top = -INFINITY;
  for (idx b = 0; b < c->nblocks; ++b) {
    const double v = c->stats[b * c->bl.stride + c->bl.max_ll];
    top = v > top ? v : top;
  }
  return top;
}

/* the last weighing stands unless every likelihood underflowed: then a pass keeps the weights */
static int underflow_check(step_ctx* c) {
  double* rep = c->rep;
  const int used = c->plan.m;
  const double top = used ? max_log_lik(c) : -INFINITY;
  rep[ABYSSAL_SIR_R_MAX_LOG_LIK] = top;
  rep[ABYSSAL_SIR_R_USED] = used;
  rep[ABYSSAL_SIR_R_UNINFORMATIVE] = used && !(top >= log(DBL_MIN));
  if (rep[ABYSSAL_SIR_R_UNINFORMATIVE] == 0.0) return 0;
  c->plan.m = 0;
  c->stage = STAGE_KEPT;
  return reweigh_mode(c);
}

/* After a block pass (thread 0): the mode of the next one, 0 when the weighing is done. */
static int next_pass(step_ctx* c) {
  const abyssal_sir* s = c->s;
  const int ny = s->n_y;
  double* rep = c->rep;
  double* gated = rep + c->ro.gated;
  double* nu = rep + c->ro.nu;
  double* S = rep + c->ro.S;
  double peak, W;
  switch (c->stage) {
    case STAGE_FIRST: {
      for (int i = 0; i < ny; ++i) gated[i] = 0.0;
      for (idx k = 0; k < (idx)ny + (idx)ny * ny; ++k) rep[c->ro.nu + k] = 0.0;
      rep[ABYSSAL_SIR_R_GATED] = 0.0;
      if (!(c->mode & MODE_YMEAN)) return underflow_check(c);
      /* nu = the prior-weighted mean residual - E[v] (residuals of the present entries, in their order) */
      double* rbar = c->tmp_a;
      const int m = c->n_present;
      combine(c, c->bl.prior_peak, c->bl.prior_W, -1, c->bl.ybar, c->bl.m2y, m, &peak, &W, NULL, rbar, NULL, 0, 0, NULL);
      for (int i = 0; i < m; ++i) nu[c->present_rows[i]] = rbar[i] - s->R_mean[c->present_rows[i]];
      if (gate_bound_passes(c, nu)) return underflow_check(c);
      c->stage = STAGE_S;
      return MODE_H | MODE_YM2;
    }
    case STAGE_S: {
      /* S = the prior-weighted spread of the residuals + R */
      double* rbar = c->tmp_a;
      double* crr = c->tmp_l;
      const int m_p = c->n_present;
      combine(c, c->bl.prior_peak, c->bl.prior_W, -1, c->bl.ybar, c->bl.m2y, m_p, &peak, &W, NULL, rbar, crr, 0, 0, NULL);
      for (int i = 0; i < m_p; ++i) {
        const int r = c->present_rows[i];
        for (int j = 0; j < m_p; ++j) {
          const int q = c->present_rows[j];
          S[r * ny + q] = crr[i * m_p + j] + s->R[r * ny + q];
        }
      }
      int rows[ABYSSAL_SIR_MAX_OUTPUTS];
      for (int i = 0; i < c->n_present; ++i) rows[i] = c->present_rows[i];
      const int m = gate_select(c, nu, S, rows, c->n_present, gated, c->tmp_a, c->tmp_l);
      int n_gated = 0;
      for (int i = 0; i < ny; ++i) n_gated += gated[i] != 0.0;
      rep[ABYSSAL_SIR_R_GATED] = n_gated;
      if (n_gated == 0) return underflow_check(c); /* the first pass's weighing stands */
      c->plan.m = 0;
      if (m > 0 && !make_plan(c, rows, m)) {
        c->status = ABYSSAL_SIR_BAD_ARGUMENT;
        return 0;
      }
      c->stage = STAGE_REWEIGHED;
      return reweigh_mode(c);
    }
    case STAGE_REWEIGHED:
      return underflow_check(c);
    default:
      return 0;
  }
}

/* The next block of this phase for the calling thread (nblocks: none left). Blocks are handed out on demand, so
 * a thread slowed by a busy core takes fewer; a block's results do not depend on which thread computes it. */
static idx grab(step_ctx* c, int phase) {
#ifndef ABYSSAL_SIR_NO_THREADS
  if (c->T > 1) return __atomic_fetch_add(&c->next[phase], 1, __ATOMIC_RELAXED);
#endif
  return c->next[phase]++;
}

static void run_blocks(step_ctx* c, int t, int mode, int phase) {
  scratch sc = scratch_of(c, t);
  for (idx b = grab(c, phase); b < c->nblocks; b = grab(c, phase)) block_pass(c, &sc, b, mode);
}

/* Normalised weights: the block pass left exp(l - the block's peak) in w_next (computed on aligned scratch:
 * a vectorised loop's alignment peeling sends some elements through the scalar exp, which may differ from the
 * vector one by an ulp, and results must not depend on the alignment of the caller's buffers); one factor per
 * block scales them. A block's weight sum (for resampling's offsets) is that factor times its W. */
static void normalise_blocks(step_ctx* c, int phase) {
  const double peak = c->peak, inv_W = 1.0 / c->W, log_z = c->log_z;
  for (idx b = grab(c, phase); b < c->nblocks; b = grab(c, phase)) {
    const idx j0 = b * BLOCK, nb = c->n - j0 < BLOCK ? c->n - j0 : BLOCK;
    double* st = c->stats + b * c->bl.stride;
    const double factor = st[c->bl.peak] > -INFINITY ? exp(st[c->bl.peak] - peak) * inv_W : 0.0;
    double* restrict lw = c->lw_next + j0;
    double* restrict w = c->w_next + j0;
#pragma omp simd
    for (idx j = 0; j < nb; ++j) {
      w[j] *= factor;
      lw[j] -= log_z;
    }
    st[c->bl.w_sum] = factor * st[c->bl.W];
  }
}

/* Ancestors of outputs k0..k0+nk-1: the particle j where the cumulative weight first exceeds the target
 * (k + u_k) total / n; the cumulative weight inside block b is offsets[b] + the running sum of the block. */
static idx first_ancestor(const step_ctx* c, double target, double* cum_out) {
  const double* restrict w = c->w_next;
  const double* off = c->offsets;
  idx b = 0, top = c->nblocks - 1; /* the first block whose cumulative end exceeds the target */
  while (b < top) {
    const idx mid = (b + top) / 2;
    if (off[mid + 1] > target) top = mid; else b = mid + 1;
  }
  idx j = b * BLOCK;
  double cum = off[b] + w[j];
  while (cum <= target && j < c->n - 1) {
    ++j;
    cum = (j % BLOCK == 0) ? off[j / BLOCK] + w[j] : cum + w[j];
  }
  *cum_out = cum;
  return j;
}

/* Systematic: the targets are evenly spaced, so particle j is the ancestor of the outputs k with
 * e_{j-1} <= k < e_j, e_j = ceil(cum_j / step - u0): a marker at e_{j-1} for every particle (in order: of the
 * particles sharing one, the last, the one with copies, stays) and a running maximum give every output its
 * ancestor without a branch per particle. */
static void systematic_ancestors(const step_ctx* c, idx k0, idx nk, idx* restrict anc) {
  const double* restrict w = c->w_next;
  const double* off = c->offsets;
  const double step = c->total / (double)c->n, u0 = c->u0;
  double cum;
  idx j = first_ancestor(c, ((double)k0 + u0) * step, &cum);
  for (idx k = 0; k <= nk; ++k) anc[k] = 0;
  anc[0] = j;
  const idx last = c->n - 1;
  while (j < last) {
    /* outputs before e_j have ancestors <= j; the next particle starts at e_j */
    const double e = ceil(cum / step - u0) - (double)k0;
    if (!(e < (double)nk)) break;
    ++j;
    anc[e > 1.0 ? (idx)e : 1] = j; /* (e >= 1 but for rounding: output k0 is j's predecessor's) */
    cum = (j % BLOCK == 0) ? off[j / BLOCK] + w[j] : cum + w[j];
  }
  for (idx k = 1; k < nk; ++k) anc[k] = anc[k] > anc[k - 1] ? anc[k] : anc[k - 1];
}

/* Stratified: a target per output, walked. */
static void stratified_ancestors(const step_ctx* c, idx k0, idx nk, const double* restrict u, idx* restrict anc) {
  const double* restrict w = c->w_next;
  const double* off = c->offsets;
  const double step = c->total / (double)c->n;
  double cum;
  idx j = first_ancestor(c, ((double)k0 + u[0]) * step, &cum);
  for (idx k = 0; k < nk; ++k) {
    const double target = ((double)(k0 + k) + u[k]) * step;
    while (cum <= target && j < c->n - 1) {
      ++j;
      cum = (j % BLOCK == 0) ? off[j / BLOCK] + w[j] : cum + w[j];
    }
    anc[k] = j;
  }
}

static void gather_blocks(step_ctx* c, int t, int phase) {
  const abyssal_sir* s = c->s;
  const scratch sc = scratch_of(c, t);
  const idx n = c->n;
  const double log_uniform = -log((double)n);
  const int stratified = (int)c->s->in[c->io.settings + ABYSSAL_SIR_SET_SCHEME] == ABYSSAL_SIR_STRATIFIED;
  for (idx ob = grab(c, phase); ob < c->nblocks; ob = grab(c, phase)) {
    const idx k0 = ob * BLOCK, nk = n - k0 < BLOCK ? n - k0 : BLOCK;
    if (stratified) {
      uniforms_block(c->key, c->counter, 2, k0, nk, sc.uni);
      stratified_ancestors(c, k0, nk, sc.uni, sc.anc);
    } else {
      systematic_ancestors(c, k0, nk, sc.anc);
    }
    for (int r = 0; r < s->n_x; ++r) {
      const double* restrict from = c->x_prop + (idx)r * c->ld;
      double* restrict to = c->x_out + (idx)r * c->ld + k0;
      const idx* restrict anc = sc.anc;
#pragma omp simd
      for (idx k = 0; k < nk; ++k) to[k] = from[anc[k]];
    }
    double* restrict lw = c->lw_next + k0;
#pragma omp simd
    for (idx k = 0; k < nk; ++k) lw[k] = log_uniform;
  }
}

/* thread 0: the posterior's sums into the report; 0 when a block failed or the moments are not finite (finite in,
 * finite out: a step whose estimate would not be finite is refused, here rather than by every caller) */
static int finish_weights(step_ctx* c) {
  const abyssal_sir* s = c->s;
  double* rep = c->rep;
  double Q;
  combine(c, c->bl.peak, c->bl.W, c->bl.Q, c->bl.mean, c->bl.m2, s->n_x, &c->peak, &c->W, &Q, rep + c->ro.mean,
          rep + c->ro.cov, c->bl.extra, s->n_extra, rep + c->ro.extra);
  if (!(c->peak > -INFINITY) || !(c->W > 0.0)) {
    c->status = ABYSSAL_SIR_NONFINITE_WEIGHT;
    return 0;
  }
  const double* moments = rep + c->ro.mean; /* the mean, then the covariance */
  for (idx k = 0; k < s->n_x + (idx)s->n_x * s->n_x; ++k)
    if (!isfinite(moments[k])) {
      c->status = ABYSSAL_SIR_NONFINITE_MOMENTS;
      return 0;
    }
  c->log_z = c->peak + log(c->W);
  rep[ABYSSAL_SIR_R_ESS] = c->W * c->W / Q;
  rep[ABYSSAL_SIR_R_LOG_MEAN] = c->log_z - log((double)c->n);
  return 1;
}

/* a block pass over the thread's blocks, then thread 0 checks them; 0 when a block failed (all threads) */
static int pass_blocks(step_ctx* c, int t, int mode, int phase) {
  run_blocks(c, t, mode, phase);
  sync_threads(c);
  if (t == 0) {
    c->status = first_error(c);
    c->rep[ABYSSAL_SIR_R_PASSES] += 1.0;
  }
  sync_threads(c);
  return c->status == ABYSSAL_SIR_OK;
}

/* every thread runs this; thread 0 takes the decisions between the barriers */
static void drive(step_ctx* c, int t) {
  const abyssal_sir* s = c->s;
  double* rep = c->rep;
  int phase = 0;
  if (!pass_blocks(c, t, c->mode, phase++)) return;
  for (;;) { /* further passes as the gate and the underflow rule ask (at most three) */
    if (t == 0) c->mode = c->status ? 0 : next_pass(c);
    sync_threads(c);
    if (c->status) return;
    if (!c->mode) break;
    if (!pass_blocks(c, t, c->mode, phase++)) return;
  }
  if (t == 0) finish_weights(c);
  sync_threads(c);
  if (c->status) return;
  normalise_blocks(c, PHASES - 2);
  sync_threads(c);
  if (t == 0) {
    const double ess = rep[ABYSSAL_SIR_R_ESS], below = s->in[c->io.settings + ABYSSAL_SIR_SET_RESAMPLE_BELOW];
    const int wanted = ess < below || below == INFINITY;
    rep[ABYSSAL_SIR_R_RESAMPLE] = wanted;
    c->resample = wanted && (int)s->in[c->io.settings + ABYSSAL_SIR_SET_SCHEME] != ABYSSAL_SIR_CALLER;
    rep[ABYSSAL_SIR_R_RESAMPLED] = c->resample;
    if (c->resample) {
      c->offsets[0] = 0.0;
      for (idx b = 0; b < c->nblocks; ++b) c->offsets[b + 1] = c->offsets[b] + c->stats[b * c->bl.stride + c->bl.w_sum];
      c->total = c->offsets[c->nblocks];
      double u0;
      uniforms_block(c->key, c->counter, 2, 0, 1, &u0);
      c->u0 = u0;
    }
  }
  sync_threads(c);
  if (c->resample) gather_blocks(c, t, PHASES - 1);
}

#ifndef ABYSSAL_SIR_NO_THREADS
typedef struct {
  step_ctx* c;
  int t;
} worker_arg;

static void* worker(void* a) {
  worker_arg* arg = (worker_arg*)a;
  step_ctx* c = arg->c;
  pthread_mutex_lock(&c->lock);
  while (c->go == 0) pthread_cond_wait(&c->go_cond, &c->lock);
  const int go = c->go;
  pthread_mutex_unlock(&c->lock);
  if (go > 0) drive(c, arg->t);
  return NULL;
}

/* drive() on T threads (this one and T - 1 started here); if a thread cannot be started, on this one alone
 * (the results do not depend on it) */
static void drive_threads(step_ctx* c) {
  pthread_t threads[ABYSSAL_SIR_MAX_THREADS];
  worker_arg args[ABYSSAL_SIR_MAX_THREADS];
  const int T = c->T;
  int started = 0;
  pthread_mutex_init(&c->lock, NULL);
  pthread_cond_init(&c->go_cond, NULL);
  pthread_cond_init(&c->barrier_cond, NULL);
  c->go = 0;
  for (int t = 1; t < T; ++t) {
    args[t].c = c;
    args[t].t = t;
    if (pthread_create(&threads[t], NULL, worker, &args[t]) != 0) break;
    ++started;
  }
  const int all = started == T - 1;
  c->arrived = c->sense = 0;
  pthread_mutex_lock(&c->lock);
  c->go = all ? 1 : -1;
  pthread_cond_broadcast(&c->go_cond);
  pthread_mutex_unlock(&c->lock);
  if (all) drive(c, 0);
  for (int t = 1; t <= started; ++t) pthread_join(threads[t], NULL);
  pthread_cond_destroy(&c->go_cond);
  pthread_cond_destroy(&c->barrier_cond);
  pthread_mutex_destroy(&c->lock);
  if (!all) {
    c->T = 1;
    drive(c, 0);
  }
}
#endif

/* ------------------------------------------------------------------------------------------ the step */
static int flag(double v) { return v == 0.0 || v == 1.0; }

int abyssal_sir_step(const abyssal_sir* s) {
  step_ctx ctx;
  step_ctx* c = &ctx;
  memset(c, 0, sizeof ctx);
  if (!s || !s->in || !s->rng || !s->work || !s->p || s->n < 1 || s->n > (idx)UINT32_MAX || s->n_x < 1 ||
      s->n_x > ABYSSAL_SIR_MAX_STATES || s->n_u < 0 || s->n_y < 0 || s->n_y > ABYSSAL_SIR_MAX_OUTPUTS ||
      s->ld < s->n || s->n_extra < 0 || s->rank < 0 || s->max_threads < 1 || s->max_threads > ABYSSAL_SIR_MAX_THREADS)
    return ABYSSAL_SIR_BAD_ARGUMENT;
  const double* in = s->in;
  c->s = s;
  c->io = abyssal_sir_inputs(s->n_x, s->n_u, s->n_y);
  c->ro = abyssal_sir_report(s->n_x, s->n_y, s->n_extra);
  c->bl = block_offsets(s->n_x, s->n_y, s->n_extra);
  c->n = s->n;
  c->ld = s->ld;
  c->nblocks = blocks_of(s->n);
  const double cur = in[ABYSSAL_SIR_IN_CUR], move = in[ABYSSAL_SIR_IN_MOVE], pieces = in[ABYSSAL_SIR_IN_PIECES];
  const double* set = in + c->io.settings;
  const double threads = set[ABYSSAL_SIR_SET_THREADS], pins = in[ABYSSAL_SIR_IN_PINS];
  if (!(cur == 0.0 || cur == 1.0 || cur == 2.0) || !flag(in[ABYSSAL_SIR_IN_SIDE]) ||
      !(move == 0.0 || move == 1.0 || move == 2.0) || !flag(in[ABYSSAL_SIR_IN_MEASURE]) ||
      !flag(set[ABYSSAL_SIR_SET_RATIO]) || !flag(in[ABYSSAL_SIR_IN_PRIOR]) || !(pieces >= 1.0 && pieces <= 1024.0 && pieces == floor(pieces)) ||
      !(threads >= 1.0) || !(pins >= 0.0 && pins <= s->n_x && pins == floor(pins)) ||
      !isfinite(in[ABYSSAL_SIR_IN_DT]) || set[ABYSSAL_SIR_SET_RESAMPLE_BELOW] != set[ABYSSAL_SIR_SET_RESAMPLE_BELOW] ||
      !(set[ABYSSAL_SIR_SET_SCHEME] == 0.0 || set[ABYSSAL_SIR_SET_SCHEME] == 1.0 || set[ABYSSAL_SIR_SET_SCHEME] == 2.0))
    return ABYSSAL_SIR_BAD_ARGUMENT;
  const int side = in[ABYSSAL_SIR_IN_SIDE] != 0.0;
  c->move = (int)move;
  c->pieces = (int)pieces;
  c->dt_piece = in[ABYSSAL_SIR_IN_DT] / c->pieces;
  c->ratio = set[ABYSSAL_SIR_SET_RATIO] != 0.0;
  c->prior_w = in[ABYSSAL_SIR_IN_PRIOR] != 0.0 && !c->ratio;
  c->x_in = s->particles[(int)cur];
  c->x_prop = s->particles[((int)cur + 1) % 3];
  c->x_out = s->particles[((int)cur + 2) % 3];
  c->lw_in = s->log_w[side];
  c->w_in = s->w[side];
  c->lw_next = s->log_w[1 - side];
  c->w_next = s->w[1 - side];
  c->rep = s->report[1 - side];
  c->u = in + c->io.u;
  c->u_std = in + c->io.u_std;
  c->z = in + c->io.z;
  c->thresholds = in + c->io.thresholds;
  c->pin_values = in + c->io.pin_values;
  c->n_pins = (int)pins;
  for (int i = 0; i < c->n_pins; ++i) {
    const double r = in[c->io.pin_rows + i];
    if (!(r >= 0.0 && r < s->n_x && r == floor(r))) return ABYSSAL_SIR_BAD_ARGUMENT;
    c->pin_rows[i] = (int)r;
  }
  c->key = s->rng[0];
  c->counter = s->rng[1];
  c->draws = c->move == ABYSSAL_SIR_MOVE_TRANSITION ? (s->input_noise ? s->n_u : 0) + s->rank : 0;
  if (!c->x_in || !c->x_prop || !c->x_out || !c->lw_in || !c->lw_next || !c->w_next || !c->rep ||
      (c->ratio && !s->log_ratio))
    return ABYSSAL_SIR_BAD_ARGUMENT;
  if (c->move == ABYSSAL_SIR_MOVE_TRANSITION) {
    const int mixture_ok = s->q_cumulative && s->q_means && s->q_factors && s->rank == s->n_x;
    if (!s->f || (s->q_components > 1 ? !mixture_ok : (s->rank > 0 && !s->factor)))
      return ABYSSAL_SIR_BAD_ARGUMENT;
    for (int q = 0; s->support && q < s->rank; ++q)
      if (s->support[q] < 0 || s->support[q] >= s->n_x) return ABYSSAL_SIR_BAD_ARGUMENT;
  }
  /* work: block sums, resampling offsets, the likelihood plan and temporaries, then per-thread scratch */
  const int K = s->r_components < 1 ? 1 : s->r_components;
  if (abyssal_sir_work_size(s->n, s->ld, s->n_x, s->n_u, s->n_y, s->n_extra, s->has_valid, s->rank, K,
                            s->max_threads) > s->work_size)
    return ABYSSAL_SIR_BAD_ARGUMENT;
  c->stats = s->work;
  c->offsets = c->stats + c->nblocks * c->bl.stride;
  double* plan = c->offsets + c->nblocks + 1;
  c->plan.linv = plan;
  c->plan.mu = plan + (idx)K * s->n_y * s->n_y;
  c->plan.cst = c->plan.mu + (idx)K * s->n_y;
  c->tmp_a = c->plan.cst + K + s->n_y;
  c->tmp_l = c->tmp_a + (idx)s->n_y * s->n_y;
  c->scratch_base = aligned(plan + plan_size(s->n_y, K));
  c->scratch_stride = scratch_size(s->n_x, s->n_u, s->n_y, s->n_extra, s->has_valid, s->rank, K, s->ld);
  /* the first pass: move, and the likelihood of every present entry (the gate may leave some out after it) */
  c->mode = MODE_MOVE | MODE_POST;
  c->stage = STAGE_FIRST;
  if (in[ABYSSAL_SIR_IN_MEASURE] != 0.0 && s->n_y > 0) {
    if (!s->h || !s->r_weights || !s->r_means || !s->r_covs || !s->R || !s->R_mean || s->r_components < 1 ||
        (s->n_angles && !s->angle_outputs))
      return ABYSSAL_SIR_BAD_ARGUMENT;
    for (int i = 0; i < s->n_y; ++i) {
      const double present = in[c->io.present + i];
      if (!flag(present)) return ABYSSAL_SIR_BAD_ARGUMENT;
      if (present != 0.0) {
        if (!isfinite(c->z[i])) return ABYSSAL_SIR_BAD_ARGUMENT;
        c->present_rows[c->n_present++] = i;
      }
    }
    if (c->n_present) {
      if (!make_plan(c, c->present_rows, c->n_present)) return ABYSSAL_SIR_BAD_ARGUMENT;
      c->mode |= MODE_H | MODE_LIK;
      if (c->thresholds[c->n_present] < INFINITY) c->mode |= MODE_YMEAN;
    }
  }
  if (s->n_extra || s->has_valid) c->mode |= MODE_H;
  if ((c->mode & MODE_H) && !s->h) return ABYSSAL_SIR_BAD_ARGUMENT;
  c->rep[ABYSSAL_SIR_R_PASSES] = 0.0;
  int T = threads > s->max_threads ? s->max_threads : (int)threads;
  c->T = (idx)T > c->nblocks ? (int)c->nblocks : T;
#ifndef ABYSSAL_SIR_NO_THREADS
  if (c->T > 1)
    drive_threads(c);
  else
    drive(c, 0);
#else
  c->T = 1;
  drive(c, 0);
#endif
  return c->status;
}
