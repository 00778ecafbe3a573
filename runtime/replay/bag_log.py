"""A rosbag2 log (sqlite3 or MCAP, a bag folder or a bare .mcap file), read by rosbags without a ROS installation.

Each mapped topic's messages become the samples of its streams (one topic may feed the input and a sensor): their
time is the header's stamp ([log] stamp = "header", the default) or the bag's record time ("log"), their arrival
the record time, their values the fields the map names (messages.py: the quantities of the common types, or
dotted field paths). Message types come from the bag's own definitions, else from ROS 2 Humble's. A bag rosbags
cannot open, a topic the bag does not have, a field a message does not have: a LogError naming the bag, the topic,
the message (its index on the topic, from 0) and the field.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..extras import require
from ..frames import geodetic_to_ned
from . import messages
from .log import Log, LogError, check_covariances, checked_samples
from .progress import progress_bar
from .sensor_map import SensorMap, Stream


def typestore():
    """ROS 2 Humble's message types (for bags that do not carry their definitions, and for writing)."""
    typesys = require("rosbags.typesys", "reading and writing bags", extra="replay")
    return typesys.get_typestore(typesys.Stores.ROS2_HUMBLE)


def storage_of(path: Path) -> str:
    """"mcap" or "sqlite3": the storage of the bag at path (its files' suffixes)."""
    files = [path] if path.is_file() else list(path.iterdir())
    return "mcap" if any(f.suffix == ".mcap" for f in files) else "sqlite3"


def is_bag(path: Path) -> bool:
    return (path.is_dir() and (path / "metadata.yaml").is_file()) or (path.is_file() and path.suffix in (".mcap", ".db3"))


class _Collected:
    """A stream's samples while the bag is read."""

    def __init__(self, stream: Stream):
        self.stream = stream
        self.t, self.arrival, self.values, self.cov, self.params, self.rows = [], [], [], [], [], []
        self.skipped: dict[str, int] = {}
        self.latlon: list[tuple[float, float, float]] = []   # a NavSatFix's latitude, longitude, altitude per sample


def read_bag_log(path: Path, sensor_map: SensorMap, progress: bool = True) -> Log:
    """The mapped streams of a bag (module docstring), with a progress bar over a long one."""
    highlevel = require("rosbags.highlevel", "reading bags", extra="replay")
    path = Path(path)
    by_topic: dict[str, list[_Collected]] = {}
    for stream in sensor_map.streams:
        if stream.topic is None:
            role = "input" if stream.role == "input" else f"sensors.{stream.role}"
            raise LogError(f"{path}: a bag has topics, not tables (the map's [{role}] needs topic = \"/NAME\")")
        by_topic.setdefault(stream.topic, []).append(_Collected(stream))
    settings = sensor_map.log
    try:
        reader = highlevel.AnyReader([path], default_typestore=typestore())
        reader.open()
    except Exception as exc:  # noqa: BLE001 -- rosbags raises its own errors, and OSError/KeyError on a damaged file
        raise LogError(f"{path}: not a readable rosbag2 or MCAP bag ({type(exc).__name__}: {exc})") from None
    try:
        topics = {c.topic: c.msgtype for c in reader.connections}
        for topic, collected in by_topic.items():
            if topic not in topics:
                roles = ", ".join("the input" if c.stream.role == "input" else f"sensor {c.stream.role!r}" for c in collected)
                raise LogError(f"{path}: topic {topic!r} (mapped to {roles}) is not in the bag; its topics: "
                               f"{ {t: m for t, m in sorted(topics.items())} }")
        connections = [c for c in reader.connections if c.topic in by_topic]
        counts = {topic: 0 for topic in by_topic}
        bar = progress_bar(sum(c.msgcount for c in connections), progress, f"read {path.name}", unit="message")
        try:
            for connection, record_ns, raw in reader.messages(connections=connections):
                topic = connection.topic
                index = counts[topic]
                counts[topic] += 1
                where = f"{path}: topic {topic!r} ({connection.msgtype}), message {index}"
                try:
                    msg = reader.deserialize(raw, connection.msgtype)
                except Exception as exc:  # noqa: BLE001 -- a damaged message
                    raise LogError(f"{where}: cannot be decoded ({type(exc).__name__}: {exc})") from None
                _collect(by_topic[topic], connection.msgtype, msg, int(record_ns), index, settings, where)
                if bar is not None:
                    bar.update(1)
        except LogError:
            raise
        except Exception as exc:  # noqa: BLE001 -- a damaged chunk or index inside the file
            raise LogError(f"{path}: the bag is damaged: reading its messages failed ({type(exc).__name__}: {exc})") \
                from None
        finally:
            if bar is not None:
                bar.close()
    finally:
        reader.close()
    return _finish(path, by_topic, sensor_map)


def _collect(collected: list[_Collected], msgtype: str, msg, record_ns: int, index: int, settings, where: str) -> None:
    quantities, covariance, skip = messages.read(msgtype, msg, settings)
    names = messages.QUANTITIES.get(msgtype, ())
    for c in collected:
        stream = c.stream
        if skip is not None:
            c.skipped[skip] = c.skipped.get(skip, 0) + 1
            continue
        if settings.stamp == "header":
            header = getattr(msg, "header", None)
            if header is None:
                raise LogError(f"{where}: a {msgtype} has no header stamp: set [log] stamp = \"log\" (the bag's record "
                               "time)")
            stamp = messages.time_ns(header.stamp)
        else:
            stamp = record_ns
        values = []
        if msgtype == messages.NAVSATFIX and any(name in messages.GEODETIC for name in stream.fields):
            c.latlon.append((quantities["latitude"], quantities["longitude"], quantities["altitude"]))
        for name in stream.fields:
            if name in names:
                values.append(quantities.get(name, np.nan))  # north, east, down: filled once the origin is known
            else:
                try:
                    values.append(messages.field_value(msg, name))
                except messages.MessageError as exc:
                    known = f" (or one of its quantities {list(names)})" if names else ""
                    raise LogError(f"{where}: {exc}{known}") from None
        if stream.covariance == "message":
            if covariance is None or any(name not in names for name in stream.fields):
                raise LogError(f"{where}: covariance = \"message\" for fields {list(stream.fields)}: a {msgtype} gives a "
                               f"covariance only for its quantities {list(names) or '(none)'}")
            chosen = [names.index(name) for name in stream.fields]
            block = covariance[np.ix_(chosen, chosen)]
            if np.isnan(block).any():
                raise LogError(f"{where}: its covariance of {list(stream.fields)} is unknown (all zeros, or flagged "
                               "unknown by the message): use std in the map instead")
            c.cov.append(block)
        params = []
        for name in stream.parameters:
            try:
                params.append(messages.field_value(msg, name))
            except messages.MessageError as exc:
                raise LogError(f"{where}: parameter {exc}") from None
        c.t.append(stamp)
        c.arrival.append(record_ns)
        c.values.append(values)
        c.params.append(params)
        c.rows.append(index)


def _finish(path: Path, by_topic: dict, sensor_map: SensorMap) -> Log:
    every = [c for group in by_topic.values() for c in group]
    stamps = [v for c in every for v in (c.t[:1] + c.arrival[:1])]
    epoch_ns = min(stamps) if stamps else 0
    origin = sensor_map.log.origin
    if origin is None:  # the first fix of the log
        first = None
        for c in every:
            for stamp, (lat, lon, alt) in zip(c.t, c.latlon):
                if np.isfinite(lat) and np.isfinite(lon) and (first is None or stamp < first[0]):
                    first = (stamp, (float(lat), float(lon), float(alt) if np.isfinite(alt) else 0.0))
        origin = None if first is None else first[1]
    log = Log(path, "bag", {}, epoch=epoch_ns * 1e-9, epoch_ns=epoch_ns, storage=storage_of(path), origin=origin,
              row_word="message")
    for c in every:
        stream, K, m = c.stream, len(c.t), len(c.stream.fields)
        values = np.array(c.values, dtype=np.float64).reshape(K, m)
        if c.latlon:
            lat, lon, alt = np.array(c.latlon, dtype=np.float64).T
            derived = dict(zip(messages.GEODETIC, geodetic_to_ned(lat, lon, np.nan_to_num(alt), origin)))
            for j, name in enumerate(stream.fields):
                if name in derived:
                    values[:, j] = derived[name]
        t = (np.array(c.t, dtype=np.int64) - epoch_ns) * 1e-9
        arrival = (np.array(c.arrival, dtype=np.int64) - epoch_ns) * 1e-9
        R = np.array(c.cov).reshape(K, m, m) if stream.covariance == "message" else None
        params = np.array(c.params, dtype=np.float64).reshape(K, len(stream.parameters)) if stream.parameters else None
        samples = checked_samples(stream, t, arrival, values, np.array(c.rows, dtype=np.int64), "message", R=R,
                                  params=params, skipped=c.skipped)
        check_covariances(samples, "message")
        log.samples[stream.role] = samples
    return log
