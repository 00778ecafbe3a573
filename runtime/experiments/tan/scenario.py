"""Seed 003's simulated world (section 4): an AUV crossing a bathymetry map under an unknown current.

``simulate(bundle, terrain, config, start, current, rng) -> Truth`` is one true track and what the filter
gets from it; the maps are ``get_map(name)``, the tracks ``TRACKS[map]``, and ``characterise`` measures a
track's terrain without any filter. The filters, the cases and the metrics are experiment.py.

Set-up (Table 2 where it says; DECISION where it does not):

* Vehicle: forward speed 0.5 m/s, operating depth 0 m; truth at 1 Hz (dt = 1 s) for ``duration_s``
  (the paper's 30 000 s; ``quick`` shortens it). Heading 0 is +x (east), 90 deg is +y (north).
* Truth (DECISION): eq. 1 with the body noise of eq. 2 (a = 0.1, 0.1, 0.001, 0.1) disturbing the
  true speed and turn rate, plus the current (d_x, d_y) (Table 2: (0.1, 0.1) and (0.15, 0.15)
  m/s along +x +y; (0, 0) for Fig. 7's "body noise alone"). A heading autopilot with an ideal
  heading sensor commands omega_k = -(theta_k - theta_0)/tau, tau = 10 s, so the track stays straight
  (the body noise alone would random-walk the heading by ~2.7 rad over 30 000 s).
* What the filter gets: the commanded [v, omega_k] as its input, and z = [altimeter depth, compass
  heading]: depth = map(x, y) + N(0, 5^2) (Table 2), heading exact (the paper's filter estimates
  position only). The current is unknown to the filter: absorbing it is the process noise's job.

Tracks (DECISION: the paper's printed postures refer to its IBCAO area; on our maps they are arbitrary
points, so each map gets several tracks, ``TRACKS``):

* ``paper_20_20`` and ``paper_60_10``: the paper's two printed postures, [20 km, 20 km, 0 deg] and
  [60 km, 10 km, 0 deg] (Table 2; the second is its Fig. 15 flat area). On the synthetic maps the second
  lies on the flat plain; on the topobathy window on the gently sloping shelf.
* ``drift_along`` and ``drift_across``: picked by ``pick_along_across`` -- among tracks starting on a 5 km
  grid with headings 0/90/180/270 deg, at least 2 km inside the map at the strongest current, at most 10 %
  flat, and at least as sloped as the median of those, the one whose drift runs most nearly along the depth
  contours and the one whose drift runs most nearly across them (``characterise``'s drift-contour angle at
  0.1 m/s). The synthetic map with cell-scale relief shares the smooth map's layout and so its tracks.
* ``start_10_40``: [10 km, 40 km, 0 deg] on the synthetic maps, a start a review of an earlier campaign
  named (there fixed sigma = 2-3 m tracked in most runs at 0.1 m/s).
* ``survey_pick``: the pick of the track survey (survey.py, `abyssal reproduce tan-survey`): every admissible track
  of the map on a 10 km grid (``admissible_starts``) run with fixed sigma = 2 and 3 m at 0.1 m/s, 3 runs each on
  the survey's own streams; among the tracks where a sigma kept every run within 1000 m, the one whose worst run
  stayed furthest below it. The tan experiment reruns it on its own, independent streams: the survey selects,
  the campaign confirms (or not).

The terrain of a track (``characterise``; no filter involved): along the noise-free path (the commanded
speed plus the current, sampled every 10 s),

* slope: the rms of |grad depth| (m/km) -- how much the depth says about position at all;
* drift-contour angle: the angle between the drift (the current's direction, +x +y as the paper's) and the
  depth contours, 0 deg along them, 90 deg across. Per 2 km window of path, the contour direction is the
  normal of the dominant gradient direction (the principal axis of sum g g^T); windows are weighted by how
  strongly one direction dominates (the eigenvalue gap). A drift along the contours changes no depth: the
  filter cannot see it;
* weakest slope: the median over 2 km windows of the slope in the window's least-informative direction
  (sqrt of the smallest eigenvalue of mean g g^T), m/km -- near 0 where the contours are straight, so the
  position along them is unobservable whatever the drift;
* cell relief: the rms second difference of the depth profile sampled every 500 m along the path (m): relief
  at the map's cell scale, beyond the slope's trend;
* flat: the share of the path where the depth changes by less than the altimeter's sigma (5 m) across a 500 m
  cell (slope < 10 m/km).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: the paper's printed postures (Table 2), by the terrain they land on in the paper's area
STARTS = {"rough": (20e3, 20e3, 0.0), "flat": (60e3, 10e3, 0.0)}
CURRENTS = {"0": (0.0, 0.0), "0.1": (0.1, 0.1), "0.15": (0.15, 0.15)}
#: the direction of the paper's current (+x +y), used for the drift-contour angle of every track
DRIFT_DIRECTION = (math.sqrt(0.5), math.sqrt(0.5))


@dataclass(frozen=True)
class Track:
    """A start posture (m, m, rad) and why it is in the campaign."""

    x: float
    y: float
    heading: float
    why: str

    @property
    def start(self) -> tuple[float, float, float]:
        return (self.x, self.y, self.heading)

    def label(self) -> str:
        return f"({self.x / 1e3:g}, {self.y / 1e3:g}) km, {math.degrees(self.heading):g} deg"


def _track(x_km: float, y_km: float, heading_deg: float, why: str) -> Track:
    return Track(x_km * 1e3, y_km * 1e3, math.radians(heading_deg), why)


_PAPER = {"paper_20_20": _track(20, 20, 0, "the paper's first printed posture"),
          "paper_60_10": _track(60, 10, 0, "the paper's second printed posture (its Fig. 15 flat area)")}
_SYNTHETIC = {**_PAPER,
              "start_10_40": _track(10, 40, 0, "a start a review of an earlier campaign named"),
              "drift_along": _track(35, 20, 270, "pick_along_across on 'arctic': drift most nearly along the contours"),
              "drift_across": _track(45, 25, 180, "pick_along_across on 'arctic': drift most nearly across the contours")}
_SURVEYED = "the track survey's pick (abyssal reproduce tan-survey, its default: 3 runs, seed 0)"
#: map -> track name -> Track (the module docstring says how each was chosen)
TRACKS: dict[str, dict[str, Track]] = {
    "arctic": {**_SYNTHETIC, "survey_pick": _track(10, 20, 270, _SURVEYED)},
    "arctic_cells": {**_SYNTHETIC, "survey_pick": _track(10, 30, 270, _SURVEYED)},
    "topobathy": {**_PAPER,
                  "drift_along": _track(15, 30, 270, "pick_along_across on 'topobathy': drift most nearly along the contours"),
                  "drift_across": _track(115, 40, 180, "pick_along_across on 'topobathy': drift most nearly across the contours"),
                  "survey_pick": _track(10, 20, 90, _SURVEYED)},
}

_MAP_CACHE: dict = {}


def get_map(name: str, seed: int = 0):
    """The named map (built once per process); the synthetic maps take ``seed``."""
    from ...terrain import MAPS

    key = (name, seed)
    if key not in _MAP_CACHE:
        _MAP_CACHE[key] = MAPS[name](seed) if name.startswith("arctic") else MAPS[name]()
    return _MAP_CACHE[key]


# --------------------------------------------------------------------------------- terrain of a track
@dataclass(frozen=True)
class TrackTerrain:
    """What the terrain offers along a track, with no filter involved (module docstring)."""

    slope_m_per_km: float
    drift_contour_angle_deg: float
    weakest_slope_m_per_km: float
    cell_relief_m: float
    flat_fraction: float
    margin_m: float            # the path's smallest distance to the map's edge (negative: it leaves the map)

    def as_dict(self) -> dict[str, float]:
        return dict(self.__dict__)


def nominal_path(start, current, duration_s: float, speed: float, sample_s: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    """The noise-free path: constant heading at ``speed`` plus the current, every ``sample_s`` seconds (m)."""
    t = np.arange(0.0, duration_s + 0.5 * sample_s, sample_s)
    vx = speed * math.cos(start[2]) + current[0]
    vy = speed * math.sin(start[2]) + current[1]
    return start[0] + vx * t, start[1] + vy * t


def characterise(terrain, start, current, duration_s: float, speed: float, window_m: float = 2000.0,
                 altimeter_sigma: float = 5.0) -> TrackTerrain:
    """The terrain measures of the track from ``start`` (x, y, heading) under ``current`` (module docstring)."""
    x, y = nominal_path(start, current, duration_s, speed)
    _, gx, gy, _ = terrain.lookup(x, y)
    g = 1e3 * np.column_stack([gx, gy])                      # m/km
    slope = float(np.sqrt(np.mean(np.sum(g * g, axis=1))))
    step = float(np.hypot(x[1] - x[0], y[1] - y[0])) if x.size > 1 else 0.0
    width = max(2, min(x.size, int(round(window_m / step)) if step > 0 else x.size))
    drift = np.asarray(DRIFT_DIRECTION)
    cosines, gaps, weakest = [], [], []
    for i in range(0, x.size - width + 1, max(1, width // 4)):
        w = g[i:i + width]
        values, vectors = np.linalg.eigh(w.T @ w / width)   # ascending
        weakest.append(math.sqrt(max(values[0], 0.0)))
        cosines.append(abs(float(vectors[:, 1] @ drift)))   # |cos(drift, dominant gradient)| = sin(drift, contours)
        gaps.append(values[1] - values[0])
    gaps = np.asarray(gaps)
    sine = float(np.average(cosines, weights=gaps)) if gaps.sum() > 0 else float(np.mean(cosines))
    angle = math.degrees(math.asin(min(1.0, sine)))
    length = float(np.hypot(x[-1] - x[0], y[-1] - y[0]))
    n = max(3, int(length // terrain.resolution) + 1)
    profile = terrain.depth_at(np.linspace(x[0], x[-1], n), np.linspace(y[0], y[-1], n))
    relief = float(np.sqrt(np.mean(np.diff(profile, 2) ** 2)))
    flat = float(np.mean(np.hypot(gx, gy) * terrain.resolution < altimeter_sigma))
    x_min, x_max, y_min, y_max = terrain.extent
    margin = float(min(x.min() - x_min, x_max - x.max(), y.min() - y_min, y_max - y.max()))
    return TrackTerrain(slope, angle, float(np.median(weakest)), relief, flat, margin)


def admissible_starts(terrain, duration_s: float = 30000.0, speed: float = 0.5, currents=(0.1, 0.15),
                      grid_km: float = 5.0) -> list[tuple[tuple[float, float, float], TrackTerrain]]:
    """The candidate tracks of a map: starts (x m, y m, heading rad) on a ``grid_km`` grid with headings 0/90/180/270
    deg whose path at the strongest current stays >= 2 km inside the map and which are at most 10 % flat at
    ``currents[0]``, each with its terrain (``characterise``) at ``currents[0]``."""
    x_min, x_max, y_min, y_max = terrain.extent
    step = grid_km * 1e3
    out = []
    for x0 in np.arange(x_min + step, x_max, step):
        for y0 in np.arange(y_min + step, y_max, step):
            for heading in (0.0, 90.0, 180.0, 270.0):
                start = (float(x0), float(y0), math.radians(heading))
                strongest = characterise(terrain, start, (max(currents),) * 2, duration_s, speed)
                if strongest.margin_m < 2000.0:
                    continue
                measured = characterise(terrain, start, (currents[0],) * 2, duration_s, speed)
                if measured.flat_fraction <= 0.1:
                    out.append((start, measured))
    return out


def pick_along_across(terrain, duration_s: float = 30000.0, speed: float = 0.5, currents=(0.1, 0.15),
                      grid_km: float = 5.0) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """The (drift_along, drift_across) starts (x m, y m, heading rad) of the rule in the module docstring: among
    ``admissible_starts``, those with a slope at least the candidates' median; the smallest and the largest
    drift-contour angle (ties to the larger slope)."""
    candidates = admissible_starts(terrain, duration_s, speed, currents, grid_km)
    if not candidates:
        raise ValueError(f"no candidate track on map {terrain.name!r}: every path leaves the map or is flat")
    median = float(np.median([m.slope_m_per_km for _, m in candidates]))
    sloped = [(s, m) for s, m in candidates if m.slope_m_per_km >= median]
    along = min(sloped, key=lambda c: (c[1].drift_contour_angle_deg, -c[1].slope_m_per_km))[0]
    across = max(sloped, key=lambda c: (c[1].drift_contour_angle_deg, c[1].slope_m_per_km))[0]
    return along, across


# --------------------------------------------------------------------------------- the truth
@dataclass
class Truth:
    states: np.ndarray        # (T + 1, 3): x, y, theta at t = 0, dt, ..., T dt
    inputs: np.ndarray        # (T, 2): commanded v, omega of each step
    measurements: np.ndarray  # (T, 2): depth, heading after each step
    current: tuple[float, float]


def simulate(bundle, terrain, config, start, current, rng: np.random.Generator) -> Truth:
    """The true track (see the module docstring), integrated with the generated eq. 1 step. config: the
    experiment's TanConfig (its n_steps, dt, speed, autopilot_tau and altimeter_sigma are used)."""
    from ...filters.particle.terrain import BODY_NOISE

    T, dt, v = config.n_steps, config.dt, config.speed
    a1, a2, a3, a4 = BODY_NOISE
    x_next = bundle.function("x_next")
    states = np.empty((T + 1, 3))
    inputs = np.empty((T, 2))
    states[0] = start
    p = np.array(current, dtype=np.float64)
    noise = rng.standard_normal((T, 2))
    for k in range(T):
        omega = -(states[k, 2] - start[2]) / config.autopilot_tau
        inputs[k] = (v, omega)
        w = np.array([noise[k, 0] * math.sqrt(a1 * v * v + a2 * omega * omega),
                      noise[k, 1] * math.sqrt(a3 * v * v + a4 * omega * omega), 0.0, 0.0])
        states[k + 1] = x_next(states[k], inputs[k], p, w, dt)
    depth = terrain.depth_at(states[1:, 0], states[1:, 1])
    measurements = np.column_stack([depth + config.altimeter_sigma * rng.standard_normal(T), states[1:, 2]])
    return Truth(states, inputs, measurements, tuple(current))
