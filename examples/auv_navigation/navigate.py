"""The navigator: one Kalman filter over a dive's sensor reports, in the order they arrive.

    track = navigate(bundle, EKF, dive, handling="stamp", smoothing=False, seed=0)
    track.t, track.x (T, 12), track.P (T, 12, 12)     the real-time estimate on the 20 Hz clock
    track.nis["usbl"]                                  (NIS, dof) of every accepted update of that sensor
    track.smoothed                                     (x, P) on the same clock (smoothing=True)

Every report is handed over when it arrives, with its own stamp; the filter predicts to each stamp with the input
held since its last one (predict_to) and updates with the sensor that sent it (update). Delayed USBL fixes:

    "stamp"    fused at their ping from the filter's history (history_seconds covers the latency)
    "arrival"  fused as if measured when they arrive (the wrong time: the vehicle moved on 0.3-1.4 m meanwhile)
    "dropped"  not used at all (dead reckoning between the surface fixes)

The filter knows what a navigator would: the model, the sensors' declared noise (and each USBL fix's own quality
figure), the force noise's spectral density as Q (noise="inputs"), the autopilot's inputs, a start drawn around the
truth with the P0 it is given. Nothing else of the truth.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from simulate import CLOCK, FORCE_PSD, Dive

HANDLINGS = ("stamp", "arrival", "dropped")
#: the start's uncertainty (standard deviations): body velocities, rates, NED position, Euler angles
START_SIGMA = np.array([0.1, 0.05, 0.05, 0.02, 0.02, 0.02, 3.0, 3.0, 0.3, *np.radians([2.0, 2.0, 5.0])])
#: the estimate is reported on the AHRS's 20 Hz clock
REPORT_EVERY = CLOCK // 20
#: how far back a late fix may be fused (the USBL's latency is at most 1 s)
HISTORY_SECONDS = 1.5


@dataclass
class Track:
    t: np.ndarray
    x: np.ndarray
    P: np.ndarray
    nis: dict = field(default_factory=dict)       # sensor -> (k, 2) array of (NIS, dof)
    counts: dict = field(default_factory=dict)    # sensor -> sensor_report (used, gated, late, ...)
    smoothed: tuple | None = None                 # (x, P) on the clock t


def start(dive: Dive, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """x0 drawn around the truth with covariance P0 (its own random stream), and P0."""
    P0 = np.diag(START_SIGMA**2)
    rng = np.random.default_rng([seed, 35])
    return dive.x[0] + START_SIGMA * rng.standard_normal(START_SIGMA.size), P0


def make_filter(bundle, kind, dive: Dive, handling: str, smoothing: bool, seed: int):
    x0, P0 = start(dive, seed)
    options = dict(noise="inputs")
    if smoothing:  # the whole dive in the history: every event of it (a predict and an update per report at most)
        options.update(smoothing=True, history_seconds=dive.mission.duration + 1.0,
                       history_entries=2 * len(dive.measurements) + len(dive.t) // REPORT_EVERY + 16)
    elif handling == "stamp":
        options.update(history_seconds=HISTORY_SECONDS)
    return kind(bundle, x0, P0, np.diag(FORCE_PSD), None, **options)


def feed(flt, dive: Dive, handling: str, clock: np.ndarray, on_update=None):
    """Hand the dive's reports to the filter as they arrive; yield the index of each clock time once the filter is
    there (predicted to it after every report that arrived by then). on_update(sensor, used) follows every update."""
    if handling not in HANDLINGS:
        raise ValueError(f"handling must be one of {HANDLINGS}, got {handling!r}")
    reports, i = dive.measurements, 0
    for j, now in enumerate(clock):
        while i < len(reports) and reports[i].arrival <= now:
            m = reports[i]
            i += 1
            if m.sensor == "usbl" and handling == "dropped":
                continue
            t = m.arrival if (m.sensor == "usbl" and handling == "arrival") else m.stamp
            if t > flt.t:
                flt.predict_to(t, dive.input_at(flt.t))
            used = flt.update(m.sensor, m.z, t, R=m.R)
            if on_update:
                on_update(m.sensor, used)
        if now > flt.t:
            flt.predict_to(now, dive.input_at(flt.t))
        yield j


def navigate(bundle, kind, dive: Dive, handling: str = "stamp", smoothing: bool = False, seed: int = 0) -> Track:
    """Run one filter class (EKF, UKF, CKF) over the dive's reports as they arrive; see the module docstring."""
    flt = make_filter(bundle, kind, dive, handling, smoothing, seed)
    clock = dive.t[::REPORT_EVERY]
    xs, Ps = np.empty((clock.size, bundle.n_x)), np.empty((clock.size, bundle.n_x, bundle.n_x))
    nis = {name: [] for name in bundle.sensor_names}

    def record(sensor, used):
        if used:
            nis[sensor].append((flt.nis, flt.nis_dof))

    for j in feed(flt, dive, handling, clock, record):
        xs[j], Ps[j] = flt.x, flt.P
    track = Track(clock, xs, Ps, {k: np.array(v).reshape(-1, 2) for k, v in nis.items()},
                  {name: flt.sensor_report(name) for name in bundle.sensor_names})
    if smoothing:
        t_s, x_s, P_s = flt.smooth()
        rows = np.searchsorted(t_s, clock, side="right") - 1  # the last event at each time: after all its updates
        if not np.array_equal(t_s[rows], clock):
            raise RuntimeError("the smoother's history does not cover the dive's clock: raise history_entries")
        track.smoothed = (x_s[rows], P_s[rows])
    return track
