"""The common ROS 2 message types as quantities in abyssal's frames (NED / body FRD; frames.py), with covariances.

A sensor map's ``fields`` for a bag topic name these quantities (or a dotted field path of the message, read as it
is: ``fluid_pressure``, ``twist.twist.linear.x``, ``position_covariance[0]``):

    sensor_msgs/msg/Imu                         roll pitch yaw (the orientation quaternion, ENU/FLU -> NED/FRD Euler)
                                                p q r (angular_velocity, FLU -> FRD), ax ay az (linear_acceleration)
    sensor_msgs/msg/FluidPressure               pressure (Pa), depth (m: (p - surface_pressure) / (density gravity))
    sensor_msgs/msg/NavSatFix                   north east down (about the local origin, pymap3d), latitude longitude
                                                altitude; a message without a fix (status < 0) is skipped and counted
    geometry_msgs/msg/TwistWithCovarianceStamped   u v w, p q r (a DVL: its frame taken as the body's FLU axes)
    geometry_msgs/msg/PoseWithCovarianceStamped    north east down (position, ENU -> NED), roll pitch yaw (a USBL fix)
    nav_msgs/msg/Odometry                       north east down roll pitch yaw u v w p q r

Covariances (``covariance = "message"`` in the map) come from the message's own fields, through the same maps'
Jacobians: positions T C T^T, body vectors B C B^T, an orientation's "rotation about the fixed X, Y, Z axes" through
the Euler-rate matrix (frames.rotation_covariance_to_euler) and the sign flips of pitch and yaw. A covariance of all
zeros, a NavSatFix position_covariance_type of 0, an Imu's -1 in its first entry or a FluidPressure variance of 0 is
"unknown" (REP-145, the messages' comments): asking for it is a LogError naming the topic and the message.
"""
from __future__ import annotations

import math
import re

import numpy as np

from .. import frames

IMU = "sensor_msgs/msg/Imu"
PRESSURE = "sensor_msgs/msg/FluidPressure"
NAVSATFIX = "sensor_msgs/msg/NavSatFix"
TWIST = "geometry_msgs/msg/TwistWithCovarianceStamped"
POSE = "geometry_msgs/msg/PoseWithCovarianceStamped"
ODOMETRY = "nav_msgs/msg/Odometry"

#: message type -> the quantities it gives, in abyssal's frames
QUANTITIES = {
    IMU: ("roll", "pitch", "yaw", "p", "q", "r", "ax", "ay", "az"),
    PRESSURE: ("pressure", "depth"),
    NAVSATFIX: ("north", "east", "down", "latitude", "longitude", "altitude"),
    TWIST: ("u", "v", "w", "p", "q", "r"),
    POSE: ("north", "east", "down", "roll", "pitch", "yaw"),
    ODOMETRY: ("north", "east", "down", "roll", "pitch", "yaw", "u", "v", "w", "p", "q", "r"),
}
#: quantities filled after the whole stream is read (they need the log's origin)
GEODETIC = ("north", "east", "down")
UNKNOWN = None


class MessageError(ValueError):
    """A message that does not hold what was asked (the caller adds the topic and the message index)."""


def xyz(v) -> np.ndarray:
    return np.array([v.x, v.y, v.z], dtype=np.float64)


def quaternion(q) -> np.ndarray:
    return np.array([q.x, q.y, q.z, q.w], dtype=np.float64)


def _square(values, size: int):
    """A covariance field as a (size, size) matrix, or UNKNOWN when it is all zeros."""
    C = np.asarray(values, dtype=np.float64).reshape(size, size)
    return UNKNOWN if not np.any(C) else C


def _attitude(q_xyzw, rotation_cov):
    """Euler angles (roll, pitch, yaw) in NED/FRD and their covariance from a REP-103 quaternion and the covariance of
    rotations about the fixed ENU axes (or UNKNOWN)."""
    if not np.all(np.isfinite(q_xyzw)) or not np.linalg.norm(q_xyzw) > 0:
        return np.full(3, np.nan), UNKNOWN
    euler = frames.quaternion_to_euler_ned(q_xyzw / np.linalg.norm(q_xyzw))
    if rotation_cov is UNKNOWN:
        return euler, UNKNOWN
    euler_enu = np.array([euler[0], -euler[1], math.pi / 2 - euler[2]])
    C_enu = frames.rotation_covariance_to_euler(euler_enu, rotation_cov)
    J = np.diag([1.0, -1.0, -1.0])  # (roll, pitch, yaw) ENU -> NED: (phi, -theta, pi/2 - psi)
    return euler, J @ C_enu @ J.T


def _block(blocks):
    """A block-diagonal covariance from blocks, or UNKNOWN blocks as NaN (asked for: an error)."""
    size = sum(n for n, _ in blocks)
    C, at = np.zeros((size, size)), 0
    for n, block in blocks:
        C[at:at + n, at:at + n] = np.nan if block is UNKNOWN else block
        at += n
    return C


def read(msgtype: str, msg, settings) -> tuple[dict, np.ndarray | None, str | None]:
    """(quantity -> value, their covariance in QUANTITIES[msgtype] order (NaN where unknown) or None, the reason to
    skip the message or None). settings: the map's [log] (water density, surface pressure, gravity)."""
    if msgtype == IMU:
        orientation_cov = msg.orientation_covariance
        has_orientation = orientation_cov[0] != -1
        euler, C_euler = _attitude(quaternion(msg.orientation), _square(orientation_cov, 3)) if has_orientation else \
            (np.full(3, np.nan), UNKNOWN)
        rates = frames.flu_to_frd_vector(xyz(msg.angular_velocity))
        accel = frames.flu_to_frd_vector(xyz(msg.linear_acceleration))
        C_rates = None if msg.angular_velocity_covariance[0] == -1 else _square(msg.angular_velocity_covariance, 3)
        C_accel = None if msg.linear_acceleration_covariance[0] == -1 else _square(msg.linear_acceleration_covariance, 3)
        values = np.concatenate([euler, rates, accel])
        C = _block([(3, C_euler), (3, None if C_rates is None else frames.flu_to_frd_covariance(C_rates)),
                    (3, None if C_accel is None else frames.flu_to_frd_covariance(C_accel))])
        return dict(zip(QUANTITIES[IMU], values)), C, None
    if msgtype == PRESSURE:
        scale = settings.water_density * settings.gravity
        depth = (msg.fluid_pressure - settings.surface_pressure) / scale
        variance = msg.variance
        C = np.full((2, 2), np.nan) if not variance > 0 else np.array([[variance, variance / scale],
                                                                     [variance / scale, variance / scale ** 2]])
        return {"pressure": float(msg.fluid_pressure), "depth": float(depth)}, C, None
    if msgtype == NAVSATFIX:
        if msg.status.status < 0:
            return {}, None, "no fix (status < 0)"
        C_enu = None if msg.position_covariance_type == 0 else _square(msg.position_covariance, 3)
        C = _block([(3, None if C_enu is None else frames.enu_to_ned_covariance(C_enu)), (3, None)])
        values = {"latitude": msg.latitude, "longitude": msg.longitude, "altitude": msg.altitude}
        return {k: float(v) for k, v in values.items()}, C, None
    if msgtype == TWIST:
        return _twist(msg.twist)
    if msgtype == POSE:
        return _pose(msg.pose)
    if msgtype == ODOMETRY:
        pose, C_pose, _ = _pose(msg.pose)
        twist, C_twist, _ = _twist(msg.twist)
        return {**pose, **twist}, _block([(6, C_pose), (6, C_twist)]), None
    return {}, None, None


def _twist(twist_with_cov):
    twist = twist_with_cov.twist
    values = np.concatenate([frames.flu_to_frd_vector(xyz(twist.linear)), frames.flu_to_frd_vector(xyz(twist.angular))])
    C6 = _square(twist_with_cov.covariance, 6)
    if C6 is not UNKNOWN:
        B = np.kron(np.eye(2), frames.B_BODY)
        C6 = B @ C6 @ B.T
    return dict(zip(QUANTITIES[TWIST], values)), _block([(6, C6)]), None


def _pose(pose_with_cov):
    pose = pose_with_cov.pose
    position = frames.enu_to_ned_vector(xyz(pose.position))
    C6 = _square(pose_with_cov.covariance, 6)
    euler, C_euler = _attitude(quaternion(pose.orientation), UNKNOWN if C6 is UNKNOWN else C6[3:, 3:])
    C = np.full((6, 6), np.nan)
    if C6 is not UNKNOWN:
        C[:3, :3] = frames.enu_to_ned_covariance(C6[:3, :3])
        C[3:, 3:] = C_euler
        # the cross terms: position (T) against the Euler angles (J E^-1 in ENU), each side through its own map
        euler_enu = np.array([euler[0], -euler[1], math.pi / 2 - euler[2]])
        M = np.diag([1.0, -1.0, -1.0]) @ np.linalg.inv(frames.euler_rates_matrix(euler_enu))
        C[:3, 3:] = frames.T_WORLD @ C6[:3, 3:] @ M.T
        C[3:, :3] = C[:3, 3:].T
    return dict(zip(QUANTITIES[POSE], np.concatenate([position, euler]))), C, None


_PART = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)(?:\[(\d+)\])?$")


def field_value(msg, path: str) -> float:
    """The number at a dotted field path of a message ("twist.twist.linear.x", "position_covariance[4]");
    MessageError naming the part that is missing and the fields that are there."""
    value = msg
    for part in path.split("."):
        match = _PART.match(part)
        if not match:
            raise MessageError(f"field {path!r}: {part!r} is not a field name (name or name[index])")
        name, index = match.group(1), match.group(2)
        if not hasattr(value, name):
            there = sorted(k for k in getattr(value, "__dataclass_fields__", {}) if not k.startswith("_"))
            raise MessageError(f"field {path!r}: {type(value).__name__.split('__')[-1]} has no field {name!r}; its "
                               f"fields: {there}")
        value = getattr(value, name)
        if index is not None:
            try:
                value = value[int(index)]
            except (IndexError, TypeError):
                raise MessageError(f"field {path!r}: {name} has no entry {index}") from None
    try:
        return float(value)
    except (TypeError, ValueError):
        raise MessageError(f"field {path!r} is not a number (it is a {type(value).__name__}); name one of its "
                           "numeric fields") from None


def time_ns(stamp) -> int:
    """A builtin_interfaces/Time as integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
