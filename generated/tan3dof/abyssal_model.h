/* Copied by abyssal's code generator from abyssal/symbolic/abyssal_model.h, the type of tan3dof_descriptor: do not edit. */
/* abyssal_model.h: what the C runtime of abyssal knows about one model.
 *
 * `abyssal regenerate` writes one descriptor per model, <m>_descriptor.c, defining
 *
 *     const abyssal_model <m>_descriptor;
 *
 * with the model's sizes, default parameters, names and units, and pointers to its generated functions
 * (NULL for a filter family the model was generated without). The runtime (runtime/c/abyssal_kalman.h)
 * reaches the model only through this descriptor, so one runtime serves every model. Hand-written C99; it
 * lives beside the code generator that writes descriptors (symbolic/codegen.py), which copies it into
 * every generated folder.
 */
#ifndef ABYSSAL_MODEL_H
#define ABYSSAL_MODEL_H

#ifdef __cplusplus
extern "C" {
#endif

/* CasADi's calling convention of every generated function: arrays of argument and result pointers,
 * integer and real work arrays of the sizes recorded beside it, and a memory index (0). Returns 0. */
typedef int (*abyssal_eval)(const double** arg, double** res, long long* iw, double* w, int mem);

/* The structure-of-arrays kernels <m>_f_soa and <m>_h_soa: points 0..n-1, entry i of point j at
 * [i * ld + j] of every per-point argument and result. */
typedef int (*abyssal_soa_eval)(long long n, long long ld, const double** arg, double** res);

/* One generated function and the sizes one call needs (eval is NULL when it was not generated). */
typedef struct {
  abyssal_eval eval;
  int sz_arg, sz_res, sz_iw, sz_w;
} abyssal_function;

typedef struct {
  const char* name;
  int n_x, n_u, n_p, n_y;
  const double* p_default;                                      /* n_p defaults */
  const char* const* state_names;     const char* const* state_units;      /* n_x */
  const char* const* input_names;     const char* const* input_units;      /* n_u */
  const char* const* parameter_names; const char* const* parameter_units;  /* n_p */
  const char* const* output_names;    const char* const* output_units;     /* n_y */
  /* the model: f(x, u, p, dt) -> x_next, F = df/dx, h(x, p) -> y, H = dh/dx, and f, h over many points */
  abyssal_function f, F, h, H;
  abyssal_soa_eval f_soa, h_soa;
  /* EKF: predict(x, P, u, p, dt, Q) -> (x, P, ok); update(x, P, z, p, R, mask) -> (x, P, nu, S, ok);
   * step(x, P, u, p, dt, Q, z, R, mask) -> (x, P, nu, S, ok) */
  abyssal_function ekf_predict, ekf_update, ekf_step;
  /* the rule of a sigma-point predict: points(x, P[, abk]) -> (X (points x n_x), ok); weights([abk]) -> (wm, wc);
   * update(x, P, z, p, R, mask[, abk]) -> (x, P, nu, S, ok) */
  abyssal_function ckf_predict_points, ckf_predict_weights, ckf_update;
  abyssal_function ukf_predict_points, ukf_predict_weights, ukf_update;
  /* robust updates: (x, P, z, p, R, mask, abk, sigma | gamma) -> (x, P, nu, S, ok) */
  abyssal_function mcukf_update, huber_ukf_update;
} abyssal_model;

#ifdef __cplusplus
}
#endif

#endif /* ABYSSAL_MODEL_H */
