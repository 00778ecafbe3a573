/* Terrain-aided navigation's measurement for the SIR step (abyssal_sir.h): the bilinear map lookup (C99).
 *
 * A regular bathymetry grid (ny x nx nodes, row-major, node (i, j) at (x0 + j res, y0 + i res)). For a point
 * (x, y): fx = (x - x0) / res, fy = (y - y0) / res; the cell is (floor fx, floor fy) (the last row/column of
 * nodes belongs to the cell before it), the depth is the bilinear blend of its four nodes (seed 003, eq. 4)
 * and the gradient the derivative of that blend inside the cell (m of depth per m). A point outside the grid,
 * or a non-finite one, is clamped onto the grid for the depth, gets gradient 0 and inside = 0: never an index
 * error; the SIR step gives it its invalid_log_lik.
 */
#ifndef ABYSSAL_SIR_TERRAIN_H
#define ABYSSAL_SIR_TERRAIN_H

#include "abyssal_sir.h"

/* depth, gradient (gx, gy) and inside (1 or 0) of n points */
void abyssal_terrain_bilinear(abyssal_idx n, const double* px, const double* py, const double* grid, abyssal_idx nx,
                              abyssal_idx ny, double x0, double y0, double inv_res, double* depth, double* gx,
                              double* gy, double* inside);

/* A generated function's batch entry point (<model>_<name>_batch: n evaluations on slices arg[k] + j arg_step[k]) */
typedef int (*abyssal_batch_fn)(long long n, const double** arg, const long long* arg_step, double** res,
                                const long long* res_step);

/* The fuzzy process noise of seed 003 (eq. 3) as a stage of the step (abyssal_sir_terrain_step), per side of the
 * step's transaction: the state fields below, and a ring of (travelled, gradient) entries along the track.
 *   gradient G = scale * the posterior mean of the slope row (the measurement's extra row);
 *   travelled = the committed travelled + |v| dt of the commanded v (a move), else unchanged;
 *   the window's base: the oldest committed entry, dropping entries while the one after it is at least `window` m
 *   behind travelled; rate = (G - the base's G) / per_length;
 *   sigma = controller(G, rate), the environment noise's standard deviation of the next step's move.
 * The step writes the new entry past the committed ones (the committed state and entries are never written) and
 * the uncommitted side's fields; a ring without room for it (count == capacity) refuses the step before any work
 * with ABYSSAL_SIR_TERRAIN_HISTORY_FULL (the caller grows the ring and steps again). */
enum {
  ABYSSAL_TAN_TRAVELLED, ABYSSAL_TAN_GRADIENT, ABYSSAL_TAN_RATE, ABYSSAL_TAN_SIGMA,
  ABYSSAL_TAN_FIRST,    /* ring index of the oldest entry */
  ABYSSAL_TAN_COUNT,    /* entries (>= 1) */
  ABYSSAL_TAN_FIELDS
};
#define ABYSSAL_SIR_TERRAIN_HISTORY_FULL 7

typedef struct {
  abyssal_batch_fn controller; /* sigma(gradient, rate): the generated fuzzy_sigma's batch entry point */
  double scale;                /* gradient scale (100: percent) */
  double window;               /* the rate's window of travel, m */
  double per_length;           /* window / the rate's length unit (0.5: per km over 500 m) */
  double* history;             /* (capacity, 2): travelled, gradient */
  abyssal_idx capacity;
  double* state;               /* (2, ABYSSAL_TAN_FIELDS): the sides */
  double* factor;              /* the step's process noise factor (x, y): the committed sigma, written before the move */
} abyssal_sir_terrain_fuzzy;

/* The measurement of a TAN particle x = [x, y, heading]: rows depth, then (slope = 1) the map's slope along the
 * particle's heading, gx cos(heading) + gy sin(heading), then inside (the validity row). */
typedef struct {
  const double* grid;
  abyssal_idx nx, ny;
  double x0, y0, inv_res;
  int slope;
  const double* heading; /* [1 when every particle has the heading heading[1] (a pinned compass), else 0, heading] */
  const abyssal_sir_terrain_fuzzy* fuzzy; /* NULL: a fixed sigma */
} abyssal_sir_terrain;

int abyssal_sir_terrain_measure(const void* ctx, abyssal_idx n, abyssal_idx ld, const double* x, const double* p,
                                double* y);

/* abyssal_sir_step with the fuzzy stage of s->h_ctx's (an abyssal_sir_terrain) `fuzzy` around it (see above); without
 * one, abyssal_sir_step. Returns its codes, ABYSSAL_SIR_TERRAIN_HISTORY_FULL, or ABYSSAL_SIR_MODEL_FAILED when the
 * controller fails. */
int abyssal_sir_terrain_step(const abyssal_sir* s);

#endif /* ABYSSAL_SIR_TERRAIN_H */
