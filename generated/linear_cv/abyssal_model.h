/* Copied by abyssal's code generator from abyssal/symbolic/abyssal_model.h, the type of linear_cv_descriptor: do not edit. */
/* abyssal_model.h: what the C runtime of abyssal knows about one model.
 *
 * `abyssal regenerate` writes one descriptor per model, <m>_descriptor.c, defining
 *
 *     const abyssal_model <m>_descriptor;
 *
 * with the model's sizes, default parameters, names and units, its sensors, and pointers to its generated
 * functions: the step f (with the model's substeps), its Jacobians F = df/dx and G = df/dw, each sensor's h_k
 * and H_k = dh_k/dx, and the structure-of-arrays kernels that evaluate f and each h_k over many points. That is
 * all the code that grows with the model; every filter's algebra (EKF, UKF, CKF, robust updates, smoothing) is
 * written once in the runtime (runtime/c/abyssal_kalman*.h) and reaches the model only through this descriptor,
 * so one runtime serves every model. Hand-written C99; it lives beside the code generator that writes
 * descriptors (symbolic/codegen.py), which copies it into every generated folder.
 */
#ifndef ABYSSAL_MODEL_H
#define ABYSSAL_MODEL_H

#ifdef __cplusplus
extern "C" {
#endif

/* The version of this layout: the runtime refuses a descriptor of another version. */
#define ABYSSAL_MODEL_VERSION 2

/* CasADi's calling convention of every generated function: arrays of argument and result pointers,
 * integer and real work arrays of the sizes recorded beside it, and a memory index (0). Returns 0. */
typedef int (*abyssal_eval)(const double** arg, double** res, long long* iw, double* w, int mem);

/* The structure-of-arrays kernels: points 0..n-1, entry i of point j at [i * ld + j] of every per-point argument
 * and result; the other arguments are shared by all points. f_soa(x, u per point; p, dt shared) -> x_next;
 * a sensor's h_soa(x per point; p shared) -> y. */
typedef int (*abyssal_soa_eval)(long long n, long long ld, const double** arg, double** res);

/* One generated function and the sizes one call needs (eval is NULL when it was not generated). */
typedef struct {
  abyssal_eval eval;
  int sz_arg, sz_res, sz_iw, sz_w;
} abyssal_function;

/* One sensor: a measurement y_k = h_k(x, p) of its own size, noise, angle outputs and parameters. */
typedef struct {
  const char* name;
  int n_y;                            /* its outputs */
  int offset;                         /* its first output in the model's stacked measurement (all sensors) */
  int p_offset, n_q;                  /* its own parameters (a lever arm, a leader's position): entries
                                         p_offset .. p_offset + n_q - 1 of the model's parameter vector p */
  const double* R_default;            /* n_y x n_y declared noise covariance (column-major); NULL: none declared */
  const unsigned char* angle_outputs; /* n_y flags: 1 for an angle (its innovations wrap to (-pi, pi]) */
  const char* const* output_names;    /* n_y */
  const char* const* output_units;    /* n_y */
  abyssal_function h, H;              /* h(x, p) -> y (n_y), H(x, p) -> dh/dx (n_y x n_x, column-major) */
  abyssal_soa_eval h_soa;             /* h over points */
} abyssal_sensor;

typedef struct {
  int version;                        /* ABYSSAL_MODEL_VERSION */
  const char* name;
  unsigned long long id;              /* the first 64 bits of the sha256 of the model's equations: a filter object
                                         records it and refuses another model's descriptor */
  int n_x, n_u, n_p, n_w, n_y;        /* n_y: every sensor's outputs, stacked in the order of the sensors */
  int n_sensors;
  const double* p_default;            /* n_p defaults */
  const char* const* state_names;     const char* const* state_units;      /* n_x */
  const char* const* input_names;     const char* const* input_units;      /* n_u */
  const char* const* parameter_names; const char* const* parameter_units;  /* n_p */
  const unsigned char* angle_states;  /* n_x flags: 1 for an angle state (differences wrap to (-pi, pi]) */
  /* the model: f(x, u, p, dt) -> x_next (the model's discretisation and substeps, noise inputs w = 0),
   * F(x, u, p, dt) = df/dx, G(x, u, p, dt) = df/dw (n_x x n_w; eval NULL when n_w = 0), f over many points */
  abyssal_function f, F, G;
  abyssal_soa_eval f_soa;
  const abyssal_sensor* sensors;      /* n_sensors */
} abyssal_model;

#ifdef __cplusplus
}
#endif

#endif /* ABYSSAL_MODEL_H */
