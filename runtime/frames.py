"""Frames: NED and body FRD inside abyssal (Fossen), ENU and body FLU at the ROS boundary (REP-103).

abyssal's models follow Fossen: positions north-east-down (NED) about a local origin, body axes forward-right-down
(FRD), Euler angles roll-pitch-yaw in the ZYX order with yaw clockwise from north. ROS (REP-103) uses east-north-up
(ENU) and forward-left-up (FLU), yaw counter-clockwise from east. The map between the two is its own inverse:

    world vectors (position, velocity)   (n, e, d)           <->  (e, n, -d)            T = [[0,1,0],[1,0,0],[0,0,-1]]
    body vectors (velocity, rates)       (u, v, w)           <->  (u, -v, -w)           B = diag(1, -1, -1)
    Euler angles (ZYX)                   (phi, theta, psi)   <->  (phi, -theta, pi/2 - psi)

The last line because T = Rz(pi/2) Rx(pi) and B = Rx(pi), so R_ned_frd = T R_enu_flu B = Rz(pi/2 - psi) Ry(-theta)
Rx(phi) when R_enu_flu = Rz(psi) Ry(theta) Rx(phi) (exact, every angle; yaw is wrapped to (-pi, pi]). A state and
its covariance go through the map and its Jacobian J (a signed permutation): x' = J x + c, P' = J P J^T.

Latitude/longitude fixes are converted about a local origin by pymap3d (WGS-84; the replay extra), never by formulas
of our own. Quaternions go through scipy's Rotation.

    frames = StateFrames.of(model.state_names, position=("north", "east", "depth"), attitude=(None, None, "psi"))
    x_enu, P_enu = ned_to_enu(x, P, frames)
    north, east, down = geodetic_to_ned(lat, lon, alt, origin=(lat0, lon0, alt0))
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .extras import require
from .numerics import wrap_to_pi

#: ENU <-> NED for world vectors (its own inverse)
T_WORLD = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
#: FLU <-> FRD for body vectors (its own inverse)
B_BODY = np.diag([1.0, -1.0, -1.0])
#: the kinds of triples a state may hold, and the signed permutation each one goes through
KINDS = ("position", "velocity", "attitude", "body_velocity", "body_rates")

Triple = tuple  # (index or None, index or None, index or None)


@dataclass(frozen=True)
class StateFrames:
    """Where a state vector keeps what changes with the frame: each field a triple of state indices (None for a
    component the state does not have), in abyssal's order.

    position       north, east, down (m) about the local origin (ENU: east, north, up)
    velocity       the world-frame velocity: north, east, down rates
    attitude       roll, pitch, yaw (ZYX Euler angles, rad)
    body_velocity  u, v, w along the body's forward, right, down axes (FLU: forward, left, up)
    body_rates     p, q, r about the same axes

    After a conversion the same indices hold the other convention's components in the same order: position[0]
    holds east in ENU (x), position[1] north (y), position[2] up (z).
    """

    position: Triple | None = None
    velocity: Triple | None = None
    attitude: Triple | None = None
    body_velocity: Triple | None = None
    body_rates: Triple | None = None

    @classmethod
    def of(cls, state_names, **named) -> "StateFrames":
        """From state names: ``StateFrames.of(names, position=("north", "east", "depth"))``; None marks a component
        the state does not have. A name that is not a state raises ValueError naming it and the states."""
        names = list(state_names)
        fields = {}
        for kind, triple in named.items():
            if kind not in KINDS:
                raise ValueError(f"frames: {kind!r} is not one of {list(KINDS)}")
            if triple is None:
                continue
            if len(triple) != 3:
                raise ValueError(f"frames: {kind} must name 3 components (None for one the state lacks), got {triple!r}")
            indices = []
            for name in triple:
                if name is None:
                    indices.append(None)
                elif name not in names:
                    raise ValueError(f"frames: {kind} names {name!r}, which is not a state; the states: {names}")
                else:
                    indices.append(names.index(name))
            fields[kind] = tuple(indices)
        return cls(**fields)

    def jacobian(self, n: int) -> tuple[np.ndarray, np.ndarray, list[int]]:
        """(J, c, yaw): the map x' = J x + c between the conventions for an n-state vector, and the index of a yaw
        to wrap (a list of 0 or 1). ValueError when a world triple has north without east (or the reverse): the swap
        needs both."""
        J, c, yaw, seen = np.eye(n), np.zeros(n), [], set()
        for kind in KINDS:
            triple = getattr(self, kind)
            if triple is None:
                continue
            for i in triple:
                if i is None:
                    continue
                if not 0 <= i < n:
                    raise ValueError(f"frames: {kind} index {i} is outside the state (n = {n})")
                if i in seen:
                    raise ValueError(f"frames: state index {i} is named twice")
                seen.add(i)
            a, b, d = triple
            if kind in ("position", "velocity"):
                if (a is None) != (b is None):
                    raise ValueError(f"frames: {kind} has {'north' if b is None else 'east'} without "
                                     f"{'east' if b is None else 'north'}: NED <-> ENU swaps the two")
                if a is not None:
                    J[a, a] = J[b, b] = 0.0
                    J[a, b] = J[b, a] = 1.0
                if d is not None:
                    J[d, d] = -1.0
            else:  # body vectors and Euler angles: the second and third components change sign
                for i in (b, d):
                    if i is not None:
                        J[i, i] = -1.0
                if kind == "attitude" and d is not None:
                    c[d] = math.pi / 2
                    yaw.append(d)
        return J, c, yaw


def _convert(x, P, frames: StateFrames):
    x = np.asarray(x, dtype=np.float64)
    n = x.shape[-1]
    J, c, yaw = frames.jacobian(n)
    out = x @ J.T + c
    for i in yaw:
        out[..., i] = wrap_to_pi(out[..., i])
    if P is None:
        return out, None
    P = np.asarray(P, dtype=np.float64)
    if P.shape[-2:] != (n, n):
        raise ValueError(f"P must have shape (..., {n}, {n}) to match x, got {P.shape}")
    return out, J @ P @ J.T


def ned_to_enu(x, P, frames: StateFrames):
    """A state (n,) or states (K, n) in abyssal's NED/FRD and their covariances (n, n) / (K, n, n) (or None) in
    ENU/FLU (REP-103); the frames say where the position, velocities and angles are."""
    return _convert(x, P, frames)


def enu_to_ned(x, P, frames: StateFrames):
    """The inverse of ned_to_enu (the same map: it is its own inverse)."""
    return _convert(x, P, frames)


# ---------------------------------------------------------------------------------------------- world and body vectors

def enu_to_ned_vector(v):
    """A world vector (..., 3) ENU -> NED (or back)."""
    return np.asarray(v, dtype=np.float64) @ T_WORLD.T


def flu_to_frd_vector(v):
    """A body vector (..., 3) FLU -> FRD (or back)."""
    return np.asarray(v, dtype=np.float64) @ B_BODY.T


def enu_to_ned_covariance(C):
    """A world vector's covariance (..., 3, 3) ENU -> NED (or back)."""
    return T_WORLD @ np.asarray(C, dtype=np.float64) @ T_WORLD.T


def flu_to_frd_covariance(C):
    """A body vector's covariance (..., 3, 3) FLU -> FRD (or back)."""
    return B_BODY @ np.asarray(C, dtype=np.float64) @ B_BODY.T


# ---------------------------------------------------------------------------------------------- attitude

def quaternion_to_euler_ned(q_xyzw):
    """The ZYX Euler angles (roll, pitch, yaw) (..., 3) of NED/FRD from a REP-103 orientation quaternion (x, y, z, w)
    of the body's FLU axes in ENU (sensor_msgs/Imu, geometry_msgs/Pose)."""
    R_enu_flu = Rotation.from_quat(np.asarray(q_xyzw, dtype=np.float64)).as_matrix()
    R_ned_frd = T_WORLD @ R_enu_flu @ B_BODY
    yaw_pitch_roll = Rotation.from_matrix(R_ned_frd).as_euler("ZYX")
    return yaw_pitch_roll[..., ::-1]


def euler_ned_to_quaternion(euler):
    """The REP-103 orientation quaternion (x, y, z, w) of the ZYX Euler angles (roll, pitch, yaw) (..., 3) of
    NED/FRD."""
    euler = np.asarray(euler, dtype=np.float64)
    R_ned_frd = Rotation.from_euler("ZYX", euler[..., ::-1]).as_matrix()
    return Rotation.from_matrix(T_WORLD @ R_ned_frd @ B_BODY).as_quat()


def euler_rates_matrix(euler):
    """E (3, 3): the small rotation about the fixed world axes made by small changes of the ZYX Euler angles,
    delta = E d(roll, pitch, yaw) (columns Rz Ry e_x, Rz e_y, e_z). The covariance of a rotation about fixed axes (a
    ROS pose's orientation block) is E C E^T for an Euler-angle covariance C."""
    roll, pitch, yaw = (float(a) for a in euler)
    cy, sy, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    return np.array([[cy * cp, -sy, 0.0], [sy * cp, cy, 0.0], [-sp, 0.0, 1.0]])


def euler_covariance_to_rotation(euler, C):
    """The covariance of small rotations about the fixed axes (REP-103 pose covariance, rad^2) from the covariance C
    of the ZYX Euler angles euler (both in one convention)."""
    E = euler_rates_matrix(euler)
    return E @ np.asarray(C, dtype=np.float64) @ E.T


def rotation_covariance_to_euler(euler, C):
    """The covariance of the ZYX Euler angles euler from the covariance C of small rotations about the fixed axes
    (the inverse of euler_covariance_to_rotation). ValueError at pitch +-90 degrees, where E is singular."""
    E = euler_rates_matrix(euler)
    if abs(math.cos(float(euler[1]))) < 1e-9:
        raise ValueError(f"the orientation is at pitch {float(euler[1])!r} rad (+-90 degrees): its Euler angles have "
                         "no covariance there")
    E_inv = np.linalg.inv(E)
    return E_inv @ np.asarray(C, dtype=np.float64) @ E_inv.T


# ---------------------------------------------------------------------------------------------- geodesy (pymap3d)

def _pymap3d():
    return require("pymap3d", "latitude/longitude fixes about a local origin", extra="replay")


def geodetic_to_ned(latitude, longitude, altitude, origin):
    """(north, east, down) in metres of WGS-84 latitude/longitude (degrees) and altitude (m) about origin = (latitude,
    longitude, altitude) of the local NED frame (pymap3d.geodetic2ned)."""
    lat0, lon0, alt0 = origin
    n, e, d = _pymap3d().geodetic2ned(latitude, longitude, altitude, lat0, lon0, alt0)
    return np.asarray(n, dtype=np.float64), np.asarray(e, dtype=np.float64), np.asarray(d, dtype=np.float64)


def ned_to_geodetic(north, east, down, origin):
    """(latitude, longitude, altitude) of a point (north, east, down) about origin (pymap3d.ned2geodetic)."""
    lat0, lon0, alt0 = origin
    lat, lon, alt = _pymap3d().ned2geodetic(north, east, down, lat0, lon0, alt0)
    return np.asarray(lat, dtype=np.float64), np.asarray(lon, dtype=np.float64), np.asarray(alt, dtype=np.float64)
