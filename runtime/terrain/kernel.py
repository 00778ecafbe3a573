"""The compiled bilinear lookup of a bathymetry grid for a whole particle cloud.

One small C kernel of the runtime (not generated from equations: the map is data). It is
compiled once through the same cache as the generated models (``abyssal.generated.build``) and
called with ctypes on preallocated buffers, one call per filter step for all particles. The
file name ends in ``_soa.c`` so it gets the structure-of-arrays flags (``-fopenmp-simd``): the
loop vectorises with gathers.

Semantics (eq. 4 of seed 003): for a point (x, y), fx = (x - x0)/res and fy = (y - y0)/res
are its grid coordinates; the cell is (floor(fx), floor(fy)) (the last row/column of nodes
belongs to the cell before it) and the depth the bilinear blend of its four nodes. The gradient
is the derivative of that blend inside the cell (m of depth per m; on a cell edge, the
gradient of the cell whose lower-left corner the point is nearest above). A point outside the
grid, or a non-finite one, is clamped onto the grid for the depth, gets gradient 0 and
inside = 0; the caller decides what an outside particle's likelihood is. Never an index error.
"""
from __future__ import annotations

import ctypes
from functools import lru_cache

import numpy as np

SOURCE = r"""
/* Bilinear depth and gradient of a regular grid at n points (abyssal.runtime.terrain.kernel). */
#include <math.h>
void terrain_bilinear(long long n, const double* restrict px, const double* restrict py,
                      const double* restrict grid, long long nx, long long ny,
                      double x0, double y0, double inv_res,
                      double* restrict depth, double* restrict gx, double* restrict gy, double* restrict inside) {
  const double fx_max = (double)(nx - 1), fy_max = (double)(ny - 1);
  const double ix_max = (double)(nx - 2), iy_max = (double)(ny - 2);
  long long j;
#pragma omp simd
  for (j = 0; j < n; ++j) {
    double fx = (px[j] - x0) * inv_res, fy = (py[j] - y0) * inv_res;
    double in = (fx >= 0.0 && fx <= fx_max && fy >= 0.0 && fy <= fy_max) ? 1.0 : 0.0;
    /* clamp onto the grid; written as comparisons (not fmin/fmax calls), and (x > 0 ? x : 0) sends a NaN to 0 */
    fx = fx > 0.0 ? fx : 0.0;
    fx = fx < fx_max ? fx : fx_max;
    fy = fy > 0.0 ? fy : 0.0;
    fy = fy < fy_max ? fy : fy_max;
    /* cell: truncation is floor for fx >= 0; the last node row/column belongs to the cell before it */
    double cx = (double)(long long)fx, cy = (double)(long long)fy;
    cx = cx < ix_max ? cx : ix_max;
    cy = cy < iy_max ? cy : iy_max;
    long long i = (long long)cy * nx + (long long)cx;
    double tx = fx - cx, ty = fy - cy;
    double q11 = grid[i], q21 = grid[i + 1], q12 = grid[i + nx], q22 = grid[i + nx + 1];
    double lower = q11 + tx * (q21 - q11), upper = q12 + tx * (q22 - q12);
    depth[j] = lower + ty * (upper - lower);
    gx[j] = in * ((q21 - q11) + ty * ((q22 - q12) - (q21 - q11))) * inv_res;
    gy[j] = in * (upper - lower) * inv_res;
    inside[j] = in;
  }
}
"""


@lru_cache(maxsize=1)
def _library() -> ctypes.CDLL:
    from abyssal.generated.build import build

    lib = ctypes.CDLL(str(build("terrain_kernel", {"terrain_bilinear_soa.c": SOURCE})))
    lib.terrain_bilinear.restype = None
    return lib


def lookup_address() -> int:
    """Address of ``terrain_bilinear`` (for runtime C that calls the lookup itself; the library stays loaded)."""
    return ctypes.cast(_library().terrain_bilinear, ctypes.c_void_p).value


class BilinearLookup:
    """The kernel bound to one grid and fixed point/result buffers; ``lookup(n)`` fills the first n.

    ``xs``/``ys`` are the coordinates read (any float64 1-D contiguous arrays of length >= capacity,
    e.g. rows of a C-ordered (3, N) particle array); ``depth``, ``gx``, ``gy``, ``inside`` are owned.
    """

    def __init__(self, grid: np.ndarray, origin, resolution: float, xs: np.ndarray, ys: np.ndarray):
        for name, arr in (("xs", xs), ("ys", ys)):
            if not (isinstance(arr, np.ndarray) and arr.dtype == np.float64 and arr.ndim == 1 and arr.flags.c_contiguous):
                raise ValueError(f"{name} must be a contiguous 1-D float64 array")
        if xs.shape != ys.shape:
            raise ValueError(f"xs and ys must have the same length, got {xs.shape} and {ys.shape}")
        self.capacity = xs.shape[0]
        self.depth, self.gx, self.gy, self.inside = (np.zeros(self.capacity) for _ in range(4))
        self._keep = (grid, xs, ys)
        ny, nx = grid.shape
        self._fn = _library().terrain_bilinear
        self._args = (
            ctypes.c_void_p(xs.ctypes.data), ctypes.c_void_p(ys.ctypes.data), ctypes.c_void_p(grid.ctypes.data),
            ctypes.c_longlong(nx), ctypes.c_longlong(ny), ctypes.c_double(origin[0]), ctypes.c_double(origin[1]),
            ctypes.c_double(1.0 / resolution),
            *(ctypes.c_void_p(a.ctypes.data) for a in (self.depth, self.gx, self.gy, self.inside)),
        )

    def __call__(self, n: int) -> None:
        if not 0 <= n <= self.capacity:
            raise ValueError(f"lookup of {n} points outside 0..{self.capacity} of the bound buffers")
        self._fn(ctypes.c_longlong(n), *self._args)
