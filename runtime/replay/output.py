"""What a replay writes, all or nothing: the tidy tables, the report, the figures and, for a bag, an Odometry bag.

    OUT/track.csv          t, stamp, event, one column per state, then P_<a>_<b> for a <= b (upper triangle)
    OUT/smoothed.csv       the same columns, one row per smoothed event (--smooth)
    OUT/measurements.csv   one row per (sample, output): t, stamp, arrival, sensor, row, status, late, output, z,
                           innovation, S (its variance), nis, nis_dof
    OUT/report.md, report.json, figures/*.png
    OUT/odometry/          (a bag log) nav_msgs/msg/Odometry in ENU / FLU (REP-103), the input bag's storage

t is seconds since t0; stamp the log's own time (a bag's: seconds since the Unix epoch). Numbers are written with
Python's repr (they read back to the same float64). Everything is written into a temporary folder beside OUT and
renamed into place at the end (an earlier replay's OUT is replaced then); on any failure the temporary folder is
removed and OUT is left as it was.

Odometry: the pose is the state's position and attitude converted to ENU / FLU (frames.py), its orientation
covariance the Euler angles' through the Euler-rate matrix (rotation about the fixed axes, as nav_msgs documents);
the twist the body velocity and rates in FLU (or a world-frame velocity rotated into the body). A component the
state does not have is 0 with a variance of 1e9 (unknown).
"""
from __future__ import annotations

import csv
import os
import shutil
import tempfile
import uuid
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from .. import frames
from .bag_log import typestore
from .run import Replay, Track

#: the variance written for a component of the Odometry the state does not have
UNKNOWN_VARIANCE = 1e9


@contextmanager
def output_folder(out):
    """A temporary folder to write into; renamed to out when the block ends, removed when it raises."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: a file, not a folder")
    if out.is_dir() and any(out.iterdir()) and not (out / "report.json").is_file():
        raise ValueError(f"--out {out}: a folder with other files in it (not an earlier replay's output): give a new or "
                         "empty folder")
    out.parent.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=f".{out.name}.writing-", dir=out.parent))
    try:
        yield work
    except BaseException:
        shutil.rmtree(work, ignore_errors=True)
        raise
    if out.exists():
        old = out.parent / f".{out.name}.old-{uuid.uuid4().hex[:8]}"
        os.rename(out, old)
        os.rename(work, out)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.rename(work, out)


def _state_columns(names) -> tuple[list[str], list[tuple[int, int]]]:
    pairs = [(a, b) for a in range(len(names)) for b in range(a, len(names))]
    return list(names) + [f"P_{names[a]}_{names[b]}" for a, b in pairs], pairs


def write_track(path: Path, track: Track, names, stamp0: float) -> None:
    """A Track as a tidy CSV (module docstring); stamp0: the log time of t = 0."""
    columns, pairs = _state_columns(names)
    a, b = (np.array(i, dtype=int) for i in zip(*pairs))
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["t", "stamp", "event", *columns])
        for k in range(len(track.t)):
            t = float(track.t[k])
            values = track.x[k].tolist() + track.P[k][a, b].tolist()
            writer.writerow([repr(t), repr(stamp0 + t), track.event[k], *map(repr, values)])


def write_measurements(path: Path, replay: Replay, stamp0: float) -> None:
    names = {s["name"]: [q["name"] for q in s["outputs"]] for s in replay.model.sensors}
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["t", "stamp", "arrival", "sensor", "row", "status", "late", "output", "z", "innovation", "S",
                         "nis", "nis_dof"])
        for m in replay.measurements:
            for j, output in enumerate(names[m.sensor]):
                innovation = np.nan if m.innovation is None else m.innovation[j]
                S = np.nan if m.S is None else m.S[j, j]
                writer.writerow([repr(m.t), repr(stamp0 + m.t), repr(m.arrival), m.sensor, m.row, m.status, int(m.late),
                                 output, repr(float(m.z[j])), repr(float(innovation)), repr(float(S)), repr(float(m.nis)),
                                 m.nis_dof])


def read_track(path, names) -> Track:
    """A track.csv or smoothed.csv back into a Track (the tests' round trip, a user's notebook)."""
    with open(path, newline="") as handle:
        rows = list(csv.reader(handle))
    header, body = rows[0], rows[1:]
    columns, pairs = _state_columns(names)
    index = {name: header.index(name) for name in ["t", "event", *columns]}
    n, K = len(names), len(body)
    x, P = np.empty((K, n)), np.empty((K, n, n))
    for k, row in enumerate(body):
        x[k] = [float(row[index[name]]) for name in names]
        for (a, b), name in zip(pairs, columns[n:]):
            P[k, a, b] = P[k, b, a] = float(row[index[name]])
    return Track(np.array([float(r[index["t"]]) for r in body]), [r[index["event"]] for r in body], x, P)


# ---------------------------------------------------------------------------------------------- Odometry (REP-103)

def odometry_fields(x: np.ndarray, P: np.ndarray, state_frames: frames.StateFrames):
    """(position (3,), quaternion xyzw (4,), pose covariance (6, 6), linear (3,), angular (3,), twist covariance
    (6, 6)) in ENU / FLU of a state in NED / FRD (module docstring)."""
    x_enu, P_enu = frames.ned_to_enu(x, P, state_frames)

    def pick(triple):
        triple = triple or (None, None, None)
        values = np.array([0.0 if i is None else x_enu[i] for i in triple])
        C = np.zeros((3, 3))
        for r, i in enumerate(triple):
            for c, j in enumerate(triple):
                if i is not None and j is not None:
                    C[r, c] = P_enu[i, j]
            if i is None:
                C[r, r] = UNKNOWN_VARIANCE
        return values, C, triple

    def cross(t1, t2):
        C = np.zeros((3, 3))
        for r, i in enumerate(t1):
            for c, j in enumerate(t2):
                if i is not None and j is not None:
                    C[r, c] = P_enu[i, j]
        return C

    position, C_pos, pos_idx = pick(state_frames.position)
    euler_enu, C_euler, att_idx = pick(state_frames.attitude)
    R_enu_flu = Rotation.from_euler("ZYX", euler_enu[::-1])
    E = frames.euler_rates_matrix(euler_enu)
    known = np.array([i is not None for i in att_idx])
    C_rot = np.diag(np.where(known, 0.0, UNKNOWN_VARIANCE))
    C_known = np.where(np.outer(known, known), C_euler, 0.0)
    C_rot += E @ C_known @ E.T
    pose_cov = np.zeros((6, 6))
    pose_cov[:3, :3], pose_cov[3:, 3:] = C_pos, C_rot
    pose_cov[:3, 3:] = cross(pos_idx, att_idx) @ E.T
    pose_cov[3:, :3] = pose_cov[:3, 3:].T
    if state_frames.body_velocity is not None:
        linear, C_lin, lin_idx = pick(state_frames.body_velocity)
    elif state_frames.velocity is not None:  # a world-frame velocity, rotated into the body (attitude taken as known)
        v_world, C_world, lin_idx = pick(state_frames.velocity)
        M = R_enu_flu.as_matrix().T
        linear, C_lin = M @ v_world, M @ C_world @ M.T
        lin_idx = (None, None, None)
    else:
        linear, C_lin, lin_idx = pick(None)
    angular, C_ang, ang_idx = pick(state_frames.body_rates)
    twist_cov = np.zeros((6, 6))
    twist_cov[:3, :3], twist_cov[3:, 3:] = C_lin, C_ang
    twist_cov[:3, 3:] = cross(lin_idx, ang_idx)
    twist_cov[3:, :3] = twist_cov[:3, 3:].T
    return position, R_enu_flu.as_quat(), pose_cov, linear, angular, twist_cov


def write_odometry(folder: Path, replay: Replay) -> Path:
    """The filtered (and smoothed) track as nav_msgs/msg/Odometry into the rosbag2 folder `folder` (the input bag's
    storage); stamps are the log's nanoseconds."""
    from ..extras import require

    rosbag2 = require("rosbags.rosbag2", "writing the Odometry bag", extra="replay")
    store = typestore()
    types = store.types
    settings, log = replay.sensor_map.odometry, replay.log
    plugin = rosbag2.StoragePlugin.MCAP if log.storage == "mcap" else rosbag2.StoragePlugin.SQLITE3
    msgtype = "nav_msgs/msg/Odometry"
    Header, Time = types["std_msgs/msg/Header"], types["builtin_interfaces/msg/Time"]
    Vector3, Point, Quaternion = types["geometry_msgs/msg/Vector3"], types["geometry_msgs/msg/Point"], \
        types["geometry_msgs/msg/Quaternion"]
    Pose, Twist = types["geometry_msgs/msg/Pose"], types["geometry_msgs/msg/Twist"]
    PoseWithCovariance, TwistWithCovariance = types["geometry_msgs/msg/PoseWithCovariance"], \
        types["geometry_msgs/msg/TwistWithCovariance"]
    Odometry = types[msgtype]
    base_ns = (log.epoch_ns or 0) + int(round(replay.t0 * 1e9))
    with rosbag2.Writer(folder, version=9, storage_plugin=plugin) as writer:
        tracks = [(settings.topic, replay.track)]
        if replay.smoothed is not None:
            tracks.append((settings.topic.rstrip("/") + "/smoothed", replay.smoothed))
        for topic, track in tracks:
            connection = writer.add_connection(topic, msgtype, typestore=store)
            stamps = [base_ns + int(round(float(t) * 1e9)) for t in track.t]
            for k, ns in enumerate(stamps):
                if k + 1 < len(stamps) and stamps[k + 1] == ns:
                    continue  # one message per stamp: the state after the last event at it
                position, q, pose_cov, linear, angular, twist_cov = odometry_fields(track.x[k], track.P[k],
                                                                                    replay.sensor_map.frames)
                header = Header(stamp=Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000),
                                frame_id=settings.frame_id)
                msg = Odometry(
                    header=header, child_frame_id=settings.child_frame_id,
                    pose=PoseWithCovariance(pose=Pose(position=Point(*map(float, position)),
                                                      orientation=Quaternion(*map(float, q))),
                                            covariance=pose_cov.reshape(-1).astype(np.float64)),
                    twist=TwistWithCovariance(twist=Twist(linear=Vector3(*map(float, linear)),
                                                          angular=Vector3(*map(float, angular))),
                                              covariance=twist_cov.reshape(-1).astype(np.float64)))
                writer.write(connection, ns, store.serialize_cdr(msg, msgtype))
    return folder
