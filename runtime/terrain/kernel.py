"""The compiled bilinear lookup of a bathymetry grid for a whole particle cloud.

The C lives in the particle filters' runtime (``runtime/c/abyssal_sir_terrain_soa.c``, built once
through the cache with ``abyssal.runtime.compiled.sir.library``): the lookup of many points
(``abyssal_terrain_bilinear``, called here with ctypes on preallocated buffers) and the TAN
measurement the compiled SIR step calls itself (``abyssal_sir_terrain_measure``, bound to a map by
``TerrainMeasure``). Its header, ``abyssal_sir_terrain.h``, states the semantics (eq. 4 of seed 003):
the cell of a point, the bilinear depth, its gradient inside the cell, and a point outside the grid
or non-finite clamped onto it with gradient 0 and inside = 0, never an index error.
"""
from __future__ import annotations

import ctypes

import numpy as np

from ..compiled.sir import address, library


class TerrainMeasure(ctypes.Structure):
    """abyssal_sir_terrain: a map bound for the SIR step's measurement (depth [, slope along the heading], inside).

    ``heading`` (2,) is read at every call: [1 when every particle has the heading heading[1] (a pinned compass),
    else 0, heading] -- the SIR step's inputs [pins, first pinned value] (CompiledSIR.inputs[IN_PINS:]).
    """

    _fields_ = [("grid", ctypes.c_void_p), ("nx", ctypes.c_longlong), ("ny", ctypes.c_longlong),
                ("x0", ctypes.c_double), ("y0", ctypes.c_double), ("inv_res", ctypes.c_double),
                ("slope", ctypes.c_int), ("heading", ctypes.c_void_p)]

    @classmethod
    def bind(cls, terrain, slope: bool) -> "TerrainMeasure":
        """The map bound; ``read_heading_from`` must name the heading's two values before a step calls it."""
        ny, nx = terrain.depth.shape
        m = cls(grid=terrain.depth.ctypes.data, nx=nx, ny=ny, x0=terrain.origin[0], y0=terrain.origin[1],
                inv_res=1.0 / terrain.resolution, slope=int(slope), heading=None)
        m._keep = [terrain.depth]
        return m

    def read_heading_from(self, values: np.ndarray) -> None:
        """Read [pinned, heading] from `values` (a contiguous float64 array of at least 2, kept alive here)."""
        if not (isinstance(values, np.ndarray) and values.dtype == np.float64 and values.shape[0] >= 2
                and values.flags.c_contiguous):
            raise ValueError("the heading must be a contiguous float64 view of at least 2 values")
        self.heading = values.ctypes.data
        self._keep.append(values)

    @staticmethod
    def function() -> int:
        """Address of the measurement function (abyssal_sir_terrain_measure)."""
        return address("abyssal_sir_terrain_measure")


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
        self._fn = library().abyssal_terrain_bilinear
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
