/* abyssal_kalman_binding.c: the runtime's calls in CasADi's calling convention, so that Python reaches them
 * through its existing fast binding (casadi.external + Function.buffer: buffers bound once, no argument
 * conversion per call) instead of ctypes. Not needed on a vehicle: `abyssal export` leaves this file out.
 *
 *     abyssal_kalman_step_call(arg, res, iw, w, mem)        abyssal_kalman_step(filter, model, u, dt, z, NULL, p)
 *     abyssal_kalman_predict_call(...)                      abyssal_kalman_predict(filter, model, u, dt, p)
 *     abyssal_kalman_update_call(...)                       abyssal_kalman_update(filter, model, z, NULL, p)
 *     abyssal_kalman_check_p_call(...)                      abyssal_kalman_update(filter, model, NULL, NULL, p)
 *     abyssal_kalman_predict_to_call(...)                   abyssal_kalman_predict_to(filter, model, t, u, p)
 *     abyssal_kalman_update_sensor_call(...)                abyssal_kalman_update_sensor(filter, model, sensor, t, z,
 *                                                               NULL, has_R ? R : NULL, has_q ? q : NULL)
 *
 *       arg[0]  the filter object (abyssal_kalman_init's memory)
 *       arg[1]  the call block: [model, dt or t, sensor, has_R, has_q, u (n_u), z (n_y), p (n_p), R (n_y^2),
 *               q (n_p)]; `model` holds the descriptor's address (its 8 bytes, not a number); a sensor's z, R and q
 *               take the first n_y_k, n_y_k^2 and n_q_k places of theirs; NaN entries of z are missing
 *       res[0]  the call's return code (abyssal_kalman.h), as a double
 *
 * One entry point per call, so that the hot path writes no command. Hand-written C99.
 */
#include <string.h>

#include "abyssal_kalman.h"

/* What casadi.external reads about each entry: two inputs and one output, each declared 1 x 1 (a buffer of at
 * least one double; CasADi only checks that a bound buffer is not smaller), no work arrays. */
static const long long scalar_sparsity[3] = {1, 1, 1};

static const abyssal_model* block_model(const double* block) {
  unsigned long long bits;
  memcpy(&bits, block, sizeof bits);
  return (const abyssal_model*)(size_t)bits;
}

#define ABYSSAL_CASADI_ENTRY(name, call)                                                                          \
  int name(const double** arg, double** res, long long* iw, double* w, int mem) {                                \
    abyssal_kalman* filter = (abyssal_kalman*)(void*)arg[0];                                                    \
    const double* block = arg[1];                                                                               \
    const abyssal_model* model = block_model(block);                                                            \
    const double time = block[1];                                                                               \
    const int sensor = (int)block[2], has_R = block[3] != 0.0, has_q = block[4] != 0.0;                         \
    const double* u = block + 5;                                                                                \
    const double* z = model ? u + model->n_u : 0;                                                               \
    const double* p = model ? z + model->n_y : 0;                                                               \
    const double* R = model ? p + model->n_p : 0;                                                               \
    const double* q = model ? R + model->n_y * model->n_y : 0;                                                  \
    (void)iw;                                                                                                   \
    (void)w;                                                                                                    \
    (void)mem;                                                                                                  \
    (void)time;                                                                                                 \
    (void)sensor;                                                                                               \
    (void)has_R;                                                                                                \
    (void)has_q;                                                                                                \
    (void)u;                                                                                                    \
    (void)z;                                                                                                    \
    (void)p;                                                                                                    \
    (void)R;                                                                                                    \
    (void)q;                                                                                                    \
    res[0][0] = model ? (call) : ABYSSAL_E_MODEL;                                                               \
    return 0;                                                                                                   \
  }                                                                                                             \
  long long name##_n_in(void) { return 2; }                                                                     \
  long long name##_n_out(void) { return 1; }                                                                    \
  const long long* name##_sparsity_in(long long i) { return i >= 0 && i < 2 ? scalar_sparsity : 0; }           \
  const long long* name##_sparsity_out(long long i) { return i == 0 ? scalar_sparsity : 0; }                    \
  int name##_work(long long* sz_arg, long long* sz_res, long long* sz_iw, long long* sz_w) {                    \
    if (sz_arg) *sz_arg = 2;                                                                                    \
    if (sz_res) *sz_res = 1;                                                                                    \
    if (sz_iw) *sz_iw = 0;                                                                                      \
    if (sz_w) *sz_w = 0;                                                                                        \
    return 0;                                                                                                   \
  }

ABYSSAL_CASADI_ENTRY(abyssal_kalman_step_call, abyssal_kalman_step(filter, model, u, time, z, 0, p))
ABYSSAL_CASADI_ENTRY(abyssal_kalman_predict_call, abyssal_kalman_predict(filter, model, u, time, p))
ABYSSAL_CASADI_ENTRY(abyssal_kalman_update_call, abyssal_kalman_update(filter, model, z, 0, p))
ABYSSAL_CASADI_ENTRY(abyssal_kalman_check_p_call, abyssal_kalman_update(filter, model, 0, 0, p))
ABYSSAL_CASADI_ENTRY(abyssal_kalman_predict_to_call, abyssal_kalman_predict_to(filter, model, time, u, p))
ABYSSAL_CASADI_ENTRY(abyssal_kalman_update_sensor_call,
                     abyssal_kalman_update_sensor(filter, model, sensor, time, z, 0, has_R ? R : 0, has_q ? q : 0))
