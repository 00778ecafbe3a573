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

/* The measurement of a TAN particle x = [x, y, heading]: rows depth, then (slope = 1) the map's slope along the
 * particle's heading, gx cos(heading) + gy sin(heading), then inside (the validity row). */
typedef struct {
  const double* grid;
  abyssal_idx nx, ny;
  double x0, y0, inv_res;
  int slope;
  const double* heading; /* [1 when every particle has the heading heading[1] (a pinned compass), else 0, heading] */
} abyssal_sir_terrain;

int abyssal_sir_terrain_measure(const void* ctx, abyssal_idx n, abyssal_idx ld, const double* x, const double* p,
                                double* y);

#endif /* ABYSSAL_SIR_TERRAIN_H */
