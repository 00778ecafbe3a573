/* abyssal_kalman_binding.c: the runtime's calls in CasADi's calling convention, so that Python reaches them
 * through its existing fast binding (casadi.external + Function.buffer, buffers bound once, ~0.05-0.2 us per
 * call) instead of ctypes. Not needed on a vehicle: `abyssal export` leaves this file out.
 *
 *     abyssal_kalman_call(arg, res, iw, w, mem)
 *       arg[0]  the filter object (abyssal_kalman_init's memory)
 *       arg[1]  the call block [command, dt, u (n_u), z (n_y), p (n_p)]
 *       res[0]  the return code of the call (abyssal_kalman.h), as a double
 *
 * command: ABYSSAL_CALL_STEP (u, dt, z; NaN entries of z missing), ABYSSAL_CALL_PREDICT (u, dt),
 * ABYSSAL_CALL_UPDATE (z), ABYSSAL_CALL_CHECK_P (only p is checked: an update without a measurement).
 * Every command uses p. Hand-written C99.
 */
#include "abyssal_kalman.h"

enum { ABYSSAL_CALL_STEP = 1, ABYSSAL_CALL_PREDICT = 2, ABYSSAL_CALL_UPDATE = 3, ABYSSAL_CALL_CHECK_P = 4 };

int abyssal_kalman_call(const double** arg, double** res, long long* iw, double* w, int mem) {
  abyssal_kalman* filter = (abyssal_kalman*)(void*)arg[0];
  const abyssal_model* model = abyssal_kalman_model(filter);
  const double* block = arg[1];
  const double *u = block + 2, *z, *p;
  int code;
  (void)iw;
  (void)w;
  (void)mem;
  if (!model) {
    res[0][0] = ABYSSAL_E_MEMORY;
    return 0;
  }
  z = u + model->n_u;
  p = z + model->n_y;
  switch ((int)block[0]) {
    case ABYSSAL_CALL_STEP: code = abyssal_kalman_step(filter, u, block[1], z, 0, p); break;
    case ABYSSAL_CALL_PREDICT: code = abyssal_kalman_predict(filter, u, block[1], p); break;
    case ABYSSAL_CALL_UPDATE: code = abyssal_kalman_update(filter, z, 0, p); break;
    case ABYSSAL_CALL_CHECK_P: code = abyssal_kalman_update(filter, 0, 0, p); break;
    default: code = ABYSSAL_E_FILTER; break;
  }
  res[0][0] = code;
  return 0;
}

/* What casadi.external reads about the function: two inputs and one output, each declared 1 x 1 (a buffer of
 * at least one double; CasADi only checks that a bound buffer is not smaller), no work arrays. */
static const long long scalar_sparsity[3] = {1, 1, 1};

long long abyssal_kalman_call_n_in(void) { return 2; }
long long abyssal_kalman_call_n_out(void) { return 1; }
const long long* abyssal_kalman_call_sparsity_in(long long i) { return i >= 0 && i < 2 ? scalar_sparsity : 0; }
const long long* abyssal_kalman_call_sparsity_out(long long i) { return i == 0 ? scalar_sparsity : 0; }

int abyssal_kalman_call_work(long long* sz_arg, long long* sz_res, long long* sz_iw, long long* sz_w) {
  if (sz_arg) *sz_arg = 2;
  if (sz_res) *sz_res = 1;
  if (sz_iw) *sz_iw = 0;
  if (sz_w) *sz_w = 0;
  return 0;
}
