/* kalman_timing: per-step times of the Kalman runtime called from C (bench_filters.py builds and runs it).
 *
 *     kalman_timing TRAJECTORY REPEATS FIRST [FILTER]   (FILTER: EKF, UKF or CKF alone, e.g. to profile it)
 *
 * Linked with a model's compiled library and the runtime's (abyssal's cache); -DDESCRIPTOR=<m>_descriptor names
 * the model. TRAJECTORY: text, first line "T n_u n_y", then T rows of u (n_u) and z (n_y); x0 = 0, P0 = 0.3 I,
 * Q = diag(1e-4 (first 8), 1e-2 (rest)), R = diag(0.05, 0.05, 0.02, 0.01, ...) as bench_filters.trajectory.
 * Prints one line per measurement: "<label> <ns per step>", the minimum over REPEATS runs of rows FIRST.. (each run
 * from a fresh init, its rows 0..FIRST-1 stepped untimed), so a loaded machine's interruptions are left out as far as
 * possible:
 *
 *   <F>          abyssal_kalman_step per row, F = EKF, UKF, CKF
 *   <F>_run      abyssal_kalman_run over the rows (one call)
 *   <F>_bytes    the filter object's bytes
 *   gate         one judgement of the innovation gate (the CKF's last update)
 * C99.
 */
#define _POSIX_C_SOURCE 200112L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "abyssal_kalman.h"

extern const abyssal_model DESCRIPTOR;

static double now_ns(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return 1e9 * (double)t.tv_sec + (double)t.tv_nsec;
}

static volatile double sink;

int main(int argc, char** argv) {
  static const struct { abyssal_filter kind; const char* label; } filters[] = {
      {ABYSSAL_EKF, "EKF"}, {ABYSSAL_UKF, "UKF"}, {ABYSSAL_CKF, "CKF"}};
  const abyssal_model* model = &DESCRIPTOR;
  int T, n_u, n_y, repeats, first, k, i, rep, which, n = model->n_x;
  double *U, *Z, *x0, *P0, *Q, *R, *memory, *X, *Pout, *nis, dt = 0.1;
  int* dof;
  FILE* in;
  if (argc != 4 && argc != 5) return 2;
  repeats = atoi(argv[2]);
  first = atoi(argv[3]);
  in = fopen(argv[1], "r");
  if (!in || fscanf(in, "%d %d %d", &T, &n_u, &n_y) != 3 || n_u != model->n_u || n_y != model->n_y || first < 1 ||
      first >= T)
    return 2;
  U = malloc(sizeof(double) * (size_t)(T * n_u));
  Z = malloc(sizeof(double) * (size_t)(T * n_y));
  X = malloc(sizeof(double) * (size_t)(T * n));
  Pout = malloc(sizeof(double) * (size_t)(T * n * n));
  nis = malloc(sizeof(double) * (size_t)T);
  dof = malloc(sizeof(int) * (size_t)T);
  x0 = calloc((size_t)n, sizeof(double));
  P0 = calloc((size_t)(n * n), sizeof(double));
  Q = calloc((size_t)(n * n), sizeof(double));
  R = calloc((size_t)(n_y * n_y), sizeof(double));
  if (!U || !Z || !X || !Pout || !nis || !dof || !x0 || !P0 || !Q || !R) return 2;
  for (k = 0; k < T; ++k) {
    for (i = 0; i < n_u; ++i)
      if (fscanf(in, "%lf", &U[k * n_u + i]) != 1) return 2;
    for (i = 0; i < n_y; ++i)
      if (fscanf(in, "%lf", &Z[k * n_y + i]) != 1) return 2;
  }
  fclose(in);
  for (i = 0; i < n; ++i) {
    P0[i * (n + 1)] = 0.3;
    Q[i * (n + 1)] = i < 8 ? 1e-4 : 1e-2;
  }
  for (i = 0; i < n_y; ++i) R[i * (n_y + 1)] = i < 2 ? 0.05 : (i == 2 ? 0.02 : 0.01);
  for (which = 0; which < 3; ++which) {
    abyssal_kalman_options options = abyssal_kalman_default_options(filters[which].kind);
    size_t bytes = abyssal_kalman_work_size(model, &options);
    double best = INFINITY, best_run = INFINITY;
    abyssal_kalman* filter;
    if (bytes == 0) return 3;
    if (argc == 5 && strcmp(argv[4], filters[which].label) != 0) continue;
    if (posix_memalign((void**)&memory, 64, bytes) != 0) return 2; /* on a cache line, as Python's (aligned_zeros) */
    for (rep = 0; rep < repeats; ++rep) {
      double t0;
      memset(memory, 0, bytes);
      if (abyssal_kalman_init(memory, bytes, model, &options, x0, P0, Q, R, 0.0, &filter) != ABYSSAL_OK) return 3;
      for (k = 0; k < first; ++k) /* (the first step checks dt's stability, and what Python leaves out too) */
        if (abyssal_kalman_step(filter, model, U + k * n_u, dt, Z + k * n_y, 0, 0) < 0) return 4;
      t0 = now_ns();
      for (k = first; k < T; ++k)
        if (abyssal_kalman_step(filter, model, U + k * n_u, dt, Z + k * n_y, 0, 0) < 0) return 4;
      t0 = (now_ns() - t0) / (T - first);
      if (t0 < best) best = t0;
      sink = abyssal_kalman_x(filter)[0];
      memset(memory, 0, bytes);
      if (abyssal_kalman_init(memory, bytes, model, &options, x0, P0, Q, R, 0.0, &filter) != ABYSSAL_OK) return 3;
      for (k = 0; k < first; ++k)
        if (abyssal_kalman_step(filter, model, U + k * n_u, dt, Z + k * n_y, 0, 0) < 0) return 4;
      t0 = now_ns();
      if (abyssal_kalman_run(filter, model, T - first, U + first * n_u, &dt, 0, Z + first * n_y, 0, 0, X, Pout, nis, dof,
                             0) < 0)
        return 4;
      t0 = (now_ns() - t0) / (T - first);
      if (t0 < best_run) best_run = t0;
      sink = X[0];
    }
    printf("%s %.2f\n", filters[which].label, best);
    printf("%s_run %.2f\n", filters[which].label, best_run);
    printf("%s_bytes %zu\n", filters[which].label, bytes);
    if (filters[which].kind == ABYSSAL_CKF) { /* the gate's cost: one judgement of the last update's nu and S */
      double best_gate = INFINITY, g = 0.0, scratch[64 * 64 + 64];
      abyssal_kalman_report report;
      const abyssal_gate* gate = (const abyssal_gate*)(const void*)((const char*)filter +
                                                                   abyssal_kalman_offset(filter, ABYSSAL_AT_GATE));
      unsigned char present[64], gated[64];
      abyssal_kalman_get_report(filter, &report);
      for (rep = 0; rep < repeats && n_y <= 64 && report.innovation; ++rep) {
        double t0 = now_ns();
        for (k = 0; k < 1000; ++k) {
          memset(present, 1, (size_t)n_y);
          memset(gated, 0, (size_t)n_y);
          abyssal_gate_judge(gate, 0, report.innovation, report.S, present, gated, &g, scratch);
        }
        t0 = (now_ns() - t0) / 1000;
        if (t0 < best_gate) best_gate = t0;
      }
      sink = g;
      printf("gate %.2f\n", best_gate);
    }
    free(memory);
  }
  free(U);
  free(Z);
  free(X);
  free(Pout);
  free(nis);
  free(dof);
  free(x0);
  free(P0);
  free(Q);
  free(R);
  return 0;
}
