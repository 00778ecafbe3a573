/* One compiled step of sequential importance resampling (SIR) for any generated model (C99).
 *
 * abyssal_sir_step() does a whole particle-filter step in one call, over caller-provided buffers:
 *
 *   move      x_k = f(x_{k-1}, u_k) + w_k for every particle: the model's structure-of-arrays kernel f
 *             (optionally with per-particle input noise u + diag(u_std) n, and 2^j substeps of dt), the
 *             process noise w drawn from the step's own counter-based generator (abyssal_rng.h): Gaussian on
 *             the positive-definite subspace of a possibly singular Q (a diagonal support or a dense factor),
 *             or a Gaussian mixture; or the particles a proposal wrote (with its log importance ratios), or
 *             none (an update alone);
 *   pins      state rows set to known values after the move (e.g. a heading copied from a compass);
 *   weigh     the measurement function h (a model's kernel or the caller's, e.g. a map lookup) and the exact
 *             (mixture) likelihood of the present entries of z, angle residuals wrapped to (-pi, pi], with the
 *             robust rule: an entry-wise chi-square gate on the cloud's predicted measurement
 *             (nu = sum_i w_i r_i - E[v] and S = sum_i w_i (r_i - rbar)(r_i - rbar)^T + R, r_i = z - h(x_i)
 *             with angle entries wrapped and w_i the weights before the step; the test of
 *             runtime/filters/kalman/gate.py with the caller's thresholds, settled by its bound
 *             nu^T R^-1 nu <= threshold when it holds, as S >= R), and, when every likelihood
 *             underflows (max log-likelihood < log DBL_MIN), the weights are kept (an uninformative step);
 *   report    normalised weights and log-weights, ESS, the weighted mean and covariance of the particles, the
 *             weighted means of the measurement's extra rows;
 *   resample  systematic or stratified, when ESS < the caller's threshold.
 *
 * Work runs in blocks of ABYSSAL_SIR_BLOCK particles (their intermediates stay in cache) and, above one
 * thread, the blocks are split over threads (POSIX threads, created per step, meeting at spin-then-sleep
 * barriers). Every sum is formed per block and blocks are combined in block order, and every random draw is a
 * function of (key, step counter, particle, row): the results do not depend on the number of threads.
 *
 * Transactions: the step reads the committed side and writes only the other side of every buffer it holds
 * twice (particles: three buffers, the committed one, the proposals and the resampled ones), so a caller
 * that does not commit a step has nothing to undo. It never allocates.
 *
 * Layouts: particles (n_x, n) with row stride ld (row r of particle j at r * ld + j); matrices row-major.
 */
#ifndef ABYSSAL_SIR_H
#define ABYSSAL_SIR_H

#include <stdint.h>

typedef long long abyssal_idx;

/* A generated structure-of-arrays kernel (CasADi's calling convention: rows of stride ld). */
typedef int (*abyssal_soa_fn)(abyssal_idx n, abyssal_idx ld, const double** arg, double** res);

/* A measurement function: y (rows: n_y outputs, then n_extra extra rows, then a validity row when the
 * model has one) of n particles x (rows of stride ld); returns 0 on success. */
typedef int (*abyssal_measure_fn)(const void* ctx, abyssal_idx n, abyssal_idx ld, const double* x, const double* p,
                                  double* y);

/* particles per block (fixed: the blocking, and so every sum, never depends on the thread count) */
#define ABYSSAL_SIR_BLOCK 512
/* limits of a model and of the threads of one step */
#define ABYSSAL_SIR_MAX_STATES 64
#define ABYSSAL_SIR_MAX_OUTPUTS 64
#define ABYSSAL_SIR_MAX_THREADS 64

/* return codes */
enum {
  ABYSSAL_SIR_OK = 0,
  ABYSSAL_SIR_NONFINITE_PARTICLE = 1,    /* a moved particle is inf or NaN, or beyond max_abs */
  ABYSSAL_SIR_NONFINITE_MEASUREMENT = 2, /* h gave inf or NaN */
  ABYSSAL_SIR_NONFINITE_WEIGHT = 3,      /* a log-weight is NaN or +inf (e.g. a NaN log importance ratio) */
  ABYSSAL_SIR_MODEL_FAILED = 4,          /* f or h returned non-zero */
  ABYSSAL_SIR_BAD_ARGUMENT = 5,          /* sizes, pointers or inputs out of range */
  ABYSSAL_SIR_NONFINITE_MOMENTS = 6      /* the weighted mean or covariance is inf or NaN */
};

/* moves */
enum { ABYSSAL_SIR_MOVE_NONE = 0, ABYSSAL_SIR_MOVE_TRANSITION = 1, ABYSSAL_SIR_MOVE_GIVEN = 2 };
/* resampling schemes done in C (others: the caller resamples when the report says ESS is below threshold) */
enum { ABYSSAL_SIR_SYSTEMATIC = 0, ABYSSAL_SIR_STRATIFIED = 1, ABYSSAL_SIR_CALLER = 2 };

/* The step's inputs, in[] (doubles): these scalars, then the vectors and settings at abyssal_sir_in_offsets().
 * Ordered so that what a filter changes every step (CUR .. the thresholds) is one contiguous slice, and the pinned
 * count is followed by the pinned values (a measurement function may read both, e.g. a compass heading copied
 * into every particle); the settings a filter keeps come last. */
enum {
  ABYSSAL_SIR_IN_CUR,             /* committed particle buffer, 0..2 (proposals go to cur+1, resampled to cur+2) */
  ABYSSAL_SIR_IN_SIDE,            /* committed side of log_w, w, report: 0 or 1 (the step writes 1 - side) */
  ABYSSAL_SIR_IN_PRIOR,           /* 1: the committed w are exp(committed log_w) (no resampling since): the gate's
                                   * prior weights are read, not recomputed; 0: recomputed */
  ABYSSAL_SIR_IN_MOVE,            /* ABYSSAL_SIR_MOVE_* */
  ABYSSAL_SIR_IN_MEASURE,         /* 1: weigh by z (present entries), 0: no measurement */
  ABYSSAL_SIR_IN_DT,              /* the model's dt */
  ABYSSAL_SIR_IN_PIECES,          /* f applied this many times with dt / pieces (>= 1) */
  ABYSSAL_SIR_IN_PINS,            /* number of pinned state rows (their values, then their rows, follow) */
  ABYSSAL_SIR_IN_HEAD
};

/* settings, at abyssal_sir_in_offsets().settings + these */
enum {
  ABYSSAL_SIR_SET_THREADS,        /* threads to use (>= 1; at most the blocks, and max_threads) */
  ABYSSAL_SIR_SET_SCHEME,         /* ABYSSAL_SIR_SYSTEMATIC / _STRATIFIED / _CALLER */
  ABYSSAL_SIR_SET_RESAMPLE_BELOW, /* resample when ESS < this (inf: always, 0: never) */
  ABYSSAL_SIR_SET_RATIO,          /* 1: add log_ratio (a proposal's log importance ratios) to the log-weights */
  ABYSSAL_SIR_SET_COUNT
};

/* Offsets of the vectors of in[]: pin values (n_x), pin rows (n_x), u (n_u), u_std (n_u), z (n_y), present (n_y:
 * 1 or 0), thresholds (n_y + 1: chi-square quantile by degrees of freedom, inf for no gate), the settings; size. */
typedef struct {
  abyssal_idx pin_values, pin_rows, u, u_std, z, present, thresholds, settings, size;
} abyssal_sir_in_offsets;

/* The report (doubles), one per side: these scalars, then the vectors at abyssal_sir_report_offsets(). */
enum {
  ABYSSAL_SIR_R_ESS,          /* 1 / sum w^2 after the update, before resampling */
  ABYSSAL_SIR_R_RESAMPLED,    /* 1 when the particles were resampled (they are then in buffer cur + 2) */
  ABYSSAL_SIR_R_RESAMPLE,     /* 1 when ESS < threshold (with the caller's scheme: the caller resamples) */
  ABYSSAL_SIR_R_UNINFORMATIVE,/* 1 when every likelihood underflowed and the weights were kept */
  ABYSSAL_SIR_R_USED,         /* entries of z that weighed the particles */
  ABYSSAL_SIR_R_GATED,        /* entries of z left out by the gate */
  ABYSSAL_SIR_R_MAX_LOG_LIK,  /* the largest log-likelihood of a particle (-inf without measurement) */
  ABYSSAL_SIR_R_LOG_MEAN,     /* log of the mean unnormalised weight exp(log w_{k-1} + log ratio + log lik) */
  ABYSSAL_SIR_R_PASSES,       /* block passes the step needed (1; 2 or 3 after a gate or an underflow) */
  ABYSSAL_SIR_R_HEAD
};

/* Offsets of the report's vectors: gated mask (n_y), mean (n_x), covariance (n_x * n_x), extra means
 * (n_extra), the gate's innovation (n_y) and its S (n_y * n_y) (zero rows for entries not present); size. */
typedef struct {
  abyssal_idx gated, mean, cov, extra, nu, S, size;
} abyssal_sir_report_offsets;

typedef struct abyssal_sir {
  /* sizes */
  abyssal_idx n;          /* particles (1 .. 2^32 - 1) */
  abyssal_idx ld;         /* row stride of the particle buffers (>= n; a multiple of 8 keeps rows 64-byte aligned) */
  int n_x, n_u, n_y, n_p;
  int n_extra;            /* measurement rows after the n_y outputs, averaged with the posterior weights */
  int has_valid;          /* 1: one more row, 0 marks a particle outside h's domain (log-likelihood = invalid_log_lik) */
  int max_threads;        /* threads the work buffer was sized for */
  /* the model */
  abyssal_soa_fn f;       /* f(x[], u[], p, dt) -> x_next[] */
  abyssal_measure_fn h;   /* h(ctx, ...) -> y (see abyssal_measure_fn) */
  const void* h_ctx;
  const double* p;        /* (n_p) model parameters */
  /* process noise: w = noise_mean + factor y, y ~ N(0, I_rank) (or a mixture, q_components >= 2) */
  int rank;               /* normals per particle for w (n_x for a mixture) */
  int q_components;       /* 1: Gaussian; K >= 2: mixture */
  const int* support;     /* (rank) state rows when the factor is diagonal, else NULL */
  const double* factor;   /* support: (rank) standard deviations; else (n_x, rank) */
  const double* noise_mean; /* (n_x) or NULL (zero) */
  const double* q_cumulative; /* mixture: (K) cumulative weights, the last 1 */
  const double* q_means;  /* mixture: (K, n_x) */
  const double* q_factors; /* mixture: (K, n_x, n_x) lower Cholesky factors */
  int input_noise;        /* 1: per-particle inputs u + u_std * n (n_u normals per particle, before w's) */
  /* measurement noise: sum_k weight_k N(mean_k, cov_k) on the present entries */
  int r_components;
  int n_angles;           /* outputs whose residuals are wrapped to (-pi, pi] */
  const int* angle_outputs;
  const double* r_weights; /* (K) normalised */
  const double* r_means;  /* (K, n_y) */
  const double* r_covs;   /* (K, n_y, n_y) positive definite */
  const double* R;        /* (n_y, n_y) its moment-matched covariance (the gate's S) */
  const double* R_mean;   /* (n_y) its mean */
  double invalid_log_lik; /* log-likelihood of a particle outside h's domain (has_valid) */
  double max_abs;         /* a moved particle with an entry beyond +-max_abs (or not finite) fails the step (inf: finite) */
  /* state buffers (the committed ones are read, the others written) */
  double* particles[3];   /* (n_x, n) each */
  double* log_w[2];       /* (n) normalised log-weights */
  double* w[2];           /* (n) normalised weights */
  double* report[2];      /* abyssal_sir_report_offsets().size */
  const double* log_ratio; /* (n): a proposal's log importance ratios (in[RATIO] = 1) */
  const uint64_t* rng;    /* [key, step counter] */
  const double* in;       /* the step's inputs (abyssal_sir_in_offsets) */
  double* work;           /* abyssal_sir_work_size() doubles */
  abyssal_idx work_size;
} abyssal_sir;

abyssal_sir_in_offsets abyssal_sir_inputs(int n_x, int n_u, int n_y);
abyssal_sir_report_offsets abyssal_sir_report(int n_x, int n_y, int n_extra);
/* doubles of work for a model of these sizes, n particles (row stride ld) and up to `threads` threads (most of it
 * address space: per thread, rows of stride ld of which only the first ABYSSAL_SIR_BLOCK columns are touched) */
abyssal_idx abyssal_sir_work_size(abyssal_idx n, abyssal_idx ld, int n_x, int n_u, int n_y, int n_extra, int has_valid,
                                  int rank, int r_components, int threads);
/* one step (see the top of this file); ABYSSAL_SIR_OK or an error code, the committed buffers untouched */
int abyssal_sir_step(const abyssal_sir* s);
/* a message for a return code */
const char* abyssal_sir_message(int code);

/* The generator, for tests and for a caller that replays a step: normal rows 0..rows-1 of particles
 * i0 .. i0 + n - 1 at out[row * ld + j] (tag 0: the step's noise), and uniforms (open (0, 1)) of a tag's
 * word 0 (tag 1: mixture components, tag 2: resampling). */
void abyssal_sir_normals(uint64_t key, uint64_t counter, uint32_t tag, abyssal_idx i0, abyssal_idx n, int rows,
                         double* out, abyssal_idx ld);
void abyssal_sir_uniforms(uint64_t key, uint64_t counter, uint32_t tag, abyssal_idx i0, abyssal_idx n, double* out);
void abyssal_sir_philox(const uint32_t counter[4], const uint32_t key[2], uint32_t out[4]);
/* The step's Box-Muller transform of 32-bit words, for tests: r cos(t), r sin(t) with r = sqrt(-2 ln((a + 1/2) 2^-32)),
 * t = 2 pi b 2^-32, in single precision */
void abyssal_sir_box_muller(const uint32_t* a, const uint32_t* b, abyssal_idx n, double* cos_out, double* sin_out);
/* The step's wrap of angle residuals, for tests: the entries of r (n) beyond +-pi wrapped to (-pi, pi] in place (as
 * numpy's pi - remainder(pi - r, 2 pi)); the others left as they are. */
void abyssal_sir_wrap_residuals(double* r, abyssal_idx n);

/* h for a generated model: ctx points to an abyssal_soa_measure (the model's h kernel, h(x[], p) -> y[]) */
typedef struct {
  abyssal_soa_fn h;
} abyssal_soa_measure;
int abyssal_sir_soa_measure(const void* ctx, abyssal_idx n, abyssal_idx ld, const double* x, const double* p,
                            double* y);

#endif /* ABYSSAL_SIR_H */
