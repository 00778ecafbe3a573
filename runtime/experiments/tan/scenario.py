"""Seed 003's simulated world (section 4): an AUV crossing a bathymetry map under an unknown current.

``simulate(bundle, terrain, config, start, current, rng) -> Truth`` is one true track and what the filter
gets from it; the maps are ``get_map(name)``. The filters, the cases and the metrics are experiment.py.

Set-up (Table 2 where it says; DECISION where it does not):

* Vehicle: forward speed 0.5 m/s, heading 0 (along +x), operating depth 0 m; truth at 1 Hz (dt = 1 s)
  for ``duration_s`` (the paper's 30 000 s; ``quick`` shortens it).
* Truth (DECISION): eq. 1 with the body noise of eq. 2 (a = 0.1, 0.1, 0.001, 0.1) disturbing the
  true speed and turn rate, plus the current (d_x, d_y) (Table 2: (0.1, 0.1) and (0.15, 0.15)
  m/s along +x +y; (0, 0) for Fig. 7's "body noise alone"). A heading autopilot with an ideal
  heading sensor commands omega_k = -(theta_k - 0)/tau, tau = 10 s, so the track stays straight
  (the body noise alone would random-walk the heading by ~2.7 rad over 30 000 s).
* What the filter gets: the commanded [v, omega_k] as its input, and z = [altimeter depth, compass
  heading]: depth = map(x, y) + N(0, 5^2) (Table 2), heading exact (the paper's filter estimates
  position only). The current is unknown to the filter: absorbing it is the process noise's job.
* Maps: the synthetic Arctic-like map (seeded, ``map_seed``) with the paper's start postures
  [20 km, 20 km] (rough slope) and [60 km, 10 km] (flat plain); and the topobathy window with
  the same postures, labelled "slope" ([20, 20] km: the upper continental slope) and "shelf"
  ([60, 10] km: the continental shelf, gently sloping -- not a flat plain).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

STARTS = {"rough": (20e3, 20e3, 0.0), "flat": (60e3, 10e3, 0.0)}
#: what the paper's two postures land on in each map (the topobathy window has no flat plain there)
START_LABELS = {"arctic": {"rough": "rough", "flat": "flat"}, "topobathy": {"rough": "slope", "flat": "shelf"}}
CURRENTS = {"0": (0.0, 0.0), "0.1": (0.1, 0.1), "0.15": (0.15, 0.15)}

_MAP_CACHE: dict = {}


def get_map(name: str, seed: int = 0):
    """The named map (built once per process)."""
    from ...terrain import MAPS

    key = (name, seed)
    if key not in _MAP_CACHE:
        _MAP_CACHE[key] = MAPS[name](seed) if name == "arctic" else MAPS[name]()
    return _MAP_CACHE[key]


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
