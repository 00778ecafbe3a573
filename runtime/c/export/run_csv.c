/* run_csv: the exported filter over rows of a CSV file (an example of the C API, and the test-vector runner).
 *
 *     run_csv SETUP INPUT OUTPUT
 *
 * SETUP  lines "name value ...": x0 (n_x values), P0, Q (n_x * n_x, column-major), R (n_y * n_y) and, optionally,
 *        any option of abyssal_kalman_options by its field name (e.g. "gate_probability 1e-10"). Missing options
 *        keep the defaults of the exported filter (ABYSSAL_EXPORTED_FILTER).
 * INPUT  a header line, then one row per step: dt, u_0 ... u_{n_u - 1}, z_0 ... z_{n_y - 1} (comma-separated;
 *        "nan" marks a missing entry: a row with every z entry nan only predicts); or, when the header begins with
 *        "t,", one row per time-stamped call: "t, -1, u_0 ... u_{n_u - 1}" is abyssal_kalman_predict_to(t, u) (u held
 *        over the interval that ends at t), "t, k, z_0 ... z_{n_y_k - 1}" is abyssal_kalman_update_sensor(k, t, z)
 *        for sensor k's outputs (a late one is fused at its stamp from the history), optionally followed by the
 *        n_y_k * n_y_k entries of that measurement's own R (column-major).
 * OUTPUT a header line, then one row per step (or call): k, code, nis, x_0 ... x_{n_x - 1}, and the upper triangle of P
 *        row by row (P_0_0, P_0_1, ..., P_{n-1}_{n-1}). code is abyssal_kalman_step's return: 1 a measurement
 *        was used, 0 predicted only, < 0 the step was refused and the state is the previous row's.
 *
 * Everything lives in static memory (no heap): the filter object, and the setup's arrays sized by the exported
 * model's header. C99.
 */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "abyssal_exported.h"

#define LINE 65536

#define N_X ABYSSAL_EXPORTED_N_X
#define N_U ABYSSAL_EXPORTED_N_U
#define N_Y ABYSSAL_EXPORTED_N_Y

static double memory[(ABYSSAL_EXPORTED_BYTES + 7) / 8];
/* a row: dt, u, z; or t, the call, and up to max(n_u, n_y + n_y^2) values */
#define ROW (2 + N_U + N_Y + N_Y * N_Y)
static double x0[N_X], P0[N_X * N_X], Q[N_X * N_X], R[N_Y * N_Y], row[ROW];
static char line[LINE];

static int fail(const char* what, const char* detail) {
  fprintf(stderr, "run_csv: %s%s%s\n", what, detail ? ": " : "", detail ? detail : "");
  return 2;
}

/* n numbers from text (separated by spaces or commas) into out; 0, or -1 when fewer were found. */
static int numbers(char* text, double* out, int n) {
  int k;
  for (k = 0; k < n; ++k) {
    char* end;
    while (*text == ' ' || *text == ',' || *text == '\t') ++text;
    errno = 0;
    out[k] = strtod(text, &end);
    if (end == text) return -1;
    text = end;
  }
  return 0;
}

/* Every number of a comma-separated row into out (at most capacity); their count, or -1 past capacity. */
static int all_numbers(const char* text, double* out, int capacity) {
  int count = 0;
  for (;;) {
    char* end;
    while (*text == ' ' || *text == ',' || *text == '\t') ++text;
    if (*text == '\0' || *text == '\n' || *text == '\r') return count;
    if (count == capacity) return -1;
    out[count] = strtod(text, &end);
    if (end == text) return -1;
    ++count;
    text = end;
  }
}

/* 1 when a row "t, call, values" (count numbers) has the values its call takes: n_u for a predict_to (call -1),
 * n_y_k or n_y_k + n_y_k^2 for sensor k's update; any for another call number (the runtime refuses it). */
static int row_fits(const abyssal_model* model, const double* values, int count) {
  const int call = (int)values[1], given = count - 2;
  if (count < 2 || values[1] != (double)call) return 0;
  if (call == -1) return given == model->n_u;
  if (call >= 0 && call < model->n_sensors) {
    const int m = model->sensors[call].n_y;
    return given == m || given == m + m * m;
  }
  return 1;
}

/* The time-stamped call of a row that fits: the runtime's return code. */
static int stamped_call(abyssal_kalman* filter, const abyssal_model* model, const double* values, int count) {
  const double t = values[0];
  const int call = (int)values[1];
  if (call == -1) return abyssal_kalman_predict_to(filter, model, t, values + 2, 0);
  if (call >= 0 && call < model->n_sensors && count - 2 > model->sensors[call].n_y)
    return abyssal_kalman_update_sensor(filter, model, call, t, values + 2, 0, values + 2 + model->sensors[call].n_y, 0);
  return abyssal_kalman_update_sensor(filter, model, call, t, values + 2, 0, 0, 0);
}

static int set_option(abyssal_kalman_options* o, const char* name, double value) {
  if (!strcmp(name, "alpha")) o->alpha = value;
  else if (!strcmp(name, "beta")) o->beta = value;
  else if (!strcmp(name, "kappa")) o->kappa = value;
  else if (!strcmp(name, "sigma")) o->sigma = value;
  else if (!strcmp(name, "gamma")) o->gamma = value;
  else if (!strcmp(name, "gate_probability")) o->gate_probability = value;
  else if (!strcmp(name, "gate_patience")) o->gate_patience = (int)value;
  else if (!strcmp(name, "gate_inflation")) o->gate_inflation = value;
  else if (!strcmp(name, "growth_limit")) o->growth_limit = value;
  else if (!strcmp(name, "max_substeps")) o->max_substeps = (int)value;
  else if (!strcmp(name, "repair_floor")) o->repair_floor = value;
  else if (!strcmp(name, "huber_iterations")) o->huber_iterations = (int)value;
  else if (!strcmp(name, "gate_max_inflations")) o->gate_max_inflations = (int)value;
  else if (!strcmp(name, "noise")) o->noise = (int)value;
  else if (!strcmp(name, "history_entries")) o->history_entries = (int)value;
  else if (!strcmp(name, "history_seconds")) o->history_seconds = value;
  else if (!strcmp(name, "smoothing")) o->smoothing = (int)value;
  else return -1;
  return 0;
}

int main(int argc, char** argv) {
  const abyssal_model* model = ABYSSAL_EXPORTED_MODEL;
  abyssal_kalman_options options = abyssal_kalman_default_options(ABYSSAL_EXPORTED_FILTER);
  abyssal_kalman* filter;
  abyssal_kalman_report report;
  const int n = N_X, n_u = N_U, m = N_Y;
  int k, i, j, code = 0, status, found = 0, stamped;
  FILE *setup, *in, *out;
  if (argc != 4) return fail("usage: run_csv SETUP INPUT OUTPUT", 0);
  if (model->n_x != N_X || model->n_u != N_U || model->n_y != N_Y) return fail("the model's sizes differ", model->name);
  setup = fopen(argv[1], "r");
  if (!setup) return fail("cannot open", argv[1]);
  while (fgets(line, LINE, setup)) {
    char name[64];
    int used;
    if (line[0] == '#' || sscanf(line, "%63s%n", name, &used) != 1) continue;
    if (!strcmp(name, "x0")) found |= numbers(line + used, x0, n) ? 0 : 1;
    else if (!strcmp(name, "P0")) found |= numbers(line + used, P0, n * n) ? 0 : 2;
    else if (!strcmp(name, "Q")) found |= numbers(line + used, Q, n * n) ? 0 : 4;
    else if (!strcmp(name, "R")) found |= numbers(line + used, R, m * m) ? 0 : 8;
    else {
      double value;
      if (numbers(line + used, &value, 1) || set_option(&options, name, value)) {
        fclose(setup);
        return fail("unknown setup line", name);
      }
    }
  }
  fclose(setup);
  if (found != 15) return fail("the setup needs the lines x0, P0, Q and R with all their values", argv[1]);
  if (abyssal_kalman_work_size(model, &options) > sizeof memory) return fail("the filter needs more memory", 0);
  code = abyssal_kalman_init(memory, sizeof memory, model, &options, x0, P0, Q, R, 0.0, &filter);
  if (code != ABYSSAL_OK) return fail("abyssal_kalman_init", abyssal_kalman_message(code));
  in = fopen(argv[2], "r");
  if (!in) return fail("cannot open", argv[2]);
  out = fopen(argv[3], "w");
  if (!out) {
    fclose(in);
    return fail("cannot write", argv[3]);
  }
  fprintf(out, "k,code,nis");
  for (i = 0; i < n; ++i) fprintf(out, ",x_%s", model->state_names[i]);
  for (i = 0; i < n; ++i)
    for (j = i; j < n; ++j) fprintf(out, ",P_%d_%d", i, j);
  fprintf(out, "\n");
  status = fgets(line, LINE, in) ? 0 : fail("empty input", argv[2]); /* the header */
  stamped = status == 0 && strncmp(line, "t,", 2) == 0;
  for (k = 0; status == 0 && fgets(line, LINE, in); ++k) {
    const double *x, *P;
    int any = 0;
    if (stamped) {
      const int count = all_numbers(line, row, ROW);
      if (count < 0 || !row_fits(model, row, count)) {
        fprintf(stderr, "run_csv: row %d of %s is not \"t, -1, u\" (n_u values) or \"t, k, z[, R]\" (sensor k's n_y "
                "values, and optionally its n_y * n_y R)\n", k + 1, argv[2]);
        status = 2;
        break;
      }
      code = stamped_call(filter, model, row, count);
    } else {
      if (numbers(line, row, 1 + n_u + m)) {
        fprintf(stderr, "run_csv: row %d of %s has fewer than %d numbers\n", k + 1, argv[2], 1 + n_u + m);
        status = 2;
        break;
      }
      for (i = 0; i < m; ++i) any |= !isnan(row[1 + n_u + i]);
      code = abyssal_kalman_step(filter, model, row + 1, row[0], any ? row + 1 + n_u : 0, 0, 0);
    }
    abyssal_kalman_get_report(filter, &report);
    x = abyssal_kalman_x(filter);
    P = abyssal_kalman_P(filter);
    fprintf(out, "%d,%d,%.17g", k, code, code == ABYSSAL_UPDATED ? report.nis : NAN);
    for (i = 0; i < n; ++i) fprintf(out, ",%.17g", x[i]);
    for (i = 0; i < n; ++i)
      for (j = i; j < n; ++j) fprintf(out, ",%.17g", P[i + j * n]);
    fprintf(out, "\n");
  }
  fclose(in);
  if (fclose(out) != 0) return fail("cannot write", argv[3]);
  if (status != 0) return status;
  abyssal_kalman_get_report(filter, &report);
  printf("%d %s; gated %lld entries, %lld inflations, %lld repairs, %lld subdivided predicts\n", k, stamped ? "calls" : "steps", report.gated,
         report.inflations, report.repairs, report.substeps);
  return 0;
}
