"""The replay of a log through a Kalman filter (EKF, UKF, CKF): the calls a vehicle would have made, in the order
the measurements reached it.

    replay = run_kalman(model, log, sensor_map, "ckf", smooth=True)
    replay.track          # the filter's state after every call: Track(t, event, x, P)
    replay.smoothed       # Rauch-Tung-Striebel over the whole log (filter.smooth()), or None
    replay.measurements   # one Measurement per sample of a sensor: what the filter did with it
    replay.counts         # per sensor: received, used, gated entries, late, too late, skipped (by reason)

The run. Samples of every stream are merged in arrival order (a CSV's stamps, unless it maps an arrival column; a
bag's record times), ties broken by the stamp, then inputs before measurements. Filter time is log time minus t0
(the map's [filter] t0, else the first stamp of the input, else of any stream). An input holds from its stamp
until the next: at its stamp the filter is predicted to it with the input before (predict_to), then the new one is
held. A measurement stamped at or after the filter's time is fused at its stamp (predict_to, then update(sensor, z,
t, R, p)); one stamped before it (it arrived late) is fused at its stamp from the filter's history (its fixed lag,
[filter] history_seconds) or, older than the lag, counted as too late and left out (the filter is unchanged).
Measurements stamped before t0, before the first input (a model with inputs) or with no entry present are counted
as skipped. R is each sample's own covariance when the map asks for it, else the filter's (the map's std or the
model's declared noise); a sensor's own parameters come with each sample when the map names their fields.

Smoothing (--smooth): the filter keeps every event of the log in its history (history_entries: the log's events;
history_seconds: its duration) and smooth() runs the C runtime's Rauch-Tung-Striebel pass over it at the end.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import block_diag

from ..compiled import kalman as kr
from ..filters.kalman import CKF, EKF, UKF
from .log import Log, LogError
from .progress import progress_bar
from .sensor_map import MapError, SensorMap

KALMAN = {"ekf": EKF, "ukf": UKF, "ckf": CKF}


@dataclass
class Track:
    """States over time: t (K,) s since t0, event (K,) what made each row, x (K, n), P (K, n, n)."""

    t: np.ndarray
    event: list
    x: np.ndarray
    P: np.ndarray


@dataclass
class Measurement:
    """One sample of a sensor and what the filter did with it."""

    sensor: str
    t: float                       # its stamp, s since t0
    arrival: float                 # s since t0
    row: int                       # its row (CSV) or message index (bag)
    z: np.ndarray                  # (m,) NaN: missing
    status: str                    # "used", "partly gated", "gated", "too late", or a reason it was skipped
    late: bool = False             # fused at its stamp from the history
    innovation: np.ndarray | None = None   # (m,) of the update (NaN on entries it did not use)
    S: np.ndarray | None = None            # (m, m)
    nis: float = np.nan
    nis_dof: int = 0


@dataclass
class Replay:
    """A replayed log (module docstring)."""

    model: object
    filter_name: str
    log: Log
    sensor_map: SensorMap
    t0: float                      # log time of the filter's t = 0 (s since the log's epoch)
    track: Track
    smoothed: Track | None
    measurements: list
    counts: dict
    notes: list = field(default_factory=list)
    elapsed: float = 0.0
    filter: object = None


def stacked_R(model, sensor_map: SensorMap) -> np.ndarray:
    """The filter's R: each sensor's block (the map's std, the model's declared noise); a sensor the map leaves out
    keeps its declared noise, or the identity (it never measures)."""
    blocks = []
    for spec in model.sensors:
        name = spec["name"]
        if name in sensor_map.sensors:
            blocks.append(sensor_map.R_block(model, name))
        elif spec.get("noise") is not None:
            blocks.append(np.array(spec["noise"], dtype=np.float64))
        else:
            blocks.append(np.eye(len(spec["outputs"])))
    return block_diag(*blocks)


def start_time(log: Log, sensor_map: SensorMap) -> float:
    """t0 in the log's time (s since its epoch): the map's, else the first stamp of the input, else of any stream."""
    if sensor_map.filter.t0 is not None:
        return sensor_map.filter.t0 - log.epoch
    first_input = log.samples.get("input")
    if first_input is not None and first_input.t.size:
        return float(first_input.t[0])
    return float(log.first_stamp)


def merged_events(log: Log, sensor_map: SensorMap) -> list[tuple[float, float, int, str, int]]:
    """(arrival, stamp, input first, role, sample index) of every sample, in the order they arrived."""
    events = []
    for role, samples in log.samples.items():
        first = 0 if role == "input" else 1
        events.extend(zip(samples.arrival.tolist(), samples.t.tolist(), [first] * len(samples.t),
                          [role] * len(samples.t), range(len(samples.t))))
    events.sort()
    return events


def next_input(log: Log, k: int, u_held) -> tuple[np.ndarray, int]:
    """Input sample k with its missing entries held from u_held, and how many were held (LogError when the first
    sample misses entries: there is nothing to hold)."""
    samples = log.samples["input"]
    u = samples.values[k].copy()
    missing = np.isnan(u)
    if missing.any():
        if u_held is None:
            raise LogError(f"{samples.stream.source}: {log.row_word} {samples.rows[k]}: the first input sample has "
                           f"missing entries {np.flatnonzero(missing).tolist()} (an input is held from its first "
                           "complete sample)")
        u[missing] = u_held[missing]
    return u, int(missing.sum())


def run_kalman(model, log: Log, sensor_map: SensorMap, kind: str, smooth: bool = False,
               progress: bool = True) -> Replay:
    """The replay of the module docstring through EKF/UKF/CKF (kind)."""
    if kind not in KALMAN:
        raise ValueError(f"filter {kind!r}: a Kalman replay runs one of {sorted(KALMAN)}")
    settings = sensor_map.filter
    t0 = start_time(log, sensor_map)
    events = merged_events(log, sensor_map)
    p = model.params(**settings.parameters)
    options = dict(noise=settings.noise, gate_probability=settings.gate_probability)
    if kind == "ukf":
        options.update(settings.sigma_points)
    measurements_total = sum(len(s.t) for role, s in log.samples.items() if role != "input")
    if smooth:  # the whole log in the history: every predict and update, and its whole duration
        last = max((e[1] for e in events), default=t0)
        options.update(smoothing=True, history_entries=int(2 * len(events) + 2),
                       history_seconds=float(max(last - t0, 0.0) + 1.0))
    else:
        options.update(history_seconds=settings.history_seconds, history_entries=settings.history_entries)
    try:
        flt = KALMAN[kind](model, settings.x0, settings.P0, settings.Q, stacked_R(model, sensor_map), **options)
    except MemoryError:
        raise MapError(f"--smooth keeps all {len(events)} events of the log in the filter's history, and that does not "
                       "fit in memory here: replay a part of the log (the map's [filter] t0 and a shorter log)") from None
    n = model.n_x
    rows_t, rows_event, rows_x, rows_P = [0.0], ["start"], [flt.x], [flt.P]

    def row(event: str) -> None:
        rows_t.append(flt.t)
        rows_event.append(event)
        rows_x.append(flt.x)
        rows_P.append(flt.P)

    counts = {name: {"received": len(log.samples[name].t), "used": 0, "gated": 0, "inflations": 0, "late": 0,
                     "too late": 0, "skipped": {}} for name in sensor_map.sensors}
    for name, samples in log.samples.items():
        if name != "input":
            for reason, count in samples.skipped.items():
                counts[name]["skipped"][reason] = count
    notes, measurements = [], []
    u_held = None if model.n_u else np.zeros(0)
    late_inputs = held_entries = 0
    started = time.perf_counter()
    bar = progress_bar(len(events), progress, f"replay {kind.upper()}")
    try:
        for arrival, stamp, _, role, k in events:
            samples = log.samples[role]
            t = stamp - t0
            if role == "input":
                u_new, held = next_input(log, k, u_held)
                held_entries += held
                if t > flt.t and u_held is not None:
                    flt.predict_to(t, u_held, p)
                    row("predict")
                elif 0.0 < t < flt.t:
                    late_inputs += 1
                u_held = u_new
            else:
                measurements.append(_measure(flt, model, samples, k, t, arrival - t0, u_held, p, counts[role], row,
                                             log.row_word))
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    for name in counts:  # P inflated after this sensor's streaks of gated entries (the runtime's gate)
        counts[name]["inflations"] = flt.sensor_report(name)["inflations"]
    smoothed = None
    if smooth:
        t_s, x_s, P_s = flt.smooth()
        if t_s.size and t_s[0] > 0.0:  # the history lost its oldest events: never expected with the sizes above
            raise RuntimeError(f"smoothing: the history starts at t = {t_s[0]} s, not at t0 (it holds {flt.history} "
                               "events)")
        smoothed = Track(t_s, ["smoothed"] * len(t_s), x_s, P_s)
    if late_inputs:
        notes.append(f"{late_inputs} input samples arrived after a measurement stamped later had moved the filter on: "
                     "each was held from then on (the filter cannot redo a predict with another input)")
    if held_entries:
        notes.append(f"{held_entries} missing input entries held their previous value")
    if measurements_total == 0:
        notes.append("no sensor sample in the log: the track is the prediction from x0")
    track = Track(np.array(rows_t), rows_event, np.array(rows_x).reshape(-1, n), np.array(rows_P).reshape(-1, n, n))
    return Replay(model, kind.upper(), log, sensor_map, t0, track, smoothed, measurements, counts, notes,
                  time.perf_counter() - started, flt)


def _measure(flt, model, samples, k, t, arrival, u_held, p, counts, row, row_word) -> Measurement:
    """One sensor sample through the filter (module docstring); its record."""
    name = samples.role
    z = samples.values[k]
    record = Measurement(name, t, arrival, int(samples.rows[k]), z.copy(), "used")
    skip = None
    if t < 0:
        skip = "before t0"
    elif u_held is None:
        skip = "before the first input"
    elif np.isnan(z).all():
        skip = "no entry present"
    if skip is not None:
        counts["skipped"][skip] = counts["skipped"].get(skip, 0) + 1
        record.status = skip
        return record
    R = samples.R[k] if samples.R is not None else None
    q = samples.params[k] if samples.params is not None else None
    late = t < flt.t
    if not late and t > flt.t:
        flt.predict_to(t, u_held, p)
        row("predict")
    before = flt.sensor_report(name)["gated"]
    try:
        used = flt.update(name, z, t, R=R, p=q)
    except ValueError as exc:
        if flt.code == kr.E_TOO_LATE:
            counts["too late"] += 1
            record.status = "too late"
            return record
        raise LogError(f"{samples.stream.source}: {row_word} {samples.rows[k]}: the filter refused it: {exc}") from None
    gated = flt.sensor_report(name)["gated"] - before
    counts["gated"] += gated
    record.late = late
    counts["late"] += late
    present = ~np.isnan(z)
    if used:
        counts["used"] += 1
        record.status = "partly gated" if gated else "used"
        innovation, S = flt.innovation, flt.S
        unused = ~present
        if gated:  # the runtime reports 0 and an identity row on the entries it left out
            unused |= (innovation == 0.0) & np.all(S == np.eye(len(z)), axis=1)
        innovation = np.where(unused, np.nan, innovation)
        record.innovation, record.S, record.nis, record.nis_dof = innovation, S, flt.nis, flt.nis_dof
    else:
        record.status = "gated"
    row(name + (" (late)" if late else ""))
    return record
