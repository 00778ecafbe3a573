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
                ("slope", ctypes.c_int), ("heading", ctypes.c_void_p), ("fuzzy", ctypes.c_void_p)]

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

    def use_fuzzy(self, fuzzy: "TerrainFuzzy") -> None:
        """The step's fuzzy stage (abyssal_sir_terrain_step reads it from the measurement's context), kept alive here."""
        self.fuzzy = ctypes.addressof(fuzzy)
        self._keep.append(fuzzy)

    @staticmethod
    def function() -> int:
        """Address of the measurement function (abyssal_sir_terrain_measure)."""
        return address("abyssal_sir_terrain_measure")


class TerrainFuzzy(ctypes.Structure):
    """abyssal_sir_terrain_fuzzy: seed 003's fuzzy process noise as a stage of the compiled step (the gradient along
    the track, its rate over a window of travel, the controller; abyssal_sir_terrain.h). ``state`` (2, FIELDS) holds
    the two sides' fields, ``history`` the ring of (travelled, gradient) entries; ``bind_history`` points the C at a
    (grown or restored) ring."""

    TRAVELLED, GRADIENT, RATE, SIGMA, FIRST, COUNT, FIELDS = range(7)
    #: the step's status when the ring has no room for its entry (grow it, step again)
    HISTORY_FULL = 7

    _fields_ = [("controller", ctypes.c_void_p), ("scale", ctypes.c_double), ("window", ctypes.c_double),
                ("per_length", ctypes.c_double), ("history", ctypes.c_void_p), ("capacity", ctypes.c_longlong),
                ("state", ctypes.c_void_p), ("factor", ctypes.c_void_p)]

    @classmethod
    def bind(cls, controller: int, scale: float, window: float, per_length: float, state: np.ndarray,
             history: np.ndarray, factor: np.ndarray) -> "TerrainFuzzy":
        """controller: the address of the generated fuzzy_sigma's batch entry point; state (2, FIELDS), history
        (capacity, 2) and factor (the step's process noise factor, 2 entries): contiguous float64 arrays, kept."""
        for name, arr, shape in (("state", state, (2, cls.FIELDS)), ("factor", factor, (2,))):
            if not (isinstance(arr, np.ndarray) and arr.dtype == np.float64 and arr.shape == shape
                    and arr.flags.c_contiguous):
                raise ValueError(f"{name} must be a contiguous float64 array of shape {shape}")
        fuzzy = cls(controller=controller, scale=scale, window=window, per_length=per_length, state=state.ctypes.data,
                    factor=factor.ctypes.data)
        fuzzy._keep = [state, factor]
        fuzzy.bind_history(history)
        return fuzzy

    def bind_history(self, history: np.ndarray) -> None:
        if not (isinstance(history, np.ndarray) and history.dtype == np.float64 and history.ndim == 2
                and history.shape[1] == 2 and history.shape[0] >= 1 and history.flags.c_contiguous):
            raise ValueError("history must be a contiguous float64 array of shape (capacity, 2)")
        self.history, self.capacity = history.ctypes.data, history.shape[0]
        self._history = history


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
