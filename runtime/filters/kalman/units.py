"""A sensor value in the wrong unit: the first updates of every sensor output are watched for a unit slip.

A heading given in degrees where the model says rad, a depth in millimetres or feet where it says m: the filter
gates every such value as an outlier, and the estimate runs on the other sensors (or on nothing) without a word.
So the first `SAMPLES` values of each output are compared with the filter's prediction of them, h(x) before the
update: when nearly all of them lie beyond `SIGMAS` standard deviations of the output's noise and their ratio to
the prediction is steadily one of the usual unit factors (or, for an angle output, they lie beyond 2 pi), a
UnitSlipWarning names the sensor, the output, its declared unit and the likely slip, once. After its samples an
output is no longer watched, so a filter pays for the watch during its first updates only.
"""
from __future__ import annotations

import math
import os
import sys
import warnings

import numpy as np

SAMPLES = 8            # values per output before the watch decides
SIGMAS = 5.0           # beyond the gate: |z - h(x)| > SIGMAS sqrt(R_ii)
AGREEMENT = 0.05       # a ratio within 5 % of a factor, every sample of it

# z / the model's value when z is given in the unit on the left instead of the model's (on the right)
FACTORS = (
    ("degrees", "rad", 180.0 / math.pi), ("degrees per second", "rad/s", 180.0 / math.pi),
    ("millimetres", "m", 1e3), ("centimetres", "m", 1e2), ("kilometres", "m", 1e-3), ("feet", "m", 1.0 / 0.3048),
    ("knots", "m/s", 3600.0 / 1852.0), ("km/h", "m/s", 3.6), ("mm/s", "m/s", 1e3), ("cm/s", "m/s", 1e2),
    ("bar", "Pa", 1e-5), ("decibar", "Pa", 1e-4), ("kPa", "Pa", 1e-3),
)


RUNTIME = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))  # runtime/


def _callers_level() -> int:
    """warnings.warn's stacklevel of the first frame outside runtime/ (the user's call) from the caller."""
    frame, level = sys._getframe(1), 1
    while frame is not None and frame.f_code.co_filename.startswith(RUNTIME):
        frame, level = frame.f_back, level + 1
    return level


class UnitSlipWarning(UserWarning):
    """A sensor's values look like they are in another unit than the model declares."""


class UnitWatch:
    """The watch over one filter's sensors (model: a loaded bundle; its manifest's sensors and outputs)."""

    def __init__(self, model, filter_name: str):
        self.model, self.filter_name = model, filter_name
        rows = model.n_y
        self.samples: list[list[tuple[float, float, float]]] = [[] for _ in range(rows)]
        self.open = np.ones(rows, dtype=bool)
        self.angle = np.zeros(rows, dtype=bool)
        self.names: list[tuple[str, str, str]] = []
        self.sensors = [(s["offset"], s["offset"] + len(s["outputs"])) for s in model.sensors]  # each one's rows
        self.watching = [True] * len(self.sensors)
        self.updates = [0] * len(self.sensors)
        for sensor in model.sensors:
            for k in sensor["angle_outputs"]:  # (indices of the sensor's angle outputs)
                self.angle[sensor["offset"] + k] = True
            for output in sensor["outputs"]:
                self.names.append((sensor["name"], output["name"], output["unit"]))

    @property
    def done(self) -> bool:
        return not any(self.watching)

    def observe_sensor(self, k: int, z: np.ndarray, y: np.ndarray, R: np.ndarray) -> None:
        """One update of sensor k: its values z (NaN: missing), the prediction y of them and their noise R."""
        first, end = self.sensors[k]
        self.observe(first, z, y, R)
        self.updates[k] += 1
        if self.updates[k] >= 2 * SAMPLES or not self.open[first:end].any():
            self.watching[k] = False
            self.open[first:end] = False

    def observe(self, first_row: int, z: np.ndarray, y: np.ndarray, R: np.ndarray) -> None:
        """The values z of rows first_row.. (NaN: missing), the prediction y of them and their noise R (square)."""
        sigma = np.sqrt(np.abs(np.diag(R)))
        for k in range(len(z)):
            row = first_row + k
            if not self.open[row] or not (math.isfinite(z[k]) and math.isfinite(y[k])):
                continue
            self.samples[row].append((float(z[k]), float(y[k]), float(sigma[k])))
            if len(self.samples[row]) >= SAMPLES:
                self.open[row] = False
                slip = self._slip(row)
                if slip:
                    self._warn(row, slip)
                self.samples[row] = []

    def _slip(self, row: int) -> str | None:
        z, y, sigma = (np.array(column) for column in zip(*self.samples[row]))
        beyond = np.abs(z - y) > SIGMAS * np.maximum(sigma, 1e-300)
        if beyond.sum() < SAMPLES - 1:  # (one may fall inside by chance)
            return None
        unit = self.names[row][2]
        if self.angle[row]:  # wrapped angles: no ratio to y, but radians never exceed 2 pi
            return f"degrees (|values| up to {np.abs(z).max():.4g}, beyond 2 pi)" if (np.abs(z) > 2 * np.pi).sum() \
                >= SAMPLES - 1 else None
        usable = np.abs(y) > 10 * np.maximum(sigma, 1e-12)
        if usable.sum() < SAMPLES // 2:
            return None
        ratios = z[usable] / y[usable]
        for name, model_unit, factor in FACTORS:
            if (unit == model_unit or unit in ("", "-", None)) and np.all(np.abs(ratios / factor - 1.0) < AGREEMENT):
                return f"{name} (about {factor:.4g}x the prediction)"
        return None

    def _warn(self, row: int, slip: str) -> None:
        sensor, output, unit = self.names[row]
        warnings.warn(f"{self.filter_name}: sensor {sensor!r} output {output!r} ({unit}): its first {SAMPLES} values were "
                      f"beyond {SIGMAS:g} sigma of the prediction and look like {slip}; the model expects {unit} "
                      "(the filter gates such values as outliers)", UnitSlipWarning, stacklevel=_callers_level())
