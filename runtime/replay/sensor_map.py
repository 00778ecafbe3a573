"""The sensor map (MAP.toml): which streams of a log feed which of the model's inputs and sensors, and the filter.

    [input]                          # the model's inputs u, held from each sample's stamp until the next
    table = "attitude.csv"           # a CSV log: a table of the log's folder; a bag: topic = "/imu"
    fields = ["pitch", "heading"]    # one per input, in order (CSV columns; a bag: the message's quantities below
                                     # or a dotted field path such as "twist.twist.linear.x")
    scale = [1.0, 1.0]               # optional, per field: value = scale * raw + offset (units)
    offset = [0.0, 0.0]
    # values = [0.0, 0.0]            # instead of a stream: constant inputs

    [sensors.gps]                    # one stream per sensor of the model, by its name
    table = "gps.csv"
    latitude = "lat"                 # CSV: geodetic columns that give the fields north, east, down (pymap3d)
    longitude = "lon"
    fields = ["north", "east"]
    # std = [3.0, 3.0]               # R's standard deviations (default: the model's declared noise)
    # covariance = "message"         # a bag: each message's own covariance as R (converted to NED / FRD)
    # std_columns = ["sd_n", "sd_e"] # CSV: each row's standard deviations as R
    # parameters = ["bx", "by"]      # fields giving the sensor's own parameters with each measurement
    # arrival = "t_rx"               # CSV: when the measurement reached the vehicle (default: its stamp)

    [filter]
    x0 = [0.0, 0.0, 0.0, 0.3, 0.0, 0.0]
    P0_std = [5.0, 5.0, 1.0, 0.2, 0.1, 0.1]   # or P0 = [[...]]: a covariance
    Q_std = [0.01, 0.001, 0.001, 0.1]         # or Q = [[...]]; per the noise convention below
    noise = "inputs"                          # "step" | "rate" | "inputs": the Kalman filters' noise option
    t0 = 1201598698.5                         # the log time x0 holds at (default: the first stamp of a stream)
    history_seconds = 2.0                     # the fixed lag for late measurements (--smooth keeps the whole log)
    parameters = { aoa = 0.0 }                # the model's parameters by name (default: its defaults)
    particles = 1000                          # --filter pf: particles, its clock dt (s), its seed
    dt = 1.0
    seed = 0

    [log]
    origin = [43.0105, 5.9927, 0.0]           # latitude, longitude (deg), altitude (m) of the local NED origin
                                              # (default: the first fix of the log)
    stamp = "header"                          # a bag: a message's time is its header.stamp, or "log" (record time)
    water_density = 1025.0                    # FluidPressure -> depth: (p - surface_pressure) / (density gravity)
    surface_pressure = 101325.0
    gravity = 9.80665

    [frames]                                  # where the state keeps what changes frame (abyssal's NED / FRD)
    position = ["north", "east", "depth"]     # state names; "" for a component the state does not have
    attitude = ["", "", ""]                   # roll, pitch, yaw; also velocity (NED rates), body_velocity, body_rates
    fixes = ["gps"]                           # sensors whose first two outputs are north and east (on the track)

    [odometry]                                # a bag: the nav_msgs/Odometry bag written beside the input (REP-103)
    topic = "/abyssal/odometry"
    frame_id = "map"
    child_frame_id = "base_link"

Every table and key is checked against the model when the map is loaded: an unknown key (a typo), a sensor the model
does not have, a field count that is not the sensor's output count, a vector of the wrong length -- each is a
ValueError naming the map file, the table and the key.
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field

import numpy as np

from ..frames import KINDS as FRAME_KINDS
from ..frames import StateFrames

NOISE_KINDS = ("step", "rate", "inputs")
STAMP_KINDS = ("header", "log")
STREAM_KEYS = {"table", "topic", "time", "arrival", "fields", "scale", "offset", "std", "covariance", "std_columns",
               "parameters", "latitude", "longitude", "altitude"}
INPUT_KEYS = {"table", "topic", "time", "fields", "scale", "offset", "values"}
FILTER_KEYS = {"x0", "P0", "P0_std", "Q", "Q_std", "noise", "t0", "history_seconds", "history_entries",
               "gate_probability", "parameters", "particles", "dt", "seed", "alpha", "beta", "kappa"}
LOG_KEYS = {"origin", "stamp", "water_density", "surface_pressure", "gravity"}
FRAMES_KEYS = set(FRAME_KINDS) | {"fixes"}
ODOMETRY_KEYS = {"topic", "frame_id", "child_frame_id"}
TOP_KEYS = {"input", "sensors", "filter", "log", "frames", "odometry"}


@dataclass(frozen=True)
class Stream:
    """One mapped stream: the input or one sensor, read from a CSV table or a bag topic."""

    role: str                                  # "input" or the sensor's name
    table: str | None                          # CSV: the table's file name in the log folder
    topic: str | None                          # a bag: the topic
    fields: tuple[str, ...]
    scale: np.ndarray
    offset: np.ndarray
    time: str = "t"                            # CSV: the time column
    arrival: str | None = None                 # CSV: the arrival column (None: the stamp)
    covariance: str = "model"                  # "model" (the filter's R), "message" (a bag's), "columns" (CSV)
    std: tuple[float, ...] | None = None       # the map's own R (standard deviations)
    std_columns: tuple[str, ...] = ()
    parameters: tuple[str, ...] = ()           # fields giving the sensor's own parameters per measurement
    geodetic: tuple[str, str, str | None] | None = None   # CSV: latitude, longitude, altitude columns

    @property
    def source(self) -> str:
        """How messages name it: "table depth.csv" or "topic '/depth'"."""
        return f"table {self.table}" if self.table is not None else f"topic {self.topic!r}"


@dataclass(frozen=True)
class FilterSettings:
    x0: np.ndarray
    P0: np.ndarray
    Q: np.ndarray
    noise: str = "step"
    t0: float | None = None
    history_seconds: float = 2.0
    history_entries: int = 1024
    gate_probability: float = 1e-10
    parameters: dict = field(default_factory=dict)
    particles: int = 1000
    dt: float | None = None
    seed: int = 0
    sigma_points: dict = field(default_factory=dict)   # UKF alpha, beta, kappa


@dataclass(frozen=True)
class LogSettings:
    origin: tuple[float, float, float] | None = None
    stamp: str = "header"
    water_density: float = 1025.0
    surface_pressure: float = 101325.0
    gravity: float = 9.80665


@dataclass(frozen=True)
class OdometrySettings:
    topic: str = "/abyssal/odometry"
    frame_id: str = "map"
    child_frame_id: str = "base_link"


@dataclass(frozen=True)
class SensorMap:
    """A checked sensor map (module docstring)."""

    path: str                                   # where it came from (for messages)
    input: Stream | None
    input_values: np.ndarray | None             # constant inputs (no input stream)
    sensors: dict                               # sensor name -> Stream, in the model's sensor order
    filter: FilterSettings
    log: LogSettings
    frames: StateFrames
    frame_names: dict                           # kind -> the state names given (for reports)
    fixes: tuple[str, ...]
    odometry: OdometrySettings

    @property
    def streams(self) -> list[Stream]:
        return ([self.input] if self.input is not None else []) + list(self.sensors.values())

    def R_block(self, model, sensor: str) -> np.ndarray:
        """The sensor's R for the filter: the map's std, else the model's declared noise, else ValueError."""
        spec = model.sensor(sensor)
        stream = self.sensors.get(sensor)
        if stream is not None and stream.std is not None:
            return np.diag(np.square(stream.std))
        if spec.get("noise") is not None:
            return np.array(spec["noise"], dtype=np.float64)
        if stream is not None and stream.covariance != "model":
            return np.eye(len(spec["outputs"]))  # every measurement brings its own; this block is never used
        raise ValueError(f"{self.path}: sensor {sensor!r} declares no noise in model {model.name!r}: give "
                         f"[sensors.{sensor}] std = [...] (one standard deviation per output)")


class MapError(ValueError):
    """A sensor map that cannot be used; the message names the file, the table and the key."""


def load_sensor_map(source, model) -> SensorMap:
    """The map from a TOML file (path) or an already parsed dict, checked against the model (a loaded bundle)."""
    if isinstance(source, dict):
        path, data = "<sensor map>", source
    else:
        path = str(source)
        try:
            with open(source, "rb") as handle:
                data = tomllib.load(handle)
        except FileNotFoundError:
            raise MapError(f"--sensors {path}: no such file") from None
        except tomllib.TOMLDecodeError as exc:
            raise MapError(f"{path}: not valid TOML: {exc}") from None
    return _Checker(path, model).sensor_map(data)


class _Checker:
    def __init__(self, path: str, model):
        self.path, self.model = path, model

    def fail(self, where: str, message: str):
        raise MapError(f"{self.path}: {where}: {message}")

    def keys(self, table: dict, allowed: set, where: str) -> None:
        if not isinstance(table, dict):
            self.fail(where, f"must be a table, got {table!r}")
        unknown = sorted(set(table) - allowed)
        if unknown:
            self.fail(where, f"unknown key(s) {unknown}; the keys it takes: {sorted(allowed)}")

    def numbers(self, value, where: str, length: int | None = None, positive: bool = False) -> np.ndarray:
        try:
            array = np.array(value, dtype=np.float64)
        except (TypeError, ValueError):
            self.fail(where, f"must be numbers, got {value!r}")
        if array.ndim != 1 or (length is not None and array.size != length):
            self.fail(where, f"must be a list of {length} numbers, got {value!r}")
        if not np.all(np.isfinite(array)) or (positive and not np.all(array > 0)):
            self.fail(where, f"must be {'positive ' if positive else ''}finite numbers, got {value!r}")
        return array

    def strings(self, value, where: str, length: int | None = None) -> tuple[str, ...]:
        if isinstance(value, str) or not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
            self.fail(where, f"must be a list of strings, got {value!r}")
        if length is not None and len(value) != length:
            self.fail(where, f"must name {length}, got {len(value)}: {list(value)}")
        return tuple(value)

    def number(self, value, where: str, low: float = -math.inf, high: float = math.inf, integer: bool = False):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or (integer and not isinstance(value, int)):
            self.fail(where, f"must be {'an integer' if integer else 'a number'}, got {value!r}")
        if not (low <= value <= high) or not math.isfinite(value):
            self.fail(where, f"must be in [{low}, {high}], got {value!r}")
        return value

    def covariance(self, table: dict, name: str, n: int, where: str) -> np.ndarray:
        given = [k for k in (name, f"{name}_std") if k in table]
        if len(given) != 1:
            self.fail(where, f"give exactly one of {name} (a covariance, a list of {n} rows) or {name}_std (a list of "
                             f"{n} standard deviations)")
        if given[0].endswith("_std"):
            std = self.numbers(table[given[0]], f"{where} {given[0]}", n)
            if np.any(std < 0):
                self.fail(f"{where} {given[0]}", f"standard deviations must be >= 0, got {table[given[0]]!r}")
            return np.diag(np.square(std))
        try:
            C = np.array(table[name], dtype=np.float64)
        except (TypeError, ValueError):
            self.fail(f"{where} {name}", f"must be a list of {n} rows of {n} numbers")
        if C.shape != (n, n) or not np.all(np.isfinite(C)):
            self.fail(f"{where} {name}", f"must be a finite ({n}, {n}) covariance, got shape {C.shape}")
        return C

    # ------------------------------------------------------------------------------------------ the tables
    def sensor_map(self, data: dict) -> SensorMap:
        self.keys(data, TOP_KEYS, "the map")
        model = self.model
        input_stream, input_values = self.input(data.get("input"))
        sensors_table = data.get("sensors", {})
        self.keys(sensors_table, set(model.sensor_names), "[sensors]")
        if not sensors_table:
            self.fail("[sensors]", f"maps no sensor; model {model.name!r} has {list(model.sensor_names)}")
        sensors = {name: self.sensor(name, sensors_table[name]) for name in model.sensor_names if name in sensors_table}
        filter_settings = self.filter(data.get("filter"))
        log = self.log(data.get("log", {}))
        frames, frame_names, fixes = self.frames(data.get("frames", {}), sensors)
        odometry = data.get("odometry", {})
        self.keys(odometry, ODOMETRY_KEYS, "[odometry]")
        for key, value in odometry.items():
            if not isinstance(value, str) or not value:
                self.fail(f"[odometry] {key}", f"must be a non-empty string, got {value!r}")
        return SensorMap(self.path, input_stream, input_values, sensors, filter_settings, log, frames, frame_names,
                         fixes, OdometrySettings(**odometry))

    def source(self, table: dict, where: str) -> tuple[str | None, str | None]:
        has_table, has_topic = "table" in table, "topic" in table
        if has_table == has_topic:
            self.fail(where, "give exactly one of table (a CSV log's table) or topic (a bag's topic)")
        value = table["table" if has_table else "topic"]
        if not isinstance(value, str) or not value:
            self.fail(f"{where} {'table' if has_table else 'topic'}", f"must be a non-empty string, got {value!r}")
        return (value, None) if has_table else (None, value)

    def scaled(self, table: dict, where: str, count: int) -> tuple[np.ndarray, np.ndarray]:
        scale = self.numbers(table.get("scale", [1.0] * count), f"{where} scale", count)
        offset = self.numbers(table.get("offset", [0.0] * count), f"{where} offset", count)
        return scale, offset

    def input(self, table) -> tuple[Stream | None, np.ndarray | None]:
        model = self.model
        if table is None:
            if model.n_u:
                self.fail("[input]", f"model {model.name!r} has inputs {list(model.input_names)}: map a stream ([input] "
                                     "table/topic and fields) or give constant values ([input] values = [...])")
            return None, np.zeros(0)
        self.keys(table, INPUT_KEYS, "[input]")
        if "values" in table:
            if set(table) - {"values"}:
                self.fail("[input]", "values (constant inputs) replaces a stream: give values alone")
            return None, self.numbers(table["values"], "[input] values", model.n_u)
        if model.n_u == 0:
            self.fail("[input]", f"model {model.name!r} has no inputs")
        csv_table, topic = self.source(table, "[input]")
        fields = self.strings(table.get("fields"), "[input] fields", model.n_u)
        scale, offset = self.scaled(table, "[input]", model.n_u)
        time = table.get("time", "t")
        if not isinstance(time, str):
            self.fail("[input] time", f"must be a column name, got {time!r}")
        return Stream("input", csv_table, topic, fields, scale, offset, time=time), None

    def sensor(self, name: str, table) -> Stream:
        where = f"[sensors.{name}]"
        self.keys(table, STREAM_KEYS, where)
        spec = self.model.sensor(name)
        outputs = [q["name"] for q in spec["outputs"]]
        csv_table, topic = self.source(table, where)
        if "fields" not in table:
            self.fail(where, f"fields is missing: one per output of sensor {name!r}: {outputs}")
        fields = self.strings(table["fields"], f"{where} fields", len(outputs))
        scale, offset = self.scaled(table, where, len(outputs))
        options = {k: table[k] for k in ("time", "arrival") if k in table}
        for key, value in options.items():
            if not isinstance(value, str):
                self.fail(f"{where} {key}", f"must be a column name, got {value!r}")
        if topic is not None and options:
            self.fail(where, f"{sorted(options)}: CSV tables only (a bag's messages carry their stamps)")
        std = None
        if "std" in table:
            std = tuple(self.numbers(table["std"], f"{where} std", len(outputs), positive=True).tolist())
        covariance = "model"
        if "covariance" in table:
            if table["covariance"] not in ("model", "message"):
                self.fail(f"{where} covariance", f"must be \"message\" (each message's own) or \"model\", got "
                                                 f"{table['covariance']!r}")
            covariance = table["covariance"]
            if covariance == "message" and topic is None:
                self.fail(f"{where} covariance", "\"message\" needs a bag topic; a CSV table gives std_columns")
        std_columns = ()
        if "std_columns" in table:
            if topic is not None:
                self.fail(f"{where} std_columns", "CSV tables only (a bag gives covariance = \"message\")")
            std_columns = self.strings(table["std_columns"], f"{where} std_columns", len(outputs))
            covariance = "columns"
        own = [q["name"] for q in spec["parameters"]]
        parameters = ()
        if "parameters" in table:
            parameters = self.strings(table["parameters"], f"{where} parameters", len(own))
        geodetic = None
        if "latitude" in table or "longitude" in table:
            if topic is not None:
                self.fail(where, "latitude/longitude: CSV tables only (a bag's NavSatFix gives north, east, down)")
            if "latitude" not in table or "longitude" not in table:
                self.fail(where, "give both latitude and longitude (column names)")
            geodetic = (table["latitude"], table["longitude"], table.get("altitude"))
            if not all(isinstance(c, str) for c in geodetic if c is not None):
                self.fail(where, f"latitude, longitude, altitude must be column names, got {geodetic!r}")
        elif "altitude" in table:
            self.fail(where, "altitude needs latitude and longitude")
        return Stream(name, csv_table, topic, fields, scale, offset, covariance=covariance, std=std,
                      std_columns=std_columns, parameters=parameters, geodetic=geodetic, **options)

    def filter(self, table) -> FilterSettings:
        model, n = self.model, self.model.n_x
        if table is None:
            self.fail("[filter]", f"is missing: x0 ({n} numbers: {list(model.state_names)}), P0 or P0_std, Q or Q_std")
        self.keys(table, FILTER_KEYS, "[filter]")
        if "x0" not in table:
            self.fail("[filter]", f"x0 is missing ({n} numbers: {list(model.state_names)})")
        x0 = self.numbers(table["x0"], "[filter] x0", n)
        P0 = self.covariance(table, "P0", n, "[filter]")
        noise = table.get("noise", "step")
        if noise not in NOISE_KINDS:
            self.fail("[filter] noise", f"must be one of {list(NOISE_KINDS)}, got {noise!r}")
        q = model.n_w if noise == "inputs" else n
        Q = self.covariance(table, "Q", q, "[filter]")
        t0 = None if "t0" not in table else float(self.number(table["t0"], "[filter] t0"))
        options = {}
        if "history_seconds" in table:
            options["history_seconds"] = float(self.number(table["history_seconds"], "[filter] history_seconds", 0.0))
        if "history_entries" in table:
            options["history_entries"] = self.number(table["history_entries"], "[filter] history_entries", 0, 1 << 24,
                                                     integer=True)
        if "gate_probability" in table:
            options["gate_probability"] = float(self.number(table["gate_probability"], "[filter] gate_probability",
                                                            0.0, 1.0))
        parameters = table.get("parameters", {})
        self.keys(parameters, set(model.parameter_names), "[filter.parameters]")
        for key, value in parameters.items():
            self.number(value, f"[filter.parameters] {key}")
        if "particles" in table:
            options["particles"] = self.number(table["particles"], "[filter] particles", 1, 10 ** 8, integer=True)
        if "dt" in table:
            options["dt"] = float(self.number(table["dt"], "[filter] dt", 0.0))
            if options["dt"] <= 0:
                self.fail("[filter] dt", f"must be positive, got {table['dt']!r}")
        if "seed" in table:
            options["seed"] = self.number(table["seed"], "[filter] seed", 0, 2 ** 63, integer=True)
        sigma_points = {k: float(self.number(table[k], f"[filter] {k}")) for k in ("alpha", "beta", "kappa") if k in table}
        return FilterSettings(x0=x0, P0=P0, Q=Q, noise=noise, t0=t0, parameters=dict(parameters),
                              sigma_points=sigma_points, **options)

    def log(self, table) -> LogSettings:
        self.keys(table, LOG_KEYS, "[log]")
        values = {}
        if "origin" in table:
            origin = self.numbers(table["origin"], "[log] origin", 3)
            if not (-90 <= origin[0] <= 90 and -180 <= origin[1] <= 360):
                self.fail("[log] origin", f"must be [latitude, longitude, altitude] in degrees and metres, got "
                                          f"{table['origin']!r}")
            values["origin"] = tuple(origin.tolist())
        if "stamp" in table:
            if table["stamp"] not in STAMP_KINDS:
                self.fail("[log] stamp", f"must be one of {list(STAMP_KINDS)}, got {table['stamp']!r}")
            values["stamp"] = table["stamp"]
        for key in ("water_density", "surface_pressure", "gravity"):
            if key in table:
                values[key] = float(self.number(table[key], f"[log] {key}", 0.0))
        if values.get("water_density") == 0 or values.get("gravity") == 0:
            self.fail("[log]", "water_density and gravity must be positive")
        return LogSettings(**values)

    def frames(self, table, sensors: dict) -> tuple[StateFrames, dict, tuple[str, ...]]:
        self.keys(table, FRAMES_KEYS, "[frames]")
        named = {}
        for kind in FRAME_KINDS:
            if kind in table:
                names = self.strings(table[kind], f"[frames] {kind}", 3)
                named[kind] = tuple(name or None for name in names)
        try:
            frames = StateFrames.of(self.model.state_names, **named)
            frames.jacobian(self.model.n_x)
        except ValueError as exc:
            self.fail("[frames]", str(exc))
        fixes = self.strings(table.get("fixes", []), "[frames] fixes")
        for name in fixes:
            if name not in sensors:
                self.fail("[frames] fixes", f"{name!r} is not a mapped sensor ({list(sensors)})")
            if len(self.model.sensor(name)["outputs"]) < 2:
                self.fail("[frames] fixes", f"sensor {name!r} has fewer than two outputs (north, east)")
        if fixes and (frames.position is None or frames.position[0] is None):
            self.fail("[frames] fixes", "needs [frames] position (north, east) to draw the fixes on the track")
        return frames, named, fixes
