"""A CSV log: a folder with one table per stream (the input, each sensor), each with a time column.

    log/attitude.csv     t,pitch,heading           the map's [input] table = "attitude.csv", fields, time = "t"
    log/depth.csv        t,depth
    log/gps.csv          t,lat,lon                 latitude = "lat", longitude = "lon": fields north, east, down

A table is read with the csv module (a header row, then one sample per row; "#" starts a comment line). An empty
cell (or NaN) is a missing entry. Anything unreadable is a LogError naming the table, the row (the first data row is
row 1; its line in the file is given too), the column and the value. Geodetic columns are converted to north, east,
down about the map's [log] origin, or the first fix of the log (pymap3d, frames.geodetic_to_ned).
"""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from ..frames import geodetic_to_ned
from .log import Log, LogError, check_covariances, checked_samples
from .sensor_map import SensorMap, Stream

GEODETIC_FIELDS = ("north", "east", "down")


class _Table:
    """A CSV table's columns as text, with the line of each data row."""

    def __init__(self, folder: Path, name: str):
        self.name, path = name, folder / name
        if not path.is_file():
            present = sorted(p.name for p in folder.glob("*.csv"))
            raise LogError(f"table {name}: no such file in the log folder {folder} (its tables: {present})")
        try:
            with open(path, newline="", encoding="utf-8") as handle:
                lines = [(number, line) for number, line in enumerate(handle, 1) if line.strip() and not line.startswith("#")]
        except UnicodeDecodeError as exc:
            raise LogError(f"table {name}: not a UTF-8 text file ({exc})") from None
        if not lines:
            raise LogError(f"table {name}: empty (a header row, then one row per sample)")
        rows = list(csv.reader(line for _, line in lines))
        self.header = [h.strip() for h in rows[0]]
        self.lines = [number for number, _ in lines[1:]]
        self.cells = rows[1:]
        for k, row in enumerate(self.cells):
            if len(row) != len(self.header):
                raise LogError(f"table {name}: row {k + 1} (line {self.lines[k]}) has {len(row)} cells, the header "
                               f"{len(self.header)} ({self.header})")

    def column(self, name: str, role: str, allow_missing: bool = True) -> np.ndarray:
        if name not in self.header:
            raise LogError(f"table {self.name}: no column {name!r} (for {role}); its columns: {self.header}")
        j = self.header.index(name)
        out = np.empty(len(self.cells))
        for k, row in enumerate(self.cells):
            text = row[j].strip()
            if not text:
                if not allow_missing:
                    raise LogError(f"table {self.name}: row {k + 1} (line {self.lines[k]}): column {name!r} is empty "
                                   f"({role} needs a value)")
                out[k] = np.nan
                continue
            try:
                out[k] = float(text)
            except ValueError:
                raise LogError(f"table {self.name}: row {k + 1} (line {self.lines[k]}): column {name!r}: {text!r} is "
                               "not a number") from None
        return out


def read_csv_log(folder: Path, sensor_map: SensorMap) -> Log:
    """The mapped streams of a folder of CSV tables (module docstring)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise LogError(f"{folder}: a CSV log is a folder with one table per stream (the map names them)")
    tables: dict[str, _Table] = {}
    raw: dict[str, tuple] = {}
    for stream in sensor_map.streams:
        if stream.table is None:
            raise LogError(f"{stream.source}: a CSV log has tables, not topics (the map's [{_key(stream)}] needs "
                           "table = \"NAME.csv\")")
        if stream.table not in tables:
            tables[stream.table] = _Table(folder, stream.table)
        raw[stream.role] = _read_stream(tables[stream.table], stream)
    origin = sensor_map.log.origin or _first_fix(raw, sensor_map)
    log = Log(folder, "csv", {}, origin=origin)
    for stream in sensor_map.streams:
        t, arrival, columns, geodetic, std, params, rows = raw[stream.role]
        if geodetic is not None:
            lat, lon, alt = geodetic
            north, east, down = geodetic_to_ned(lat, lon, alt, origin)
            derived = {"north": north, "east": east, "down": down}
            columns = [derived[f] if isinstance(f, str) else f for f in columns]
        values = np.column_stack(columns) if columns else np.zeros((len(t), 0))
        R = None
        if std is not None:
            bad = np.argwhere(~(std > 0) & ~np.isnan(values))
            if bad.size:
                k, j = bad[0]
                raise LogError(f"{stream.source}: row {rows[k]}: std column {stream.std_columns[j]!r} is {std[k, j]!r} "
                               f"for a present {stream.fields[j]!r} (a standard deviation must be positive)")
            R = np.zeros((len(t), std.shape[1], std.shape[1]))
            idx = np.arange(std.shape[1])
            R[:, idx, idx] = np.where(np.isnan(std), 1.0, std) ** 2
        samples = checked_samples(stream, t, arrival, values, rows, "row", R=R, params=params)
        check_covariances(samples, "row")
        if params is not None:
            bad = np.argwhere(~np.isfinite(params))
            if bad.size:
                k, j = bad[0]
                raise LogError(f"{stream.source}: row {rows[k]}: parameter column {stream.parameters[j]!r} is "
                               f"{params[k, j]!r} (the sensor's own parameters must be finite)")
        log.samples[stream.role] = samples
    return log


def _key(stream: Stream) -> str:
    return "input" if stream.role == "input" else f"sensors.{stream.role}"


def _read_stream(table: _Table, stream: Stream):
    role = "the input" if stream.role == "input" else f"sensor {stream.role!r}"
    t = table.column(stream.time, f"the time of {role}", allow_missing=False)
    arrival = t if stream.arrival is None else table.column(stream.arrival, f"the arrival of {role}", allow_missing=False)
    geodetic = None
    if stream.geodetic is not None:
        lat_name, lon_name, alt_name = stream.geodetic
        lat = table.column(lat_name, f"{role}'s latitude")
        lon = table.column(lon_name, f"{role}'s longitude")
        alt = np.zeros(len(t)) if alt_name is None else table.column(alt_name, f"{role}'s altitude")
        for name, values, limit in ((lat_name, lat, 90.0), (lon_name, lon, 360.0)):
            bad = np.flatnonzero(np.abs(values) > limit)
            if bad.size:
                raise LogError(f"table {table.name}: row {bad[0] + 1} (line {table.lines[bad[0]]}): column {name!r}: "
                               f"{values[bad[0]]!r} is not a {'latitude' if limit == 90 else 'longitude'} in degrees")
        geodetic = (lat, lon, alt)
    columns = []
    for name in stream.fields:
        if geodetic is not None and name in GEODETIC_FIELDS:
            columns.append(name)  # filled once the origin is known
        else:
            columns.append(table.column(name, f"{role}'s field"))
    std = None
    if stream.std_columns:
        std = np.column_stack([table.column(c, f"{role}'s standard deviation") for c in stream.std_columns])
    params = None
    if stream.parameters:
        params = np.column_stack([table.column(c, f"{role}'s parameter") for c in stream.parameters])
    rows = np.arange(1, len(t) + 1)
    return t, arrival, columns, geodetic, std, params, rows


def _first_fix(raw: dict, sensor_map: SensorMap):
    """The earliest geodetic sample with a latitude and longitude (the default origin), or None."""
    best = None
    for stream in sensor_map.streams:
        t, _, _, geodetic, *_ = raw[stream.role]
        if geodetic is None:
            continue
        lat, lon, alt = geodetic
        ok = np.flatnonzero(np.isfinite(lat) & np.isfinite(lon))
        if ok.size and (best is None or t[ok[0]] < best[0]):
            k = ok[0]
            best = (t[k], (float(lat[k]), float(lon[k]), float(alt[k]) if np.isfinite(alt[k]) else 0.0))
    return None if best is None else best[1]
