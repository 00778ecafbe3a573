/* kalman_timing: per-step times of the Kalman runtime called from C (bench_filters.py builds and runs it).
 *
 *     kalman_timing TRAJECTORY REPEATS
 *
 * Linked with a model's compiled library (abyssal's cache); -DDESCRIPTOR=<m>_descriptor names the model, and
 * -DFUSED_STEPS="<m>_ckf_step, <m>_ekf_step" its generated fused steps, timed alone as peers (the whole step as one
 * generated function, no checks, no gate: the C of the previous Python path).
 * TRAJECTORY: text, first line "T n_u n_y", then T rows of u (n_u) and z (n_y); x0 = 0, P0 = 0.3 I,
 * Q = diag(1e-4 (first 8), 1e-2 (rest)), R = diag(0.05, 0.05, 0.02, 0.01, ...) as bench_filters.trajectory.
 * Prints one line per measurement: "<label> <ns per step>", the minimum over REPEATS runs of the whole trajectory
 * (each from a fresh init), so a loaded machine's interruptions are left out as far as possible. C99.
 */
#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "abyssal_kalman.h"

extern const abyssal_model DESCRIPTOR;
typedef int (*generated_step)(const double** arg, double** res, long long* iw, double* w, int mem);
extern int CKF_STEP(const double** arg, double** res, long long* iw, double* w, int mem);
extern int EKF_STEP(const double** arg, double** res, long long* iw, double* w, int mem);

/* ns per step of a generated fused step (x, P, u, p, dt, Q, z, R, mask) -> (x, P, nu, S, ok) over the trajectory */
static double fused(generated_step step, const abyssal_model* model, int T, const double* U, const double* Z,
                    const double* P0, const double* Q, const double* R, int repeats, double now_ns(void)) {
  static double x[2][64], P[2][64 * 64], nu[64], S[64 * 64], mask[64], w[1 << 16], ok, dt = 0.1;
  static long long iw[64];
  int n = model->n_x, m = model->n_y, rep, k, c, i;
  double best = INFINITY;
  for (i = 0; i < m; ++i) mask[i] = 1.0;
  for (rep = 0; rep < repeats; ++rep) {
    double t0;
    memset(x, 0, sizeof x);
    memcpy(P[0], P0, sizeof(double) * (size_t)(n * n));
    c = 0;
    t0 = now_ns();
    for (k = 1; k < T; ++k) {
      const double* arg[64] = {0};
      double* res[64] = {0};
      arg[0] = x[c]; arg[1] = P[c]; arg[2] = U + k * model->n_u; arg[3] = model->p_default; arg[4] = &dt; arg[5] = Q;
      arg[6] = Z + k * m; arg[7] = R; arg[8] = mask;
      res[0] = x[1 - c]; res[1] = P[1 - c]; res[2] = nu; res[3] = S; res[4] = &ok;
      step(arg, res, iw, w, 0);
      c = 1 - c;
    }
    t0 = (now_ns() - t0) / (T - 1);
    if (t0 < best) best = t0;
  }
  return best;
}

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
  int T, n_u, n_y, repeats, k, i, rep, which, n = model->n_x;
  double *U, *Z, *x0, *P0, *Q, *R, *memory;
  FILE* in;
  if (argc != 3) return 2;
  repeats = atoi(argv[2]);
  in = fopen(argv[1], "r");
  if (!in || fscanf(in, "%d %d %d", &T, &n_u, &n_y) != 3 || n_u != model->n_u || n_y != model->n_y) return 2;
  U = malloc(sizeof(double) * (size_t)(T * n_u));
  Z = malloc(sizeof(double) * (size_t)(T * n_y));
  x0 = calloc((size_t)n, sizeof(double));
  P0 = calloc((size_t)(n * n), sizeof(double));
  Q = calloc((size_t)(n * n), sizeof(double));
  R = calloc((size_t)(n_y * n_y), sizeof(double));
  if (!U || !Z || !x0 || !P0 || !Q || !R) return 2;
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
  printf("generated_ckf_step %.2f\n", fused(CKF_STEP, model, T, U, Z, P0, Q, R, repeats, now_ns));
  printf("generated_ekf_step %.2f\n", fused(EKF_STEP, model, T, U, Z, P0, Q, R, repeats, now_ns));
  for (which = 0; which < 3; ++which) {
    abyssal_kalman_options options = abyssal_kalman_default_options(filters[which].kind);
    size_t bytes = abyssal_kalman_work_size(model, &options);
    double best = INFINITY;
    abyssal_kalman* filter;
    if (bytes == 0) continue; /* the model lacks this family */
    memory = malloc(bytes);
    if (!memory) return 2;
    for (rep = 0; rep < repeats; ++rep) {
      double t0;
      if (abyssal_kalman_init(memory, bytes, model, &options, x0, P0, Q, R, 0.0, &filter) != ABYSSAL_OK) return 3;
      abyssal_kalman_step(filter, model, U, 0.1, Z, 0, 0); /* the first step checks dt's stability: not timed */
      t0 = now_ns();
      for (k = 1; k < T; ++k)
        if (abyssal_kalman_step(filter, model, U + k * n_u, 0.1, Z + k * n_y, 0, 0) < 0) return 4;
      t0 = (now_ns() - t0) / (T - 1);
      if (t0 < best) best = t0;
      sink = abyssal_kalman_x(filter)[0];
    }
    printf("%s %.2f\n", filters[which].label, best);
    printf("%s_bytes %zu\n", filters[which].label, bytes);
    if (filters[which].kind == ABYSSAL_CKF) { /* the gate's cost: one judgement of the last update's nu and S */
      double best_gate = INFINITY, nis = 0.0, scratch[64 * 64 + 64];
      abyssal_kalman_report report;
      const abyssal_gate* gate = (const abyssal_gate*)(const void*)((const char*)filter +
                                                                   abyssal_kalman_offset(filter, ABYSSAL_AT_GATE));
      unsigned char present[64], gated[64];
      abyssal_kalman_get_report(filter, &report);
      for (rep = 0; rep < repeats && n_y <= 64; ++rep) {
        double t0 = now_ns();
        for (k = 0; k < 1000; ++k) {
          memset(present, 1, (size_t)n_y);
          memset(gated, 0, (size_t)n_y);
          abyssal_gate_judge(gate, 0, report.innovation, report.S, present, gated, &nis, scratch);
        }
        t0 = (now_ns() - t0) / 1000;
        if (t0 < best_gate) best_gate = t0;
      }
      sink = nis;
      printf("gate %.2f\n", best_gate);
    }
    free(memory);
  }
  free(U);
  free(Z);
  free(x0);
  free(P0);
  free(Q);
  free(R);
  return 0;
}
