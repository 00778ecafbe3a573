/* abyssal_kalman.h: the Kalman-family filters of abyssal (EKF, UKF, CKF, MCUKF, Huber UKF) in C.
 *
 * One implementation behind Python and C: Python's abyssal.runtime filters call these functions, and
 * `abyssal export` ships them. The filter steps themselves are the model's generated C (reached through its
 * descriptor, abyssal_model.h); this runtime adds what makes a filter one can trust on a vehicle:
 *
 *   - a filter object in caller-provided memory: abyssal_kalman_work_size() bytes (8-byte aligned), built by
 *     abyssal_kalman_init(); no heap, no global state, re-entrant (one object per thread), no pointers inside
 *     (a memcpy of the object is a checkpoint; copying it back restores the filter exactly);
 *   - a transaction: a call that returns an error code leaves the filter bit-identical (its state, reports and
 *     counters; the spare buffers it computes in are scratch); a successful call commits everything at once;
 *   - missing data: NaN entries of z, or entries a mask leaves out, are left out entry by entry;
 *   - the innovation gate with patience and inflation (abyssal_kalman_gate.h);
 *   - covariance repair: a step whose Cholesky guard trips on a covariance that is not numerically positive
 *     definite is retried once on the repaired covariance (eigenvalues clipped, counted in `repairs`);
 *   - dt beyond the stable range: every predict is checked for a covariance that grows more than growth_limit
 *     times in one step (or an integration that overflows); such a step is split into 2, 4, ... max_substeps
 *     pieces (counted in `substeps`), or refused: with ABYSSAL_E_UNSTABLE when dt is larger than any found
 *     stable before (the pieces found for such a dt are remembered), with ABYSSAL_E_UNSTABLE_INPUT when it is not
 *     (then u or p, at this state, blew it up: an accepted glitch of u must not leave a finite but absurd state
 *     that every later step refuses).
 *
 * Layouts: vectors are arrays of doubles; matrices n x n column-major (symmetric matrices read the same in
 * either order). The state, input, parameter and output layouts, with units, are in the model's header.
 *
 * Return codes: >= 0 success (ABYSSAL_UPDATED: a measurement was used; ABYSSAL_OK: not), < 0 refusal (the
 * object is unchanged); abyssal_kalman_message(code) says what it means.
 */
#ifndef ABYSSAL_KALMAN_H
#define ABYSSAL_KALMAN_H

#include <stddef.h>

#include "abyssal_kalman_gate.h"
#include "abyssal_model.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef enum {
  ABYSSAL_EKF = 1,       /* extended Kalman filter, Joseph-form update */
  ABYSSAL_UKF = 2,       /* unscented, scaled points (alpha, beta, kappa) */
  ABYSSAL_CKF = 3,       /* cubature (third degree, 2n points) */
  ABYSSAL_MCUKF = 4,     /* UKF predict, maximum-correntropy update (kernel bandwidth sigma) */
  ABYSSAL_HUBER_UKF = 5  /* UKF predict, Huber M-estimation update (threshold gamma) */
} abyssal_filter;

typedef struct {
  abyssal_filter filter;
  double alpha, beta, kappa;  /* UKF, MCUKF, Huber: scaled unscented points; default 1, 2, 0 */
  double sigma;               /* MCUKF kernel bandwidth; default 15 (inf: the plain UKF update) */
  double gamma;               /* Huber threshold; default 1.345 (inf: the plain UKF update) */
  double gate_probability;    /* tail probability of the innovation gate; default 1e-10; 0: no gate */
  int gate_patience;          /* consecutive gated updates of an entry before P is inflated; default 5 */
  double gate_inflation;      /* factor on P per further gated update; default 4 */
  double growth_limit;        /* a predict growing P more than this many times is subdivided; default 1e3 */
  int max_substeps;           /* at most this many pieces of one dt; default 64 */
  double repair_floor;        /* eigenvalue floor of the repair, relative to the largest; default 1e-10 */
} abyssal_kalman_options;

enum {
  ABYSSAL_UPDATED = 1,        /* success, and a measurement was used */
  ABYSSAL_OK = 0,             /* success: predicted only, or no entry of z present, or every entry gated */
  ABYSSAL_E_MEMORY = -1,      /* memory NULL, not 8-byte aligned, smaller than abyssal_kalman_work_size(), or
                                 not an initialised filter */
  ABYSSAL_E_MODEL = -2,       /* the model lacks this filter's generated functions (regenerate with its family) */
  ABYSSAL_E_FILTER = -3,      /* options.filter is not an abyssal_filter */
  ABYSSAL_E_SIGMA_POINTS = -4,/* alpha, beta, kappa: finite with 0 < alpha^2 (n + kappa) < inf */
  ABYSSAL_E_ROBUST = -5,      /* sigma (MCUKF) or gamma (Huber) must be > 0 (inf allowed) */
  ABYSSAL_E_GATE = -6,        /* 0 <= gate_probability < 1, gate_patience >= 1, 1 <= gate_inflation < inf */
  ABYSSAL_E_SUBSTEPS = -7,    /* growth_limit > 1, max_substeps >= 1, 0 < repair_floor < 1 */
  ABYSSAL_E_X0 = -8,          /* x0 (or reset's x): NULL or not finite */
  ABYSSAL_E_P0 = -9,          /* P0 (or reset's P): not a symmetric positive semi-definite finite matrix */
  ABYSSAL_E_Q = -10,          /* Q: not a symmetric positive semi-definite finite matrix */
  ABYSSAL_E_R = -11,          /* R: not a symmetric positive definite finite matrix */
  ABYSSAL_E_U = -12,          /* u: NULL or not finite */
  ABYSSAL_E_DT = -13,         /* dt: not a positive finite number of seconds */
  ABYSSAL_E_Z = -14,          /* z: an infinite entry (a missing entry is NaN) */
  ABYSSAL_E_P = -15,          /* p: not finite */
  ABYSSAL_E_DIVERGED = -16,   /* the step failed (non-finite outputs, or a covariance that is not positive
                                 definite) even after repairing P */
  ABYSSAL_E_UNSTABLE = -17,   /* dt: the predict blew up even in max_substeps pieces */
  ABYSSAL_E_STATE = -18,      /* the filter state is not finite */
  ABYSSAL_E_UNSTABLE_INPUT = -19 /* u or p: the predict blew up at a dt that was stable before, even in
                                    max_substeps pieces (the input drives the model out of its stable range) */
};

typedef struct abyssal_kalman abyssal_kalman;

/* What the last calls reported (pointers into the filter object; valid until its next call). */
typedef struct {
  const double* innovation;   /* (n_y) of the last accepted update, 0 on unused entries; NULL before one */
  const double* S;            /* (n_y x n_y) its innovation covariance, identity rows on unused entries; NULL */
  double nis;                 /* innovation^T S^-1 innovation of the last accepted update; NaN before one */
  int nis_dof;                /* entries it used; 0 before one */
  long long gated;            /* measurement entries left out by the gate so far */
  long long inflations;       /* covariance inflations after gate_patience consecutive gates of an entry */
  long long repairs;          /* covariance repairs (eigenvalue clipping) so far */
  long long substeps;         /* predicts subdivided because dt was beyond the stable range */
} abyssal_kalman_report;

/* The defaults of a filter (the values listed in abyssal_kalman_options). */
abyssal_kalman_options abyssal_kalman_default_options(abyssal_filter filter);

/* Bytes of the filter object for this model and options (a multiple of 8), 0 when they are invalid (see
 * abyssal_kalman_check_options). */
size_t abyssal_kalman_work_size(const abyssal_model* model, const abyssal_kalman_options* options);

/* ABYSSAL_OK when the model has the filter's generated functions and the options are valid, else the code. */
int abyssal_kalman_check_options(const abyssal_model* model, const abyssal_kalman_options* options);

/* Build a filter in memory (bytes >= abyssal_kalman_work_size, 8-byte aligned). Checks the options and that
 * x0 is finite, P0 and Q symmetric positive semi-definite (singular and zero allowed), R symmetric positive
 * definite (the matrices are stored symmetrised). *filter (may be NULL) receives the filter, or NULL. */
int abyssal_kalman_init(void* memory, size_t bytes, const abyssal_model* model, const abyssal_kalman_options* options,
                        const double* x0, const double* P0, const double* Q, const double* R, abyssal_kalman** filter);

/* predict(u, dt, p) then update(z, mask, p) as one transaction. z NULL: predict only. NaN entries of z, and
 * entries whose mask byte is 0 (mask NULL: all used), are left out; entries left out are not read. p NULL:
 * the model's defaults; p may change every call. ABYSSAL_UPDATED, ABYSSAL_OK or a refusal. */
int abyssal_kalman_step(abyssal_kalman* filter, const double* u, double dt, const double* z, const unsigned char* mask,
                        const double* p);
int abyssal_kalman_predict(abyssal_kalman* filter, const double* u, double dt, const double* p);
int abyssal_kalman_update(abyssal_kalman* filter, const double* z, const unsigned char* mask, const double* p);

/* The state (n_x) and its covariance (n_x x n_x); pointers into the object, valid until its next call. */
const double* abyssal_kalman_x(const abyssal_kalman* filter);
const double* abyssal_kalman_P(const abyssal_kalman* filter);
void abyssal_kalman_get_report(const abyssal_kalman* filter, abyssal_kalman_report* report);
const abyssal_model* abyssal_kalman_model(const abyssal_kalman* filter);

/* Replace the state (checked as x0, P0), or the noise covariances (checked as Q, R); a refusal changes nothing. */
int abyssal_kalman_reset(abyssal_kalman* filter, const double* x, const double* P);
int abyssal_kalman_set_Q(abyssal_kalman* filter, const double* Q);
int abyssal_kalman_set_R(abyssal_kalman* filter, const double* R);

/* What a return code means (a static string). */
const char* abyssal_kalman_message(int code);

/* Byte offsets of the object's parts, for bindings that view its memory (Python): ABYSSAL_AT_X + k (k < 3) and
 * ABYSSAL_AT_P + k are the buffer sets of x and P (the current one is the int at ABYSSAL_AT_CURRENT), ...
 * Returns -1 for an unknown item. */
enum {
  ABYSSAL_AT_X = 0, ABYSSAL_AT_P = 3, ABYSSAL_AT_INNOVATION = 6, ABYSSAL_AT_S = 8, ABYSSAL_AT_Q = 10,
  ABYSSAL_AT_R = 11, ABYSSAL_AT_GATE = 12, ABYSSAL_AT_CURRENT = 13, ABYSSAL_AT_REPORTED = 14, ABYSSAL_AT_NIS = 15,
  ABYSSAL_AT_NIS_DOF = 16, ABYSSAL_AT_REPAIRS = 17, ABYSSAL_AT_SUBSTEPS = 18, ABYSSAL_AT_STATE_BYTES = 19,
  ABYSSAL_AT_COUNT = 20
};
long long abyssal_kalman_offset(const abyssal_kalman* filter, int item);

#ifdef __cplusplus
}
#endif

#endif /* ABYSSAL_KALMAN_H */
