"""Frames (runtime/frames.py): NED / FRD <-> ENU / FLU for states and covariances, against pymap3d, scipy's rotations
and finite differences, and the round trip."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from abyssal.runtime import frames

pymap3d = pytest.importorskip("pymap3d", reason="pymap3d (the replay extra) is not installed")

NAMES = ("n", "e", "d", "phi", "theta", "psi", "vn", "ve", "vd", "u", "v", "w", "p", "q", "r", "bias")
FRAMES = frames.StateFrames.of(NAMES, position=("n", "e", "d"), attitude=("phi", "theta", "psi"),
                               velocity=("vn", "ve", "vd"), body_velocity=("u", "v", "w"), body_rates=("p", "q", "r"))


def random_state(rng):
    x = rng.normal(size=len(NAMES)) * 10
    x[3:6] = [rng.uniform(-1.2, 1.2), rng.uniform(-1.2, 1.2), rng.uniform(-math.pi, math.pi)]
    A = rng.normal(size=(len(NAMES), len(NAMES)))
    return x, A @ A.T + np.eye(len(NAMES))


def test_world_vectors_equal_pymap3d_enu_and_ned():
    """Our ENU -> NED of pymap3d's geodetic2enu is pymap3d's own geodetic2ned (and geodetic_to_ned is it)."""
    rng = np.random.default_rng(0)
    lat0, lon0, alt0 = 43.01, 5.99, 3.0
    lat, lon, alt = lat0 + rng.uniform(-0.05, 0.05, 50), lon0 + rng.uniform(-0.05, 0.05, 50), rng.uniform(-600, 20, 50)
    enu = np.column_stack(pymap3d.geodetic2enu(lat, lon, alt, lat0, lon0, alt0))
    ned = np.column_stack(pymap3d.geodetic2ned(lat, lon, alt, lat0, lon0, alt0))
    assert np.abs(frames.enu_to_ned_vector(enu) - ned).max() <= 1e-9
    ours = np.column_stack(frames.geodetic_to_ned(lat, lon, alt, (lat0, lon0, alt0)))
    assert np.abs(ours - ned).max() <= 1e-9
    back = frames.ned_to_geodetic(*ours.T, (lat0, lon0, alt0))
    assert np.abs(back[0] - lat).max() <= 1e-11 and np.abs(back[1] - lon).max() <= 1e-11
    assert np.abs(back[2] - alt).max() <= 1e-6


def test_euler_angles_follow_the_rotation_matrices():
    """(phi, -theta, pi/2 - psi) is exactly R_enu_flu = T R_ned_frd B, checked with scipy's rotations; and the
    quaternion helpers invert each other."""
    rng = np.random.default_rng(1)
    for _ in range(200):
        euler = np.array([rng.uniform(-3, 3), rng.uniform(-1.5, 1.5), rng.uniform(-math.pi, math.pi)])
        R_ned_frd = Rotation.from_euler("ZYX", euler[::-1]).as_matrix()
        R_enu_flu = frames.T_WORLD @ R_ned_frd @ frames.B_BODY
        expected = Rotation.from_matrix(R_enu_flu).as_euler("ZYX")[::-1]
        x, _ = frames.ned_to_enu(np.r_[0, 0, 0, euler, np.zeros(10)], None, FRAMES)
        difference = frames.wrap_to_pi(x[3:6] - expected)
        assert np.abs(difference).max() <= 1e-12
        q = frames.euler_ned_to_quaternion(euler)
        assert np.allclose(Rotation.from_quat(q).as_matrix(), R_enu_flu, atol=1e-14)
        assert np.abs(frames.wrap_to_pi(frames.quaternion_to_euler_ned(q) - euler)).max() <= 1e-12


def test_a_state_and_its_covariance_round_trip_and_follow_the_jacobian():
    rng = np.random.default_rng(2)
    x, P = random_state(rng)
    y, Q = frames.ned_to_enu(x, P, FRAMES)
    assert y[0] == x[1] and y[1] == x[0] and y[2] == -x[2]           # position: (e, n, -d)
    assert y[9] == x[9] and y[10] == -x[10] and y[11] == -x[11]     # body velocity: (u, -v, -w)
    assert y[15] == x[15]                                            # a state of no frame stays
    back, P_back = frames.enu_to_ned(y, Q, FRAMES)
    assert np.abs(frames.wrap_to_pi(back - x)).max() <= 1e-14
    assert np.array_equal(P_back, P)
    # the covariance is J P J^T with J the map's Jacobian, here by central differences of the map itself
    J = np.empty((len(x), len(x)))
    for i in range(len(x)):
        step = np.zeros(len(x))
        step[i] = 1e-6
        plus, _ = frames.ned_to_enu(x + step, None, FRAMES)
        minus, _ = frames.ned_to_enu(x - step, None, FRAMES)
        J[:, i] = frames.wrap_to_pi(plus - minus) / 2e-6
    assert np.abs(J @ P @ J.T - Q).max() <= 1e-8 * np.abs(P).max()
    # many states at once
    X = np.stack([random_state(rng)[0] for _ in range(5)])
    Y, _ = frames.ned_to_enu(X, None, FRAMES)
    assert np.array_equal(Y[2], frames.ned_to_enu(X[2], None, FRAMES)[0])


def test_the_rotation_covariance_is_the_euler_covariance_through_the_euler_rate_matrix():
    """A small change of the Euler angles is the rotation E d(euler) about the fixed axes: E against the rotation
    vector of R(euler + d) R(euler)^T (scipy), and the two covariance maps invert each other."""
    rng = np.random.default_rng(3)
    euler = np.array([0.3, -0.4, 2.0])
    E = frames.euler_rates_matrix(euler)
    R0 = Rotation.from_euler("ZYX", euler[::-1])
    for i in range(3):
        d = np.zeros(3)
        d[i] = 1e-7
        delta = (Rotation.from_euler("ZYX", (euler + d)[::-1]) * R0.inv()).as_rotvec()
        assert np.abs(delta / 1e-7 - E[:, i]).max() <= 1e-6
    A = rng.normal(size=(3, 3))
    C = A @ A.T
    assert np.allclose(frames.rotation_covariance_to_euler(euler, frames.euler_covariance_to_rotation(euler, C)), C,
                       rtol=1e-12, atol=1e-14)
    with pytest.raises(ValueError, match="pitch"):
        frames.rotation_covariance_to_euler([0.0, math.pi / 2, 0.0], C)


def test_a_frame_layout_that_cannot_be_mapped_is_refused_naming_it():
    with pytest.raises(ValueError, match="north without east"):
        frames.StateFrames.of(NAMES, position=("n", None, "d")).jacobian(len(NAMES))
    with pytest.raises(ValueError, match="names 'north', which is not a state"):
        frames.StateFrames.of(NAMES, position=("north", "e", "d"))
    with pytest.raises(ValueError, match="named twice"):
        frames.StateFrames.of(NAMES, position=("n", "e", "d"), attitude=("d", None, None)).jacobian(len(NAMES))
    partial = frames.StateFrames.of(("x", "y", "yaw"), position=("x", "y", None), attitude=(None, None, "yaw"))
    y, _ = frames.ned_to_enu(np.array([1.0, 2.0, 0.25]), None, partial)
    assert np.allclose(y, [2.0, 1.0, math.pi / 2 - 0.25])
