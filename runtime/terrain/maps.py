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
  whose relief (~1.5 m) is below the altimeter's 5 m noise.
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


def _smooth_noise(rng, shape, correlation_cells: float) -> np.ndarray:
    """Zero-mean, unit-std Gaussian random field with a Gaussian correlation of `correlation_cells`."""
    from scipy.ndimage import gaussian_filter

    field = gaussian_filter(rng.standard_normal(shape), correlation_cells, mode="wrap")
    return field / field.std()


def synthetic_arctic(seed: int = 0, width_m: float = 140e3, height_m: float = 60e3,
                     resolution: float = 500.0) -> BathymetryMap:
    """Seeded Arctic-like map: rough continental slope in the west, flat abyssal plain in the east."""
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
    relief = ridges + 45.0 * _smooth_noise(rng, X.shape, 2.5)
    depth = depth + rough * relief
    # a flat-topped bank on the slope (cf. the paper's "top of the steep area ... suddenly flat")
    bank = 1300.0 * np.exp(-(((X - 33 * km) / (5 * km)) ** 2 + ((Y - 24 * km) / (6 * km)) ** 2))
    depth = np.maximum(depth - bank, np.minimum(depth, 1250.0 + 1.0 * _smooth_noise(rng, X.shape, 8)))
    # the plain: ~1.5 m of long-wavelength relief, below the altimeter noise
    depth = depth + (1 - rough) * 1.5 * _smooth_noise(rng, X.shape, 10)
    return BathymetryMap(depth, (0.0, 0.0), resolution, "arctic",
                         (f"synthetic Arctic-like map, seed {seed}: 800-3000 m rough continental slope (west) with a "
                          "flat-topped bank, flat abyssal plain (east)",))


MAPS = {"arctic": synthetic_arctic, "topobathy": topobathy_window}
