/* abyssal_kalman.h: the Kalman-family filters of abyssal (EKF, UKF, CKF, MCUKF, Huber UKF) in C.
 *
 * One implementation behind Python and C: Python's abyssal.runtime filters call these functions, and
 * `abyssal export` ships them. The algebra of every step is abyssal_kalman_steps.h (written once, generic over
 * the dimensions); the model enters only through its generated descriptor (abyssal_model.h), which every call
 * is given. This runtime adds what makes a filter one can trust on a vehicle:
 *
 *   - a filter object in caller-provided memory: abyssal_kalman_work_size() bytes (8-byte aligned), built by
 *     abyssal_kalman_init(); no heap, no global state, re-entrant (one object per thread), and no pointers inside:
 *     a memcpy of the object is a checkpoint, valid in another process (the object records its model's id and
 *     every call checks the descriptor it is given against it);
 *   - a transaction: a call that returns an error code leaves the filter bit-identical (its state, reports,
 *     counters and history; the spare buffers it computes in are scratch); a successful call commits everything
 *     at once;
 *   - sensors and time: the model's sensors (abyssal_model.h) are measured one at a time, each with its own R
 *     (the filter's, or one given with the measurement), at their own time stamps: abyssal_kalman_predict_to(t, u)
 *     integrates to t with u held; abyssal_kalman_update_sensor(sensor, t, z) fuses a measurement at its stamp,
 *     predicting to it first when it is ahead of the filter, or, when it is behind (a late USBL fix), from the
 *     filter's history: the state at the last event before t, the measurement inserted there and every later
 *     event replayed (a fixed lag: history_seconds and history_entries bound it; older is refused with
 *     ABYSSAL_E_TOO_LATE, nothing changed). The result equals the in-order run of the same calls. The fixed-rate
 *     calls (abyssal_kalman_step/predict/update: every sensor stacked, time advanced by dt) remain;
 *   - missing data: NaN entries of z, or entries a mask leaves out, are left out entry by entry;
 *   - the innovation gate, per entry, with patience and a bounded inflation: an entry gated gate_patience times in
 *     a row inflates P, at most gate_max_inflations times per streak; beyond that its sensor is held as rejected
 *     (stuck or lost: its measurements gated and counted, P left alone) until one passes. While other entries are
 *     accepted during the streak the filter follows them and the sensor is taken to be stuck: P is inflated only
 *     along the directions it measures (P += (f - 1) Pxz Pzz^-1 Pxz^T on the gated entries), so a stuck depth
 *     gauge leaves x, y and heading to the other sensors; when nothing was accepted during the streak the filter
 *     itself is taken to be wrong (a jump it cannot follow) and the whole P is inflated;
 *   - covariance repair: a step whose Cholesky guard trips on a covariance that is not numerically positive
 *     definite is retried once on the repaired covariance (eigenvalues clipped, counted in `repairs`); an update
 *     whose posterior P is not positive definite (a tiny R) is repaired the same way;
 *   - dt beyond the stable range: every predict is checked for a covariance that grows more than growth_limit
 *     times in one step (or an integration that overflows); such a step is split into 2, 4, ... max_substeps
 *     pieces (counted in `substeps`), or refused: ABYSSAL_E_UNSTABLE when dt is larger than any found stable
 *     before, ABYSSAL_E_UNSTABLE_INPUT when it is not (u or p, at this state, blew it up), ABYSSAL_E_UNSTABLE_STATE
 *     when the state came from init or reset since the last accepted predict (the state given blew it up).
 *
 * Process noise (options.noise): ABYSSAL_NOISE_STEP, Q is the covariance added by one predict call (split over its
 * substeps; the fixed-rate convention); ABYSSAL_NOISE_RATE, Q is per second (Q dt is added: irregular stamps);
 * ABYSSAL_NOISE_INPUTS, Q (n_w x n_w) is the power spectral density of the model's noise inputs w, held over each
 * step: G (Q / dt) G^T is added, G = df/dw of the step (the discrete equivalent of continuous white noise).
 *
 * Layouts: vectors are arrays of doubles; matrices column-major (symmetric ones read the same either way). The
 * state, input, parameter and output layouts, with units, are in the model's descriptor and exported header.
 *
 * Return codes: >= 0 success (ABYSSAL_UPDATED: a measurement was used; ABYSSAL_OK: not), < 0 refusal (the
 * object is unchanged); abyssal_kalman_message(code) says what it means. Hand-written C99.
 */
#ifndef ABYSSAL_KALMAN_H
#define ABYSSAL_KALMAN_H

#include <stddef.h>

#include "abyssal_kalman_gate.h"
#include "abyssal_kalman_steps.h"
#include "abyssal_model.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef enum {
  ABYSSAL_NOISE_STEP = 0,   /* Q per predict call */
  ABYSSAL_NOISE_RATE = 1,   /* Q per second */
  ABYSSAL_NOISE_INPUTS = 2  /* Q: power spectral density of the noise inputs w (n_w x n_w) */
} abyssal_noise;

typedef struct {
  abyssal_filter filter;
  double alpha, beta, kappa;  /* UKF, MCUKF, Huber: scaled unscented points; default 1, 2, 0 */
  double sigma;               /* MCUKF kernel bandwidth; default 15 (inf: the plain UKF update) */
  double gamma;               /* Huber threshold; default 1.345 (inf: the plain UKF update) */
  int huber_iterations;       /* Huber reweightings; default 3 */
  double gate_probability;    /* tail probability of the innovation gate; default 1e-10; 0: no gate */
  int gate_patience;          /* consecutive gated updates of an entry before P is inflated; default 5 */
  double gate_inflation;      /* factor on P along the gated entries' directions per further gate; default 4 */
  int gate_max_inflations;    /* inflations per streak before the sensor is held as rejected; default 10: P may
                                 grow gate_inflation^10 (4^10 ~ 1e6, 1000x in std) along a sensor, enough to
                                 re-acquire a real jump of ~1000 gate widths; a value further out (a gauge
                                 stuck at +1e6 m) is rejected rather than re-acquired */
  double growth_limit;        /* a predict growing P more than this many times is subdivided; default 1e3 */
  int max_substeps;           /* at most this many pieces of one dt; default 64 */
  double repair_floor;        /* eigenvalue floor of the repair, relative to the largest; default 1e-10 */
  int noise;                  /* abyssal_noise; default ABYSSAL_NOISE_STEP */
  int history_entries;        /* events (predicts, updates) kept for late measurements and smoothing; default 0 */
  double history_seconds;     /* the fixed lag: events older than this are dropped; default 2 */
  int smoothing;              /* 1: keep each predict's smoother gain in the history (abyssal_kalman_smooth) */
} abyssal_kalman_options;

enum {
  ABYSSAL_UPDATED = 1,        /* success, and a measurement was used */
  ABYSSAL_OK = 0,             /* success: predicted only, or no entry of z present, or every entry gated */
  ABYSSAL_E_MEMORY = -1,      /* memory NULL, not 8-byte aligned, smaller than abyssal_kalman_work_size(), or
                                 not an initialised filter */
  ABYSSAL_E_MODEL = -2,       /* the model: NULL, another layout version, lacking the functions this filter needs,
                                 or not the model the filter was built for (another id or size) */
  ABYSSAL_E_FILTER = -3,      /* options.filter is not an abyssal_filter */
  ABYSSAL_E_SIGMA_POINTS = -4,/* alpha, beta, kappa: finite with 0 < alpha^2 (n + kappa) < inf */
  ABYSSAL_E_ROBUST = -5,      /* sigma (MCUKF) or gamma (Huber) must be > 0 (inf allowed), huber_iterations >= 1 */
  ABYSSAL_E_GATE = -6,        /* 0 <= gate_probability < 1, gate_patience >= 1, 1 <= gate_inflation < inf,
                                 gate_max_inflations >= 0 */
  ABYSSAL_E_SUBSTEPS = -7,    /* growth_limit > 1, max_substeps >= 1, 0 < repair_floor < 1 */
  ABYSSAL_E_X0 = -8,          /* x0 (or reset's x): NULL or not finite */
  ABYSSAL_E_P0 = -9,          /* P0 (or reset's P): not a symmetric positive semi-definite finite matrix */
  ABYSSAL_E_Q = -10,          /* Q: not a symmetric positive semi-definite finite matrix */
  ABYSSAL_E_R = -11,          /* R: not a symmetric positive definite finite matrix (or none given and a sensor
                                 declares none) */
  ABYSSAL_E_U = -12,          /* u: NULL or not finite */
  ABYSSAL_E_DT = -13,         /* dt: not a positive finite number of seconds */
  ABYSSAL_E_Z = -14,          /* z: an infinite entry (a missing entry is NaN) */
  ABYSSAL_E_P = -15,          /* p (or a sensor's own parameters q): not finite */
  ABYSSAL_E_DIVERGED = -16,   /* the step failed (non-finite outputs, or a covariance that is not positive
                                 definite) even after repairing P */
  ABYSSAL_E_UNSTABLE = -17,   /* dt: the predict blew up even in max_substeps pieces */
  ABYSSAL_E_STATE = -18,      /* the filter state is not finite */
  ABYSSAL_E_UNSTABLE_INPUT = -19, /* u or p: the predict blew up at a dt that was stable before, even in
                                     max_substeps pieces (the input drives the model out of its stable range) */
  ABYSSAL_E_SENSOR = -20,     /* the sensor index is not one of the model's */
  ABYSSAL_E_TIME = -21,       /* a time stamp: not finite, before the filter's time (predict_to), or not after the
                                 sensor's previous stamp (each sensor's stamps must increase) */
  ABYSSAL_E_TOO_LATE = -22,   /* the measurement is older than the history holds (history_seconds, history_entries) */
  ABYSSAL_E_LIVE = -23,       /* init: the memory holds an initialised filter (abyssal_kalman_release() it first) */
  ABYSSAL_E_UNSTABLE_STATE = -24, /* x or P: the first predict from the state given to init or reset blew up even in
                                     max_substeps pieces (an absurd state) */
  ABYSSAL_E_OPTIONS = -25     /* noise, history_entries >= 0, history_seconds >= 0 finite, smoothing 0 or 1; noise
                                 inputs need the model's G (n_w > 0) */
};

typedef struct abyssal_kalman abyssal_kalman;

/* What the last calls reported (pointers into the filter object; valid until its next call). */
typedef struct {
  const double* innovation;   /* (rows) of the last accepted update, 0 on unused entries; NULL before one */
  const double* S;            /* (rows x rows) its innovation covariance, identity rows on unused entries; NULL */
  int rows;                   /* its rows: n_y for a stacked update, the sensor's outputs for one sensor */
  int sensor;                 /* its sensor, -1 for a stacked update (or none yet) */
  double nis;                 /* innovation^T S^-1 innovation of the last accepted update; NaN before one */
  int nis_dof;                /* entries it used; 0 before one */
  double t;                   /* the filter's time, s */
  long long gated;            /* measurement entries left out by the gate so far */
  long long inflations;       /* covariance inflations after gate_patience consecutive gates of an entry */
  long long repairs;          /* covariance repairs (eigenvalue clipping) so far */
  long long substeps;         /* predicts subdivided because dt was beyond the stable range */
  long long late;             /* measurements fused at their own earlier stamp from the history */
  int history;                /* events held in the history now */
} abyssal_kalman_report;

/* What one sensor did so far. */
typedef struct {
  long long used;             /* its updates that used at least one of its entries */
  long long gated;            /* its entries left out by the gate */
  long long late;             /* its measurements fused from the history at their own stamp */
  long long inflations;       /* inflations of P along its entries */
  int rejected;               /* 1 while held as stuck or lost (gated beyond gate_max_inflations) */
  int streak;                 /* its current run of consecutive gated updates (the longest over its entries) */
  double last_t;              /* the stamp of its last measurement; NaN before one */
  double nis;                 /* of its last accepted update; NaN before one */
  int nis_dof;
} abyssal_sensor_report;

/* The defaults of a filter (the values listed in abyssal_kalman_options). */
abyssal_kalman_options abyssal_kalman_default_options(abyssal_filter filter);

/* Bytes of the filter object for this model and options (a multiple of 8), 0 when they are invalid. */
size_t abyssal_kalman_work_size(const abyssal_model* model, const abyssal_kalman_options* options);

/* ABYSSAL_OK when the model has what the filter needs and the options are valid, else the code. */
int abyssal_kalman_check_options(const abyssal_model* model, const abyssal_kalman_options* options);

/* Build a filter in memory (bytes >= abyssal_kalman_work_size, 8-byte aligned) at time t0. Checks the options and
 * that x0 is finite, P0 symmetric positive semi-definite (singular and zero allowed), Q likewise (n x n, or
 * n_w x n_w for noise inputs), R (n_y x n_y, every sensor stacked) symmetric positive definite; R NULL takes each
 * sensor's declared noise. Refused, memory untouched, when it holds an initialised filter. *filter (may be NULL)
 * receives the filter, or NULL. */
int abyssal_kalman_init(void* memory, size_t bytes, const abyssal_model* model, const abyssal_kalman_options* options,
                        const double* x0, const double* P0, const double* Q, const double* R, double t0,
                        abyssal_kalman** filter);

/* Forget the filter: its memory may be initialised again. */
void abyssal_kalman_release(abyssal_kalman* filter);

/* predict(u, dt, p) then update(z, mask, p) of every sensor stacked, as one transaction; the time advances by dt.
 * z NULL: predict only. NaN entries of z, and entries whose mask byte is 0 (mask NULL: all used), are left out;
 * entries left out are not read. p NULL: the model's defaults; p may change every call. */
int abyssal_kalman_step(abyssal_kalman* filter, const abyssal_model* model, const double* u, double dt, const double* z,
                        const unsigned char* mask, const double* p);
int abyssal_kalman_predict(abyssal_kalman* filter, const abyssal_model* model, const double* u, double dt,
                           const double* p);
int abyssal_kalman_update(abyssal_kalman* filter, const abyssal_model* model, const double* z, const unsigned char* mask,
                          const double* p);

/* Step over a whole sequence in one call, as T calls of abyssal_kalman_step would: row k is u = U + k n_u, dt =
 * dt[k dt_step] (dt_step 0: one dt for every row), z = Z + k n_y (NULL, or a row of NaN only: predict only), p =
 * P_rows + k p_step n_p (NULL: the defaults; p_step 0: one p for every row). After each row the state goes to
 * X + k n_x and P_out + k n_x^2 (NULL: not kept), the NIS of its update to nis[k] (NaN when none) and its entries
 * to dof[k] (NULL: not kept). A refused row stops the run: *row (may be NULL) receives its index and the code is
 * returned; the rows before it are committed (the caller restores a copy of the object for all-or-nothing). */
int abyssal_kalman_run(abyssal_kalman* filter, const abyssal_model* model, long long T, const double* U, const double* dt,
                       int dt_step, const double* Z, const double* P_rows, int p_step, double* X, double* P_out,
                       double* nis, int* dof, long long* row);

/* Integrate from the filter's time to t with u held (t equal to the filter's time: only u and p are held). p NULL:
 * the model's defaults. */
int abyssal_kalman_predict_to(abyssal_kalman* filter, const abyssal_model* model, double t, const double* u,
                              const double* p);

/* One sensor's measurement z (its n_y entries; NaN or mask 0: left out) stamped t, with R (its n_y x n_y; NULL: the
 * filter's) and q (its n_q own parameters, e.g. a leader's position; NULL: those of the held p). Ahead of the
 * filter's time: predicted to t with the held input first; behind: fused at t from the history (late). */
int abyssal_kalman_update_sensor(abyssal_kalman* filter, const abyssal_model* model, int sensor, double t,
                                 const double* z, const unsigned char* mask, const double* R, const double* q);

/* The index of the model's sensor called name, or -1. */
int abyssal_kalman_sensor_index(const abyssal_model* model, const char* name);

/* The state (n_x), its covariance (n_x x n_x) and time; pointers into the object, valid until its next call. */
const double* abyssal_kalman_x(const abyssal_kalman* filter);
const double* abyssal_kalman_P(const abyssal_kalman* filter);
double abyssal_kalman_time(const abyssal_kalman* filter);
/* report may be NULL (nothing is written); a NULL or uninitialised filter gives an empty report (nis NaN). */
void abyssal_kalman_get_report(const abyssal_kalman* filter, abyssal_kalman_report* report);
/* ABYSSAL_OK, ABYSSAL_E_MEMORY or ABYSSAL_E_SENSOR; report may be NULL. */
int abyssal_kalman_get_sensor_report(const abyssal_kalman* filter, int sensor, abyssal_sensor_report* report);
/* The id of the model the filter was built for (abyssal_model.id). */
unsigned long long abyssal_kalman_model_id(const abyssal_kalman* filter);

/* Replace the state (checked as x0, P0; the history restarts from it), or the noise covariances (checked as Q, R;
 * a new Q restarts the history, a new R applies to later measurements); a refusal changes nothing. */
int abyssal_kalman_reset(abyssal_kalman* filter, const double* x, const double* P);
int abyssal_kalman_set_Q(abyssal_kalman* filter, const double* Q);
int abyssal_kalman_set_R(abyssal_kalman* filter, const double* R);
int abyssal_kalman_set_sensor_R(abyssal_kalman* filter, const abyssal_model* model, int sensor, const double* R);

/* Rauch-Tung-Striebel smoothing over the history (options.smoothing): for each event it holds, oldest first, its
 * time t[k], the smoothed state x[k n_x ..] and covariance P[k n_x^2 ..] given every measurement in the history.
 * capacity: the rows the arrays hold; *count receives the events smoothed. ABYSSAL_OK, ABYSSAL_E_OPTIONS (no
 * smoothing gains kept), ABYSSAL_E_MEMORY (capacity too small) or ABYSSAL_E_DIVERGED. It computes in the object's
 * scratch; the filter's state, reports and history are unchanged. */
int abyssal_kalman_smooth(abyssal_kalman* filter, double* t, double* x, double* P, int capacity, int* count);

/* One backward Rauch-Tung-Striebel step (the smoother's one implementation): from the smoothed (xs, Ps) at the
 * end of a predict whose prior was (x, P), prediction (x_pred, P_pred) and gain G = C P_pred^-1, the smoothed
 * state at its start: xs_out = x + G (xs - x_pred), Ps_out = P + G (Ps - P_pred) G^T (exactly symmetric);
 * differences of angle states (flags, NULL: none) wrapped. scratch: 2 n^2 doubles. Returns 1 when finite. */
int abyssal_rts_step(int n, const unsigned char* angle_states, const double* x, const double* P, const double* x_pred,
                     const double* P_pred, const double* G, const double* xs, const double* Ps, double* xs_out,
                     double* Ps_out, double* scratch);

/* What a return code means (a static string). */
const char* abyssal_kalman_message(int code);

/* Byte offsets of the object's parts, for bindings that view its memory (Python); -1 for an unknown item. */
enum {
  ABYSSAL_AT_X = 0,            /* + k, k < 4: the buffer sets of x (the current one is the int at AT_CURRENT) */
  ABYSSAL_AT_P = 4,            /* + k, k < 4: of P */
  ABYSSAL_AT_INNOVATION = 8,   /* + k, k < 2 */
  ABYSSAL_AT_S = 10,           /* + k, k < 2 */
  ABYSSAL_AT_Q = 12, ABYSSAL_AT_R = 13, ABYSSAL_AT_GATE = 14, ABYSSAL_AT_CURRENT = 15, ABYSSAL_AT_REPORTED = 16,
  ABYSSAL_AT_NIS = 17, ABYSSAL_AT_NIS_DOF = 18, ABYSSAL_AT_REPAIRS = 19, ABYSSAL_AT_SUBSTEPS = 20,
  ABYSSAL_AT_STATE_BYTES = 21, ABYSSAL_AT_TIME = 22, ABYSSAL_AT_SENSORS = 23, ABYSSAL_AT_REPORTED_ROWS = 24,
  ABYSSAL_AT_REPORTED_SENSOR = 25, ABYSSAL_AT_INFLATIONS = 26, ABYSSAL_AT_LATE = 27, ABYSSAL_AT_HISTORY = 28,
  ABYSSAL_AT_COUNT = 29
};
long long abyssal_kalman_offset(const abyssal_kalman* filter, int item);

/* Doubles per sensor in the block at ABYSSAL_AT_SENSORS, and the fields' order. The fields before
 * ABYSSAL_SENSOR_LAST_T follow the measurements in time order (a late measurement's replay recounts them); LAST_T
 * and LATE follow the calls (the stream's last stamp, and how many of its measurements came late). */
enum {
  ABYSSAL_SENSOR_USED = 0, ABYSSAL_SENSOR_GATED, ABYSSAL_SENSOR_INFLATIONS, ABYSSAL_SENSOR_REJECTED,
  ABYSSAL_SENSOR_STREAK_INFLATIONS, ABYSSAL_SENSOR_NIS, ABYSSAL_SENSOR_NIS_DOF, ABYSSAL_SENSOR_ACCEPTED,
  ABYSSAL_SENSOR_ACCEPTED_AT_STREAK, ABYSSAL_SENSOR_LAST_T, ABYSSAL_SENSOR_LATE, ABYSSAL_SENSOR_FIELDS
};

#ifdef __cplusplus
}
#endif

#endif /* ABYSSAL_KALMAN_H */
