/* Terrain-aided navigation's map lookup and SIR measurement (see abyssal_sir_terrain.h). Hand-written C99 of
 * abyssal's runtime; the file name ends in _soa.c for the structure-of-arrays flags (the loops vectorise with
 * gathers and libmvec's sin/cos). */
#include "abyssal_sir_terrain.h"

#include <math.h>
#include <stdint.h>
#include <string.h>

#if defined(__x86_64__) && defined(__GLIBC__) && !defined(ABYSSAL_NO_LIBMVEC)
#pragma omp declare simd notinbranch
extern double sin(double) __attribute__((const));
#pragma omp declare simd notinbranch
extern double cos(double) __attribute__((const));
#endif

typedef abyssal_idx idx;

/* v, an integer in [0, 2^52) held in a double, as an integer: v + 2^52 holds it in the low bits of its mantissa.
 * (A double-to-int64 conversion instruction exists only with AVX-512: without it, (long long)v keeps the loops
 * scalar.) */
static inline idx whole(double v) {
  const double shifted = v + 0x1p52;
  uint64_t bits;
  memcpy(&bits, &shifted, sizeof bits);
  return (idx)(bits - UINT64_C(0x4330000000000000));
}

/* one point: its depth, gradient and inside flag (the comparisons, not fmin/fmax calls, keep the loops
 * vectorised; (x > 0 ? x : 0) sends a NaN to 0) */
#pragma omp declare simd uniform(grid, nx, ny, x0, y0, inv_res) notinbranch
static inline double bilinear(double px, double py, const double* grid, idx nx, idx ny, double x0, double y0,
                              double inv_res, double* gx, double* gy, double* inside) {
  const double fx_max = (double)(nx - 1), fy_max = (double)(ny - 1);
  const double ix_max = (double)(nx - 2), iy_max = (double)(ny - 2);
  double fx = (px - x0) * inv_res, fy = (py - y0) * inv_res;
  const double in = (fx >= 0.0 && fx <= fx_max && fy >= 0.0 && fy <= fy_max) ? 1.0 : 0.0;
  fx = fx > 0.0 ? fx : 0.0;
  fx = fx < fx_max ? fx : fx_max;
  fy = fy > 0.0 ? fy : 0.0;
  fy = fy < fy_max ? fy : fy_max;
  /* cell: truncation is floor for fx >= 0; the last node row/column belongs to the cell before it */
  double cx = trunc(fx), cy = trunc(fy);
  cx = cx < ix_max ? cx : ix_max;
  cy = cy < iy_max ? cy : iy_max;
  const idx i = whole(cy * (double)nx + cx); /* exact: below nx ny, which a grid in memory keeps below 2^52 */
  const double tx = fx - cx, ty = fy - cy;
  const double q11 = grid[i], q21 = grid[i + 1], q12 = grid[i + nx], q22 = grid[i + nx + 1];
  const double lower = q11 + tx * (q21 - q11), upper = q12 + tx * (q22 - q12);
  *gx = in * ((q21 - q11) + ty * ((q22 - q12) - (q21 - q11))) * inv_res;
  *gy = in * (upper - lower) * inv_res;
  *inside = in;
  return lower + ty * (upper - lower);
}

void abyssal_terrain_bilinear(abyssal_idx n, const double* restrict px, const double* restrict py,
                              const double* restrict grid, abyssal_idx nx, abyssal_idx ny, double x0, double y0,
                              double inv_res, double* restrict depth, double* restrict gx, double* restrict gy,
                              double* restrict inside) {
#pragma omp simd
  for (idx j = 0; j < n; ++j) {
    double a, b, c;
    depth[j] = bilinear(px[j], py[j], grid, nx, ny, x0, y0, inv_res, &a, &b, &c);
    gx[j] = a;
    gy[j] = b;
    inside[j] = c;
  }
}

int abyssal_sir_terrain_measure(const void* ctx, abyssal_idx n, abyssal_idx ld, const double* x, const double* p,
                                double* y) {
  const abyssal_sir_terrain* t = (const abyssal_sir_terrain*)ctx;
  const double* restrict px = x;
  const double* restrict py = x + ld;
  const double* restrict heading = x + 2 * ld;
  const double* restrict grid = t->grid;
  const idx nx = t->nx, ny = t->ny;
  const double x0 = t->x0, y0 = t->y0, inv_res = t->inv_res;
  double* restrict depth = y;
  (void)p;
  if (!t->slope) {
    double* restrict inside = y + ld;
#pragma omp simd
    for (idx j = 0; j < n; ++j) {
      double a, b, c;
      depth[j] = bilinear(px[j], py[j], grid, nx, ny, x0, y0, inv_res, &a, &b, &c);
      inside[j] = c;
    }
  } else if (t->heading[0] != 0.0) { /* every particle has the compass heading: its cos and sin once */
    double* restrict slope = y + ld;
    double* restrict inside = y + 2 * ld;
    const double ch = cos(t->heading[1]), sh = sin(t->heading[1]);
#pragma omp simd
    for (idx j = 0; j < n; ++j) {
      double a, b, c;
      depth[j] = bilinear(px[j], py[j], grid, nx, ny, x0, y0, inv_res, &a, &b, &c);
      slope[j] = a * ch + b * sh;
      inside[j] = c;
    }
  } else {
    double* restrict slope = y + ld;
    double* restrict inside = y + 2 * ld;
#pragma omp simd
    for (idx j = 0; j < n; ++j) {
      double a, b, c;
      depth[j] = bilinear(px[j], py[j], grid, nx, ny, x0, y0, inv_res, &a, &b, &c);
      slope[j] = a * cos(heading[j]) + b * sin(heading[j]);
      inside[j] = c;
    }
  }
  return 0;
}

/* ------------------------------------------------------------------ the fuzzy stage (abyssal_sir_terrain.h) */

int abyssal_sir_terrain_step(const abyssal_sir* s) {
  const abyssal_sir_terrain* t = s ? (const abyssal_sir_terrain*)s->h_ctx : 0;
  const abyssal_sir_terrain_fuzzy* z = t ? t->fuzzy : 0;
  if (!z) return abyssal_sir_step(s);
  const double side_value = s->in[ABYSSAL_SIR_IN_SIDE];
  if (!(side_value == 0.0 || side_value == 1.0) || s->n_extra < 1 || !z->controller || !z->history || !z->state ||
      !z->factor || z->capacity < 1)
    return ABYSSAL_SIR_BAD_ARGUMENT;
  const int side = (int)side_value;
  const double* before = z->state + side * ABYSSAL_TAN_FIELDS;
  double* after = z->state + (1 - side) * ABYSSAL_TAN_FIELDS;
  const double first_value = before[ABYSSAL_TAN_FIRST], count_value = before[ABYSSAL_TAN_COUNT];
  if (!(first_value >= 0.0 && first_value < (double)z->capacity && count_value >= 1.0 &&
        count_value <= (double)z->capacity))
    return ABYSSAL_SIR_BAD_ARGUMENT;
  const idx cap = z->capacity, first = (idx)first_value, count = (idx)count_value;
  if (count == cap) return ABYSSAL_SIR_TERRAIN_HISTORY_FULL;
  const double* ring = z->history;
  const abyssal_sir_in_offsets io = abyssal_sir_inputs(s->n_x, s->n_u, s->n_y);
  const int move = s->in[ABYSSAL_SIR_IN_MOVE] != (double)ABYSSAL_SIR_MOVE_NONE;
  const double travelled = before[ABYSSAL_TAN_TRAVELLED] + (move ? fabs(s->in[io.u]) * s->in[ABYSSAL_SIR_IN_DT] : 0.0);
  idx dropped = 0;
  while (dropped < count - 1 && travelled - ring[2 * ((first + dropped + 1) % cap)] >= z->window) ++dropped;
  z->factor[0] = z->factor[1] = before[ABYSSAL_TAN_SIGMA]; /* eq. 3: the sigma of the last update moves */
  int rc = abyssal_sir_step(s);
  if (rc != ABYSSAL_SIR_OK) return rc;
  const abyssal_sir_report_offsets ro = abyssal_sir_report(s->n_x, s->n_y, s->n_extra);
  double gradient = z->scale * s->report[1 - side][ro.extra];
  double rate = (gradient - ring[2 * ((first + dropped) % cap) + 1]) / z->per_length, sigma = 0.0;
  const double* arg[2] = {&gradient, &rate};
  double* res[1] = {&sigma};
  const long long arg_step[2] = {0, 0}, res_step[1] = {0};
  if (z->controller(1, arg, arg_step, res, res_step) != 0) return ABYSSAL_SIR_MODEL_FAILED;
  const idx slot = (first + count) % cap; /* past the committed entries */
  z->history[2 * slot] = travelled;
  z->history[2 * slot + 1] = gradient;
  after[ABYSSAL_TAN_TRAVELLED] = travelled;
  after[ABYSSAL_TAN_GRADIENT] = gradient;
  after[ABYSSAL_TAN_RATE] = rate;
  after[ABYSSAL_TAN_SIGMA] = sigma;
  after[ABYSSAL_TAN_FIRST] = (double)((first + dropped) % cap);
  after[ABYSSAL_TAN_COUNT] = (double)(count - dropped + 1);
  return ABYSSAL_SIR_OK;
}
