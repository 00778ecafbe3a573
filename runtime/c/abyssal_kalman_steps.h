/* abyssal_kalman_steps.h: the algebra of every Kalman-type filter on one Gaussian N(x, P), written once and
 * generic over the dimensions; the model enters only through its descriptor (abyssal_model.h): f, F, each
 * sensor's h and H, and the structure-of-arrays kernels of f and h over the sigma points.
 *
 *   predict  EKF:           x' = f(x, u, p, dt), P' = F P F^T + Q, F = df/dx (the variational Jacobian of the step)
 *            UKF, CKF:      points X_k = x + L xi_k (P = L L^T, guarded Cholesky), propagated through f in one call
 *                           of f_soa, x' = sum wm_k Y_k, P' = sum wc_k (Y_k - x')(Y_k - x')^T + Q
 *   update   EKF:           nu = z - h(x) (angles wrapped), S = H P H^T + R, K = P H^T S^-1, x + K nu, and the Joseph
 *                           form (I - K H) P (I - K H)^T + K R K^T (expanded: valid for the gain actually computed)
 *            UKF, CKF:      points redrawn from (x, P), Z_k = h(X_k) in one call of h_soa, z_pred = sum wm_k Z_k,
 *                           Pzz = sum wc_k dZ dZ^T, Pxz = sum wc_k (X_k - x) dZ^T, S = Pzz + R, x + K nu, P - K S K^T
 *            MCUKF, Huber:  the UKF update with R replaced by R~ from the innovation whitened by R = a a^T
 *                           (seed 002 eqs. 31-39): maximum correntropy R~ = a C^-1 a^T, C = diag(exp(-zeta^2 / 2 s^2))
 *                           (exponent capped at ABYSSAL_MCC_MAX_EXPONENT); Huber: huber_iterations reweightings
 *                           R~ = a diag(max(1, |zeta_i| / gamma)) a^T on the post-fit residual R~ S^-1 nu
 *
 * An update measures a *selection* of the model's sensors (one sensor, or all of them stacked in their order);
 * z, R, the present flags and the reported innovation and S are in the selection's stacked layout. Entries not
 * present are left out exactly (the algebra runs on the present ones; the reported innovation is 0 there and S
 * has an identity row and column there, so nu^T S^-1 nu counts the present entries only).
 *
 * Every function returns 1 when every Cholesky guard passed and every output is finite, else 0 (its outputs are
 * then unspecified: the caller repairs P and retries, or refuses). Matrices column-major. No allocation: `scratch`
 * is abyssal_steps_scratch_bytes() bytes, 8-byte aligned, reused by every call. Hand-written C99.
 */
#ifndef ABYSSAL_KALMAN_STEPS_H
#define ABYSSAL_KALMAN_STEPS_H

#include <stddef.h>

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

/* The kernel exponent cap of the correntropy update: an extreme outlier inflates R by at most e^50. */
#define ABYSSAL_MCC_MAX_EXPONENT 50.0

/* What a filter's algebra needs beyond the model: its rule and robust settings. */
typedef struct {
  abyssal_filter filter;
  double alpha, beta, kappa;  /* the scaled unscented rule (UKF, MCUKF, Huber); the cubature rule has none */
  double sigma;               /* MCUKF kernel bandwidth (inf: the plain UKF update) */
  double gamma;               /* Huber threshold (inf: the plain UKF update) */
  int huber_iterations;       /* Huber reweightings (>= 1) */
} abyssal_algebra;

/* 1 for the filters that propagate sigma points (UKF, CKF, MCUKF, Huber), 0 for the EKF. */
int abyssal_is_sigma_point(abyssal_filter filter);

/* The number of sigma points for n states: 2n (CKF), 2n + 1 (unscented), 0 (EKF). */
int abyssal_sigma_points(abyssal_filter filter, int n);

/* The rule's weights (points entries each; nothing for the EKF). Returns 1 when they are finite. */
int abyssal_sigma_weights(const abyssal_algebra* algebra, int n, double* wm, double* wc);

/* Bytes of scratch one call needs, for updates of up to max_rows stacked outputs (8-byte multiple). */
size_t abyssal_steps_scratch_bytes(const abyssal_model* model, const abyssal_algebra* algebra, int max_rows);

/* The prediction over dt with input u, parameters p and additive noise Q (n x n). P and Q must be exactly symmetric
 * (the filter object keeps them so; the batched steps symmetrise what they are given). When cross is
 * not NULL it receives C = E[(x_k - x)(x_k+1 - x')^T] (n x n): P F^T for the EKF, sum wc_k (X_k - x)(Y_k - x')^T
 * for the sigma-point rules: what Rauch-Tung-Striebel smoothing needs (its gain is C P'^-1). wm, wc: the rule's
 * weights (NULL for the EKF). */
int abyssal_predict_gaussian(const abyssal_model* model, const abyssal_algebra* algebra, const double* wm,
                             const double* wc, const double* x, const double* P, const double* u, const double* p,
                             double dt, const double* Q, double* x_pred, double* P_pred, double* cross, void* scratch);

/* The update of (x, P) with the selection's measurement: the sensors first .. first + count - 1 of the model
 * (one sensor, or all of them: the stacked measurement), rows = the sum of their outputs; z (rows; read only where present), present (rows flags), R (rows x rows,
 * exactly symmetric, as P), p the model's parameters (each sensor's own among them). Outputs: x_post, P_post (n x n,
 * exactly symmetric), innovation (rows) and S (rows x rows) in the reporting convention above; when not NULL,
 * Pxz (n x rows, zero columns where absent) and Pzz (rows x rows, the predicted measurement covariance without R,
 * zero where absent): what the gate's inflation along the measured directions uses. */
int abyssal_update_gaussian(const abyssal_model* model, const abyssal_algebra* algebra, const double* wm,
                            const double* wc, int first, int count, const double* x, const double* P,
                            const double* z, const unsigned char* present, const double* p, const double* R,
                            double* x_post, double* P_post, double* innovation, double* S, double* Pxz, double* Pzz,
                            void* scratch);

/* The batched steps (particle proposals, Gaussian-sum components): N slices of every argument at arg[k] + j
 * arg_step[k] (a step of 0 shares the argument), every result at res[k] + j res_step[k]: the calling convention of
 * the models' generated `_batch` entry points. The measurement is every sensor stacked; mask (1 / 0 per entry)
 * leaves entries out; the rule's settings are arguments after the model's (as the generated steps had them).
 *
 *   ABYSSAL_BATCH_PREDICT  (x, P, u, p, dt, Q [, abk])                      -> (x_pred, P_pred, ok)
 *   ABYSSAL_BATCH_UPDATE   (x, P, z, p, R, mask [, abk [, sigma | gamma]])  -> (x_post, P_post, innovation, S, ok)
 *   ABYSSAL_BATCH_STEP     (x, P, u, p, dt, Q, z, R, mask [, abk])          -> (x_post, P_post, innovation, S, ok)
 *
 * abk = (alpha, beta, kappa) for the unscented rules; ok is 1.0 when every guard passed and the slice is finite.
 * huber_iterations is the default (3). scratch: abyssal_steps_batch_scratch_bytes(). Returns 0 (-1: an unknown op
 * or filter). */
enum { ABYSSAL_BATCH_PREDICT = 0, ABYSSAL_BATCH_UPDATE = 1, ABYSSAL_BATCH_STEP = 2 };
size_t abyssal_steps_batch_scratch_bytes(const abyssal_model* model, abyssal_filter filter);
int abyssal_steps_batch(const abyssal_model* model, int filter, int op, void* scratch, long long N, const double** arg,
                        const long long* arg_step, double** res, const long long* res_step);

/* The stacked rows of a selection (the sum of its sensors' outputs); -1 when it is not within the model's sensors. */
int abyssal_selection_rows(const abyssal_model* model, int first, int count);

/* G = df/dw of the step (n_x x n_w, column-major) at (x, u, p, dt), the noise inputs held over the step. Returns 1
 * when it is finite (0 also when the model has no G). */
int abyssal_noise_jacobian(const abyssal_model* model, const abyssal_algebra* algebra, const double* x, const double* u,
                           const double* p, double dt, double* G, void* scratch);

#ifdef __cplusplus
}
#endif

#endif /* ABYSSAL_KALMAN_STEPS_H */
