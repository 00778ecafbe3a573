"""Bathymetry maps as data: a regular depth grid with bilinear interpolation (seed 003, eq. 4).

``BathymetryMap`` holds seabed depth (m, positive down) on a regular grid of square cells:
node (i, j) -- row i, column j -- sits at (x0 + j res, y0 + i res). Depth between nodes is the
bilinear blend of eq. 4; its gradient is the derivative of that blend inside a cell. All
particles are looked up in one call of a compiled kernel (``kernel.BilinearLookup``).

Two maps are built offline, at run time (IBCAO, the paper's Arctic grid, cannot be downloaded
here):

* ``topobathy_window``: matplotlib's bundled ``topobathy.npz`` (91 x 120 nodes at 2' of
  longitude by ~1.3' of latitude, ~2.4 km; the Pacific coast of Washington and Vancouver
  Island), its south-west 140 x 60 km window -- slope and deep water in the west, the shelf in
  the middle, land in the east -- resampled bilinearly to 500 m cells in a local east/north
  frame (equirectangular at the window's mid latitude). Land is clipped to depth 0. Being
  interpolated from ~2.4 km cells, it is smoother at 500 m than a real 500 m survey.
* ``synthetic_arctic``: a seeded 140 x 60 km map in the spirit of the paper's study area
  (Fig. 2): a continental slope from an 800 m shelf down to a 3000 m abyssal plain in the west,
  cut by ridges and rough relief, with a flat-topped bank on the slope, and a plain in the east
  whose relief (~1.5 m) is below the altimeter's 5 m noise. Its relief is smooth at the 500 m
  cell: ridges of 3-9 km wavelength and a random field correlated over ~1.25 km.
* ``synthetic_arctic(seed, cell_relief=True)`` (``MAPS["arctic_cells"]``): the same map -- the same
  layout and the same random draws -- with the random part of the relief given a von Karman
  spectrum (the form Goff & Jordan (1988) fitted to abyssal hills: power ~ (1 + (k/k0)^2)^-(H+1),
  corner wavelength 4 km, Hurst exponent H = 0.8) instead of the smooth field, at the same 45 m rms.
  A power law has relief down to the 500 m cell, as a survey grid has: neighbouring nodes differ by
  tens of metres where the smooth map's differ by the slope's trend.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .kernel import BilinearLookup

EARTH_RADIUS_M = 6_371_000.0


@dataclass(frozen=True)
class BathymetryMap:
    """Seabed depth (m, positive down) on a regular grid; see the module docstring for the layout.

    depth: (ny, nx) float64 C-ordered array (read-only); origin: (x0, y0) of node (0, 0) in m;
    resolution: cell size in m; name and notes describe where the data came from.
    """

    depth: np.ndarray
    origin: tuple[float, float]
    resolution: float
    name: str = "map"
    notes: tuple[str, ...] = field(default_factory=tuple)

    def __post_init__(self):
        depth = np.ascontiguousarray(self.depth, dtype=np.float64)
        if depth.ndim != 2 or min(depth.shape) < 2:
            raise ValueError(f"depth must be a 2-D grid of at least 2 x 2 nodes, got shape {depth.shape}")
        if not np.isfinite(depth).all():
            raise ValueError("depth must be finite everywhere (fill holes before building a map)")
        if not (np.isfinite(self.resolution) and self.resolution > 0):
            raise ValueError(f"resolution must be a positive number of metres, got {self.resolution}")
        depth.setflags(write=False)
        object.__setattr__(self, "depth", depth)
        object.__setattr__(self, "origin", (float(self.origin[0]), float(self.origin[1])))

    @property
    def shape(self) -> tuple[int, int]:
        return self.depth.shape

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) in m."""
        ny, nx = self.depth.shape
        x0, y0 = self.origin
        return x0, x0 + (nx - 1) * self.resolution, y0, y0 + (ny - 1) * self.resolution

    def node_coordinates(self) -> tuple[np.ndarray, np.ndarray]:
        """(x of each column, y of each row) in m."""
        ny, nx = self.depth.shape
        return self.origin[0] + self.resolution * np.arange(nx), self.origin[1] + self.resolution * np.arange(ny)

    def bind(self, xs: np.ndarray, ys: np.ndarray) -> BilinearLookup:
        """Compiled lookup of the points (xs[j], ys[j]) into owned depth/gx/gy/inside buffers."""
        return BilinearLookup(self.depth, self.origin, self.resolution, xs, ys)

    def lookup(self, x, y) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(depth, d depth/dx, d depth/dy, inside) at points x, y (any equal shapes); convenience path."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        if x.shape != y.shape:
            raise ValueError(f"x and y must have the same shape, got {x.shape} and {y.shape}")
        xs, ys = np.ascontiguousarray(x.ravel()), np.ascontiguousarray(y.ravel())
        lookup = self.bind(xs, ys)
        lookup(xs.shape[0])
        return tuple(a.reshape(x.shape) for a in (lookup.depth, lookup.gx, lookup.gy, lookup.inside.astype(bool)))

    def depth_at(self, x, y) -> np.ndarray:
        return self.lookup(x, y)[0]


# --------------------------------------------------------------------------------- builders
def _resampled(lon, lat, values, lon0, lat0, width_m, height_m, resolution):
    """values(lat, lon) on a local east/north grid of `resolution` from (lon0, lat0), bilinear."""
    from scipy.interpolate import RegularGridInterpolator

    lat_mid = np.radians(lat0) + 0.5 * height_m / EARTH_RADIUS_M
    xs = np.arange(0.0, width_m + 0.5 * resolution, resolution)
    ys = np.arange(0.0, height_m + 0.5 * resolution, resolution)
    lon_q = lon0 + np.degrees(xs / (EARTH_RADIUS_M * np.cos(lat_mid)))
    lat_q = lat0 + np.degrees(ys / EARTH_RADIUS_M)
    interp = RegularGridInterpolator((lat, lon), values, method="linear")
    LAT, LON = np.meshgrid(lat_q, lon_q, indexing="ij")
    return interp(np.stack([LAT.ravel(), LON.ravel()], axis=1)).reshape(LAT.shape)


def topobathy_window(width_m: float = 140e3, height_m: float = 60e3, resolution: float = 500.0,
                     lon0: float | None = None, lat0: float | None = None) -> BathymetryMap:
    """The south-west window of matplotlib's ``topobathy.npz`` resampled to `resolution` (see module)."""
    from matplotlib import cbook

    data = cbook.get_sample_data("topobathy.npz")
    lon = np.asarray(data["longitude"], dtype=np.float64)
    lat = np.asarray(data["latitude"], dtype=np.float64)
    elevation = np.asarray(data["topo"], dtype=np.float64)
    lon0 = float(lon[0]) if lon0 is None else lon0
    lat0 = float(lat[0]) if lat0 is None else lat0
    depth = np.maximum(-_resampled(lon, lat, elevation, lon0, lat0, width_m, height_m, resolution), 0.0)
    return BathymetryMap(depth, (0.0, 0.0), resolution, "topobathy",
                         (f"matplotlib sample_data/topobathy.npz, window from {lon0:.3f}E {lat0:.3f}N, "
                          f"{width_m / 1e3:g} x {height_m / 1e3:g} km, resampled bilinearly to {resolution:g} m; "
                          "land clipped to depth 0",))


def _normalised(field: np.ndarray) -> np.ndarray:
    return field / field.std()


def _smooth_noise(rng, shape, correlation_cells: float) -> np.ndarray:
    """Zero-mean, unit-std Gaussian random field with a Gaussian correlation of `correlation_cells`."""
    return _smoothed(rng.standard_normal(shape), correlation_cells)


def _smoothed(white: np.ndarray, correlation_cells: float) -> np.ndarray:
    """White noise filtered by a Gaussian of `correlation_cells` (periodic), normalised to unit std."""
    from scipy.ndimage import gaussian_filter

    return _normalised(gaussian_filter(white, correlation_cells, mode="wrap"))


def _von_karman(white: np.ndarray, corner_cells: float, hurst: float) -> np.ndarray:
    """White noise given the isotropic von Karman spectrum, power ~ (1 + (k corner_cells)^2)^-(hurst + 1) with k
    in cycles per cell (periodic, like ``_smoothed``), normalised to unit std: relief down to the cell scale."""
    ny, nx = white.shape
    k = np.hypot(np.fft.fftfreq(ny)[:, None], np.fft.rfftfreq(nx)[None, :])
    amplitude = (1.0 + (k * corner_cells) ** 2) ** (-(hurst + 1.0) / 2.0)
    return _normalised(np.fft.irfft2(np.fft.rfft2(white) * amplitude, s=white.shape))


#: the cell-scale relief of ``synthetic_arctic(cell_relief=True)``: corner wavelength (m) and Hurst exponent
CELL_RELIEF_CORNER_M = 4000.0
CELL_RELIEF_HURST = 0.8


def synthetic_arctic(seed: int = 0, width_m: float = 140e3, height_m: float = 60e3,
                     resolution: float = 500.0, cell_relief: bool = False) -> BathymetryMap:
    """Seeded Arctic-like map: rough continental slope in the west, flat abyssal plain in the east.

    cell_relief: give the slope's 45 m rms random relief a von Karman spectrum reaching the cell scale instead of
    a ~1.25 km Gaussian correlation (the module docstring); everything else, random draws included, is the same.
    """
    rng = np.random.default_rng(seed)
    x = np.arange(0.0, width_m + 0.5 * resolution, resolution)
    y = np.arange(0.0, height_m + 0.5 * resolution, resolution)
    X, Y = np.meshgrid(x, y)
    km = 1e3
    # slope: 800 m shelf (west) to 3000 m plain, its foot wandering with y
    slope_centre = 26 * km + 4 * km * np.sin(2 * np.pi * Y / (45 * km) + rng.uniform(0, 2 * np.pi))
    depth = 1900.0 + 1100.0 * np.tanh((X - slope_centre) / (7 * km))
    # roughness fades out between x = 44 and 54 km: east of it the plain is flat
    rough = 0.5 * (1.0 - np.tanh((X - 49 * km) / (2.5 * km)))
    ridges = np.zeros_like(X)
    for _ in range(6):
        wavelength = rng.uniform(3 * km, 9 * km)
        angle = rng.uniform(0, np.pi)
        k = 2 * np.pi / wavelength
        ridges += rng.uniform(40, 110) * np.sin(k * (X * np.cos(angle) + Y * np.sin(angle)) + rng.uniform(0, 2 * np.pi))
    white = rng.standard_normal(X.shape)
    random_relief = (_von_karman(white, CELL_RELIEF_CORNER_M / resolution, CELL_RELIEF_HURST) if cell_relief
                     else _smoothed(white, 2.5))
    relief = ridges + 45.0 * random_relief
    depth = depth + rough * relief
    # a flat-topped bank on the slope (cf. the paper's "top of the steep area ... suddenly flat")
    bank = 1300.0 * np.exp(-(((X - 33 * km) / (5 * km)) ** 2 + ((Y - 24 * km) / (6 * km)) ** 2))
    depth = np.maximum(depth - bank, np.minimum(depth, 1250.0 + 1.0 * _smooth_noise(rng, X.shape, 8)))
    # the plain: ~1.5 m of long-wavelength relief, below the altimeter noise
    depth = depth + (1 - rough) * 1.5 * _smooth_noise(rng, X.shape, 10)
    if cell_relief:
        notes = (f"synthetic Arctic-like map, seed {seed}, relief at the cell scale: the 'arctic' map's layout and draws "
                 f"with its 45 m rms random relief given a von Karman spectrum (corner {CELL_RELIEF_CORNER_M / km:g} km, "
                 f"Hurst {CELL_RELIEF_HURST:g})",)
    else:
        notes = (f"synthetic Arctic-like map, seed {seed}: 800-3000 m rough continental slope (west) with a "
                 "flat-topped bank, flat abyssal plain (east)",)
    return BathymetryMap(depth, (0.0, 0.0), resolution, "arctic_cells" if cell_relief else "arctic", notes)


def synthetic_arctic_cells(seed: int = 0) -> BathymetryMap:
    """``synthetic_arctic(seed, cell_relief=True)``: the same map with relief down to the 500 m cell."""
    return synthetic_arctic(seed, cell_relief=True)


#: name -> builder; the synthetic maps take a seed
MAPS = {"arctic": synthetic_arctic, "arctic_cells": synthetic_arctic_cells, "topobathy": topobathy_window}
