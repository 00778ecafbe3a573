/* kalman_loop: the C side of bench_filters' paired timings. Built as a shared library and called from the bench's own
 * process on a filter object Python built (the same options, the same memory, the runtime library Python loaded): a C
 * loop of abyssal_kalman_step over rows, timed inside, so that each Python run of the rows has a C run of the same
 * rows beside it within milliseconds. C99.
 */
#define _POSIX_C_SOURCE 200112L
#include <time.h>

#include "abyssal_kalman.h"

double abyssal_bench_steps(abyssal_kalman* filter, const abyssal_model* model, long long rows, const double* U, int n_u,
                           const double* Z, int n_y, double dt);

/* Nanoseconds of abyssal_kalman_step over rows 0..rows-1 of U (rows x n_u) and Z (rows x n_y) at one dt; -1 when a
 * step is refused. */
double abyssal_bench_steps(abyssal_kalman* filter, const abyssal_model* model, long long rows, const double* U, int n_u,
                           const double* Z, int n_y, double dt) {
  struct timespec start, end;
  long long k;
  clock_gettime(CLOCK_MONOTONIC, &start);
  for (k = 0; k < rows; ++k)
    if (abyssal_kalman_step(filter, model, U + k * n_u, dt, Z + k * n_y, 0, 0) < 0) return -1.0;
  clock_gettime(CLOCK_MONOTONIC, &end);
  return 1e9 * (double)(end.tv_sec - start.tv_sec) + (double)(end.tv_nsec - start.tv_nsec);
}
