"""What the readers make of a log: per mapped stream, its samples in the order they arrived, checked.

    log = read_log(path, sensor_map, model)       # a folder of CSV tables, or a rosbag2 / MCAP bag
    log.samples["gps"].t, .values, .R, .params    # (K,), (K, m), (K, m, m) or None, (K, q) or None

Time: ``t`` and ``arrival`` are seconds of the log's own clock since ``log.epoch`` (a CSV table's time column as it
is, epoch 0; a bag's nanoseconds since its first stamp, so no precision is lost on 1.7e9 s stamps). Each stream's
stamps must increase (an input's may repeat: the later sample holds); a stamp that goes backwards is a LogError
naming the stream, the row and both stamps. Values: the map's scale and offset applied; NaN is a missing entry
(the filter leaves it out); inf is refused naming the row and the field.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .sensor_map import Stream


class LogError(ValueError):
    """A log that cannot be read as mapped; the message names the stream (topic or table), the row and the field."""


@dataclass
class Samples:
    """One mapped stream of the log, in arrival order."""

    stream: Stream
    t: np.ndarray                     # (K,) stamps, s since the log's epoch
    arrival: np.ndarray               # (K,) when each reached the vehicle, s since the epoch
    values: np.ndarray                # (K, m), NaN: a missing entry
    R: np.ndarray | None = None       # (K, m, m): each sample's own covariance
    params: np.ndarray | None = None  # (K, q): the sensor's own parameters with each sample
    rows: np.ndarray | None = None    # (K,) the row (CSV, from 1) or message index (bag, from 0) of each
    skipped: dict = field(default_factory=dict)   # reason -> samples left out by the reader (e.g. "no fix")

    @property
    def role(self) -> str:
        return self.stream.role


@dataclass
class Log:
    path: Path
    kind: str                          # "csv" or "bag"
    samples: dict                      # role -> Samples
    epoch: float = 0.0                 # log time of t = 0, s
    epoch_ns: int | None = None        # a bag's epoch in integer nanoseconds
    storage: str | None = None         # a bag's storage ("mcap" or "sqlite3")
    origin: tuple | None = None        # the local NED origin of geodetic fields (latitude, longitude, altitude)
    row_word: str = "row"              # how messages count samples: "row" (CSV) or "message" (bag)

    @property
    def first_stamp(self) -> float:
        stamps = [s.t[0] for s in self.samples.values() if s.t.size]
        return min(stamps) if stamps else 0.0


def checked_samples(stream: Stream, t, arrival, raw, rows, row_word: str, R=None, params=None,
                    skipped=None) -> Samples:
    """Samples of a stream from raw columns (K, m) with the map's scale and offset, after the checks of the module
    docstring (rows: what each sample is called in messages)."""
    t = np.asarray(t, dtype=np.float64)
    arrival = np.asarray(arrival, dtype=np.float64)
    rows = np.asarray(rows)
    where = stream.source
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise LogError(f"{where}: {row_word} {rows[bad[0]]}: its time stamp is {float(t[bad[0]])!r}, not a finite number of "
                       "seconds")
    steps = np.diff(t)
    backwards = np.flatnonzero(steps < 0 if stream.role == "input" else steps <= 0)
    if backwards.size:
        k = backwards[0] + 1
        word = "goes backwards" if steps[k - 1] < 0 else "repeats"
        raise LogError(f"{where}: {row_word} {rows[k]}: time {word}: t = {float(t[k])!r} s after {float(t[k - 1])!r} s at "
                       f"{row_word} {rows[k - 1]} (each stream's stamps must increase)")
    values = np.asarray(raw, dtype=np.float64).reshape(len(t), len(stream.fields)) * stream.scale + stream.offset
    infinite = np.argwhere(np.isinf(values))
    if infinite.size:
        k, j = infinite[0]
        raise LogError(f"{where}: {row_word} {rows[k]}: field {stream.fields[j]!r} is {float(values[k, j])!r} (use an empty "
                       "value, NaN, for a missing entry)")
    if R is not None:
        R = np.asarray(R, dtype=np.float64) * np.einsum("i,j->ij", stream.scale, stream.scale)
    return Samples(stream, t, arrival, values, R, None if params is None else np.asarray(params, dtype=np.float64),
                   rows, dict(skipped or {}))


def check_covariances(samples: Samples, row_word: str) -> None:
    """Each sample's own R must be finite and positive definite where its entries are present."""
    if samples.R is None:
        return
    for k in range(len(samples.t)):
        present = ~np.isnan(samples.values[k])
        if not present.any():
            continue
        block = samples.R[k][np.ix_(present, present)]
        ok = np.all(np.isfinite(block)) and np.allclose(block, block.T, rtol=1e-9, atol=0.0)
        if ok:
            try:
                np.linalg.cholesky(block)
            except np.linalg.LinAlgError:
                ok = False
        if not ok:
            raise LogError(f"{samples.stream.source}: {row_word} {samples.rows[k]}: its covariance is not a finite "
                           f"positive-definite matrix ({block.tolist()}); give std in the map instead")
