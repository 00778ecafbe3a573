"""The replay of a log through the bootstrap particle filter (``--filter pf``), on a clock of its own.

The particle filter has no history and one process noise per step, so it cannot take irregular, late measurements
as the Kalman replay does. It runs on ticks of the map's [filter] dt from t0, offline (the samples in stamp order):
tick k predicts from k dt to (k + 1) dt with the input held at k dt, then updates with the stacked measurement of
every sensor stamped in (k dt, (k + 1) dt], NaN for the sensors with no sample in it. So a measurement is used at the
end of its tick, up to dt after its stamp; two samples of one sensor in a tick keep the later (the earlier is
counted as skipped); a sample's own parameters go into the tick's p. What it cannot do it refuses, naming the
reason: each sample's own covariance (one R per sensor), noise = "inputs" (G(x) differs from particle to particle),
smoothing. Q per tick: the map's Q ("step") or Q dt ("rate"). NIS is not defined for a particle filter; each
measurement's innovation is z - h(x) at the predicted mean.
"""
from __future__ import annotations

import math
import time

import numpy as np

from ..filters.particle import ParticleFilter
from ..noise import GaussianMixture
from .log import Log
from .progress import progress_bar
from .run import Measurement, Replay, Track, next_input, stacked_R, start_time
from .sensor_map import MapError, SensorMap


def check_particle_replay(sensor_map: SensorMap, smooth: bool) -> None:
    """MapError naming why this map or log cannot run through the particle filter (module docstring)."""
    where = sensor_map.path
    if smooth:
        raise MapError("--filter pf: the particle filter has no smoother; --smooth needs ekf, ukf or ckf")
    if sensor_map.filter.dt is None:
        raise MapError(f"{where}: [filter] dt: --filter pf runs on a clock of its own: give its step in seconds (e.g. the "
                       "fastest sensor's period)")
    if sensor_map.filter.noise == "inputs":
        raise MapError(f"{where}: [filter] noise = \"inputs\": the particle filter takes Q per step or per second "
                       "(\"step\" or \"rate\"); G Q G^T differs from particle to particle")
    for name, stream in sensor_map.sensors.items():
        if stream.covariance != "model":
            raise MapError(f"{where}: [sensors.{name}]: each sample's own covariance: the particle filter uses one R per "
                           "sensor (give std instead)")


def run_particle(model, log: Log, sensor_map: SensorMap, progress: bool = True) -> Replay:
    """The replay of the module docstring."""
    check_particle_replay(sensor_map, smooth=False)
    settings = sensor_map.filter
    dt = settings.dt
    t0 = start_time(log, sensor_map)
    Q = settings.Q * dt if settings.noise == "rate" else settings.Q
    R = stacked_R(model, sensor_map)
    noise = GaussianMixture(np.ones(1), np.zeros((1, model.n_y)), R[None])
    pf = ParticleFilter(model, settings.x0, settings.P0, Q, noise, settings.particles, settings.seed,
                        gate_probability=settings.gate_probability)
    p_model = model.params(**settings.parameters)
    offsets = {s["name"]: s["offset"] for s in model.sensors}
    p_offsets = {s["name"]: s["p_offset"] for s in model.sensors}

    # the samples in stamp order, each with its tick
    samples = sorted((s.t[k] - t0, role, k) for role, s in log.samples.items() for k in range(len(s.t)))
    last = max((t for t, _, _ in samples), default=0.0)
    ticks = max(int(math.ceil(last / dt - 1e-9)), 0)
    counts = {name: {"received": len(log.samples[name].t), "used": 0, "gated": 0, "inflations": 0, "late": 0, "too late": 0,
                     "skipped": dict(log.samples[name].skipped)} for name in sensor_map.sensors}
    measurements = []
    u_held = None if model.n_u else np.zeros(0)
    rows_t, rows_event, rows_x, rows_P = [0.0], ["start"], [pf.x], [pf.P]
    started = time.perf_counter()
    at = unattributed = 0
    bar = progress_bar(ticks, progress, "replay PF")
    try:
        while at < len(samples) and samples[at][0] <= 0.0:  # inputs at or before t0 set the held input
            t, role, k = samples[at]
            if role == "input":
                u_held = next_input(log, k, u_held)[0]
            else:
                reason = "before t0" if t < 0.0 else "at t0 (before the first tick)"
                measurements.append(_skipped(log, role, k, t, t0, reason, counts[role]))
            at += 1
        for tick in range(ticks):
            end = (tick + 1) * dt
            in_tick = []
            while at < len(samples) and samples[at][0] <= end + 1e-12 * max(1.0, end):
                in_tick.append(samples[at])
                at += 1
            if u_held is None:  # nothing to predict with: skip the measurements, take the inputs
                for t, role, k in in_tick:
                    if role == "input":
                        u_held = next_input(log, k, u_held)[0]
                    else:
                        measurements.append(_skipped(log, role, k, t, t0, "before the first input", counts[role]))
                continue
            pf.predict(u_held, dt, p_model)
            z, p, chosen = np.full(model.n_y, np.nan), p_model.copy(), {}
            for t, role, k in in_tick:
                if role == "input":
                    continue
                s = log.samples[role]
                if role in chosen:
                    old = chosen[role]
                    measurements.append(_skipped(log, role, old[1], old[0], t0, "two in one tick (the earlier left out)",
                                                 counts[role]))
                chosen[role] = (t, k)
                rows = slice(offsets[role], offsets[role] + s.values.shape[1])
                z[rows] = s.values[k]
                if s.params is not None:
                    p[p_offsets[role]:p_offsets[role] + s.params.shape[1]] = s.params[k]
            x_prior = pf.x
            if chosen and not np.isnan(z).all():
                h = model.h(x_prior, p)
                before = pf.gated
                used = pf.update(z, p)
                gated = pf.gated - before
                status = "used" if used and not gated else ("gated" if not used else "partly gated")
                if gated and len(chosen) > 1:  # the gate counts the stacked measurement's entries, not per sensor
                    status = "tick partly gated" if used else "gated"
                    unattributed += gated
                for role, (t, k) in chosen.items():
                    s = log.samples[role]
                    rows = slice(offsets[role], offsets[role] + s.values.shape[1])
                    record = Measurement(role, t, log.samples[role].arrival[k] - t0, int(s.rows[k]), s.values[k].copy(),
                                         status)
                    record.innovation = z[rows] - h[rows]
                    counts[role]["used"] += bool(used)
                    counts[role]["gated"] += gated if len(chosen) == 1 else 0
                    measurements.append(record)
            for t, role, k in in_tick:  # an input takes effect at the next tick
                if role == "input":
                    u_held = next_input(log, k, u_held)[0]
            rows_t.append(end)
            rows_event.append("tick")
            rows_x.append(pf.x)
            rows_P.append(pf.P)
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    n = model.n_x
    notes = [f"particle filter: the bootstrap SIR with {settings.particles} particles (seed {settings.seed}) on ticks of "
             f"dt = {dt:g} s: each tick fuses the stacked measurement of the sensors stamped in it, NaN for the "
             "sensors without a sample there; a measurement is used at the end of its tick (up to dt after its "
             "stamp); one R per sensor; the innovations are z - h(x) at the predicted mean; NIS is not defined"]
    if unattributed:
        notes.append(f"{unattributed} measurement entries were gated in ticks with several sensors: the gate counts the "
                     "stacked measurement's entries, so they are not counted per sensor (status \"tick partly gated\")")
    track = Track(np.array(rows_t), rows_event, np.array(rows_x).reshape(-1, n), np.array(rows_P).reshape(-1, n, n))
    return Replay(model, "PF", log, sensor_map, t0, track, None, measurements, counts, notes,
                  time.perf_counter() - started, pf)


def _skipped(log: Log, role: str, k: int, t: float, t0: float, reason: str, counts: dict) -> Measurement:
    s = log.samples[role]
    counts["skipped"][reason] = counts["skipped"].get(reason, 0) + 1
    return Measurement(role, t, s.arrival[k] - t0, int(s.rows[k]), s.values[k].copy(), reason)
