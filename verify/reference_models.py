"""Independent NumPy implementations of the registered models: the oracle of `abyssal verify`.

Written from the papers and Fossen's textbook, not from the CasADi equations (nothing here
imports CasADi or abyssal.symbolic), so a sign or index error on either side shows up as a
disagreement. Each model takes the parameter vector in the manifest's order
(``bundle.parameter_names``) and works on one state (n,) or on a batch of columns (n, N):
every function indexes rows (``x[3]``) and stacks rows, so NumPy broadcasting vectorises it.

    REFERENCES[name].xdot(x, u, p, w=None)  continuous dynamics
    REFERENCES[name].h(x, p)                measurement
    step(ref, x, u, p, dt, discretisation, substeps, w=None)   Euler / RK4, inputs held over dt
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np


def _stack(rows, like=0.0) -> np.ndarray:
    """Rows (scalars or (N,) arrays) -> (n,) or (n, N); `like` (a row of the state) sets N when
    no row depends on the state."""
    return np.stack(np.broadcast_arrays(*rows, like)[:-1], axis=0)


def _noise(w, n_w: int):
    return np.zeros(n_w) if w is None else np.asarray(w, dtype=float)


# --------------------------------------------------------------------------- rov4dof
# Seed 000 (Wang et al. 2023), 4-DOF ROV with Fossen's conventions; see the docstring of
# symbolic/models/rov4dof.py for the departures from the printed matrices.
ROV4DOF_PARAMETERS = ("m", "I_z", "X_udot", "Y_vdot", "Z_wdot", "N_rdot", "X_u", "Y_v", "Z_w", "N_r",
                      "X_uu", "Y_vv", "Z_ww", "N_rr", "W", "B", "T_b")


def rov4dof_xdot(x, u, p, w=None):
    """[eta_dot; nu_dot; b_dot] of the 12-state ROV (eqs. 5-15 of seed 000, Fossen signs)."""
    prm = dict(zip(ROV4DOF_PARAMETERS, p))
    w = _noise(w, 8)
    psi, vel_u, vel_v, vel_w, vel_r = x[3], x[4], x[5], x[6], x[7]
    b_x, b_y, b_z, b_psi = x[8], x[9], x[10], x[11]
    c, s = np.cos(psi), np.sin(psi)

    # M = M_RB + M_A with M_A = -diag(X_udot, Y_vdot, Z_wdot, N_rdot)           (eq. 6)
    m11 = prm["m"] - prm["X_udot"]
    m22 = prm["m"] - prm["Y_vdot"]
    m33 = prm["m"] - prm["Z_wdot"]
    m44 = prm["I_z"] - prm["N_rdot"]

    # C(nu) nu of a diagonal M, written out (Fossen eq. 6.43 with p = q = 0):
    # surge -m22 v r, sway m11 u r, heave 0, yaw (m22 - m11) u v (the Munk moment).
    cor_u = -m22 * vel_v * vel_r
    cor_v = m11 * vel_u * vel_r
    cor_w = 0.0
    cor_r = (m22 - m11) * vel_u * vel_v

    # D(nu) nu = -(X_u + X_|u|u |u|) u ...                                        (eqs. 8-9)
    damp_u = -(prm["X_u"] + prm["X_uu"] * np.abs(vel_u)) * vel_u
    damp_v = -(prm["Y_v"] + prm["Y_vv"] * np.abs(vel_v)) * vel_v
    damp_w = -(prm["Z_w"] + prm["Z_ww"] * np.abs(vel_w)) * vel_w
    damp_r = -(prm["N_r"] + prm["N_rr"] * np.abs(vel_r)) * vel_r

    # g(eta) at phi = theta = 0: only heave, -(W - B)                              (eq. 10)
    restoring_w = -(prm["W"] - prm["B"])

    # Earth-frame bias into the body frame: R(psi)^T b                            (eq. 15)
    bias_u = c * b_x + s * b_y
    bias_v = -s * b_x + c * b_y

    forces = (
        u[0] - cor_u - damp_u + bias_u + w[0],
        u[1] - cor_v - damp_v + bias_v + w[1],
        u[2] - cor_w - damp_w - restoring_w + b_z + w[2],
        u[3] - cor_r - damp_r + b_psi + w[3],
    )
    return _stack([
        c * vel_u - s * vel_v,          # eta_dot = R(psi) nu                         (eq. 12)
        s * vel_u + c * vel_v,
        vel_w,
        vel_r,
        forces[0] / m11,
        forces[1] / m22,
        forces[2] / m33,
        forces[3] / m44,
        -b_x / prm["T_b"] + w[4],       # first-order Gauss-Markov bias               (eq. 11)
        -b_y / prm["T_b"] + w[5],
        -b_z / prm["T_b"] + w[6],
        -b_psi / prm["T_b"] + w[7],
    ])


def rov4dof_h(x, p):
    """Position fix, depth and compass: H = [I_4 0] (eq. 16)."""
    return _stack([x[0], x[1], x[2], x[3]])


def rov4dof_state(rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """A plausible state of the ROV cleaning a chain: metres, < 1 m/s, tens of newtons of bias."""
    shape = (n,) if n else ()
    return _stack([
        rng.uniform(-50, 50, shape), rng.uniform(-50, 50, shape), rng.uniform(0, 30, shape),
        rng.uniform(-np.pi, np.pi, shape),
        rng.normal(0, 0.5, shape), rng.normal(0, 0.3, shape), rng.normal(0, 0.2, shape), rng.normal(0, 0.3, shape),
        rng.normal(0, 10, shape), rng.normal(0, 10, shape), rng.normal(0, 5, shape), rng.normal(0, 1, shape),
    ])


def rov4dof_input(rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    shape = (n,) if n else ()
    return _stack([rng.normal(0, 30, shape), rng.normal(0, 20, shape), rng.normal(0, 20, shape), rng.normal(0, 2, shape)])


#: Surging ahead at 0.5 m/s while crabbing, sinking and turning: u, v, w, r stay positive for > 2 s.
ROV4DOF_CRUISE = (np.array([10.0, -5.0, 8.0, 0.3, 0.5, 0.2, 0.1, 0.1, 5.0, 3.0, 2.0, 0.5]),
                  np.array([40.0, 20.0, 15.0, 2.0]))


# --------------------------------------------------------------------------- cn2d
def cn2d_xdot(x, u, p, w=None):
    """Dead reckoning of seed 002 eq. 2 (divided by dt): heading counter-clockwise from east."""
    w = _noise(w, 2)
    speed_fwd, speed_stbd, heading = u[0], u[1], u[2]
    vel_east = speed_fwd * np.cos(heading) + speed_stbd * np.sin(heading)
    vel_north = speed_fwd * np.sin(heading) - speed_stbd * np.cos(heading)
    return _stack([vel_east + w[0], vel_north + w[1]], like=x[0])


def cn2d_h(x, p):
    """Acoustic ranges to the two leaders at p = [x_r0, y_r0, x_r1, y_r1] (eq. 3; sensors leader0 and leader1)."""
    return _stack([np.hypot(x[0] - p[0], x[1] - p[1]), np.hypot(x[0] - p[2], x[1] - p[3])])


def cn2d_state(rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    shape = (n,) if n else ()
    return _stack([rng.uniform(-2000, 2000, shape), rng.uniform(-2000, 2000, shape)])


def cn2d_input(rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    shape = (n,) if n else ()
    return _stack([rng.uniform(0.5, 2.0, shape), rng.normal(0, 0.2, shape), rng.uniform(-np.pi, np.pi, shape)])


# --------------------------------------------------------------------------- linear_cv
def linear_cv_xdot(x, u, p, w=None):
    """Constant velocity: p_dot = v, v_dot = a + w."""
    w = _noise(w, 2)
    return _stack([x[2], x[3], u[0] + w[0], u[1] + w[1]])


def linear_cv_h(x, p):
    """Position relative to the sensor at p."""
    return _stack([x[0] - p[0], x[1] - p[1]])


def linear_cv_state(rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    shape = (n,) if n else ()
    return _stack([rng.normal(0, 100, shape), rng.normal(0, 100, shape), rng.normal(0, 2, shape), rng.normal(0, 2, shape)])


def linear_cv_input(rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    shape = (n,) if n else ()
    return _stack([rng.normal(0, 0.5, shape), rng.normal(0, 0.5, shape)])


# --------------------------------------------------------------------------- remus100
# Seed 004 (Ariza Ramirez et al. 2019): REMUS 100 of ../shared/REMUS100-SPEC.md sections 1-4 and 8,
# written from the spec's tables and Fossen's rigid-body formulas (M_RB about the CB + M_A), with the
# defaults D1 (rpm input), D2 (no propeller torque), D3 (B = W), D4 (Z_w|w| = -131).
REMUS100_PARAMETERS = (
    "g", "W", "B", "xg", "yg", "zg", "xb", "yb", "zb", "Ixx", "Iyy", "Izz",
    "Xudot", "Yvdot", "Zwdot", "Yrdot", "Zqdot", "Mwdot", "Nvdot", "Kpdot", "Mqdot", "Nrdot",
    "Xuu", "Xwq", "Xqq", "Xvr", "Xrr", "Yvv", "Yrr", "Yuv", "Ywp", "Yur", "Ypq",
    "Zww", "Zqq", "Zuw", "Zuq", "Zvp", "Zrp", "Kpp", "Mww", "Mqq", "Muw", "Muq", "Mvp", "Mrp",
    "Nvv", "Nrr", "Nuv", "Nur", "Nwp", "Npq", "kT", "kQ", "prop_torque",
)


def _remus100_mass(c) -> np.ndarray:
    """M = M_RB + M_A: rigid body with the CG at r_G from the CB, plus Prestero's added mass."""
    m = c["W"] / c["g"]
    rg = np.array([c["xg"], c["yg"], c["zg"]])
    S = np.array([[0.0, -rg[2], rg[1]], [rg[2], 0.0, -rg[0]], [-rg[1], rg[0], 0.0]])
    M_rb = np.block([[m * np.eye(3), -m * S], [m * S, np.diag([c["Ixx"], c["Iyy"], c["Izz"]])]])
    M_a = np.zeros((6, 6))
    for (i, j), name in {(0, 0): "Xudot", (1, 1): "Yvdot", (2, 2): "Zwdot", (3, 3): "Kpdot", (4, 4): "Mqdot",
                         (5, 5): "Nrdot", (1, 5): "Yrdot", (5, 1): "Nvdot", (2, 4): "Zqdot", (4, 2): "Mwdot"}.items():
        M_a[i, j] = -c[name]
    return M_rb + M_a


def remus100_xdot(x, u, p, w=None):
    """[nu_dot; eta_dot] of the REMUS 100 (spec 3-4): M nu_dot = tau_HS + tau_hydro + tau_prop + tau_ctrl + w."""
    c = dict(zip(REMUS100_PARAMETERS, p))
    w = _noise(w, 6)
    m = c["W"] / c["g"]
    xg, yg, zg, xb, yb, zb = c["xg"], c["yg"], c["zg"], c["xb"], c["yb"], c["zb"]
    W, B = c["W"], c["B"]
    U, V, Wv, P, Q, R = x[0], x[1], x[2], x[3], x[4], x[5]
    phi, th, psi = x[9], x[10], x[11]
    cf, sf, ct, st, cp, sp = np.cos(phi), np.sin(phi), np.cos(th), np.sin(th), np.cos(psi), np.sin(psi)

    omega = 2.0 * np.pi * u[0] / 60.0                       # rpm -> rad/s (D1)
    thrust = c["kT"] * omega * np.abs(omega)
    torque = c["prop_torque"] * c["kQ"] * omega * np.abs(omega)   # D2: off by default

    dW = W - B
    gx, gy, gz = zg * W - zb * B, yg * W - yb * B, xg * W - xb * B  # first moments of weight - buoyancy
    F = [
        -dW * st + c["Xuu"] * U * np.abs(U) + (c["Xwq"] - m) * Wv * Q + (c["Xqq"] + m * xg) * Q * Q
        + (c["Xvr"] + m) * V * R + (c["Xrr"] + m * xg) * R * R - m * yg * P * Q - m * zg * P * R + thrust,
        dW * ct * sf + c["Yvv"] * V * np.abs(V) + c["Yrr"] * R * np.abs(R) + c["Yuv"] * U * V
        + (c["Ywp"] + m) * Wv * P + (c["Yur"] - m) * U * R + (c["Ypq"] - m * xg) * P * Q - m * zg * Q * R
        + m * yg * (P * P + R * R),
        dW * ct * cf + c["Zww"] * Wv * np.abs(Wv) + c["Zqq"] * Q * np.abs(Q) + c["Zuw"] * U * Wv
        + (c["Zuq"] + m) * U * Q + (c["Zvp"] - m) * V * P + (c["Zrp"] - m * xg) * R * P + m * zg * (P * P + Q * Q)
        - m * yg * R * Q,
        gy * ct * cf - gx * ct * sf + c["Kpp"] * P * np.abs(P) - (c["Izz"] - c["Iyy"]) * Q * R
        + m * yg * (U * Q - V * P) - m * zg * (Wv * P - U * R) + torque,
        -gx * st - gz * ct * cf + c["Mww"] * Wv * np.abs(Wv) + c["Mqq"] * Q * np.abs(Q) + c["Muw"] * U * Wv
        + (c["Muq"] - m * xg) * U * Q + (c["Mvp"] + m * xg) * V * P + (c["Mrp"] - (c["Ixx"] - c["Izz"])) * R * P
        + m * zg * (V * R - Wv * Q) + u[1],
        gz * ct * sf + gy * st + c["Nvv"] * V * np.abs(V) + c["Nrr"] * R * np.abs(R) + c["Nuv"] * U * V
        + (c["Nur"] - m * xg) * U * R + (c["Nwp"] + m * xg) * Wv * P + (c["Npq"] - (c["Iyy"] - c["Ixx"])) * P * Q
        - m * yg * (V * R - Wv * Q) + u[2],
    ]
    F = _stack(F, like=x[0])
    F = F + (w.reshape(6, 1) if F.ndim == 2 else w)
    nu_dot = np.linalg.solve(_remus100_mass(c), F)

    # Kinematics (spec 4): position rates by R_z(psi) R_y(theta) R_x(phi), Euler-angle rates.
    north = cp * ct * U + (cp * st * sf - sp * cf) * V + (cp * st * cf + sp * sf) * Wv
    east = sp * ct * U + (sp * st * sf + cp * cf) * V + (sp * st * cf - cp * sf) * Wv
    down = -st * U + ct * sf * V + ct * cf * Wv
    return _stack([
        nu_dot[0], nu_dot[1], nu_dot[2], nu_dot[3], nu_dot[4], nu_dot[5],
        north, east, down,
        P + (Q * sf + R * cf) * np.tan(th),
        Q * cf - R * sf,
        (Q * sf + R * cf) / ct,
    ], like=x[0])


def remus100_h(x, p):
    """DVL u v w, gyro p q r, depth, roll, pitch, compass (spec 8, [S] order)."""
    return _stack([x[0], x[1], x[2], x[3], x[4], x[5], x[8], x[9], x[10], x[11]])


def remus100_state(rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """A state of the helix manoeuvre: ~1.4 m/s surge, small rates, within the 60 m circle, |theta| < 0.3."""
    shape = (n,) if n else ()
    return _stack([
        rng.uniform(0.3, 2.0, shape), rng.normal(0, 0.05, shape), rng.normal(0, 0.05, shape),
        rng.normal(0, 0.05, shape), rng.normal(0, 0.05, shape), rng.normal(0, 0.05, shape),
        rng.uniform(-60, 60, shape), rng.uniform(-60, 60, shape), rng.uniform(0, 10, shape),
        rng.normal(0, 0.1, shape), rng.normal(0, 0.1, shape), rng.uniform(-np.pi, np.pi, shape),
    ])


def remus100_input(rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    shape = (n,) if n else ()
    return _stack([rng.uniform(1000, 2400, shape), rng.normal(0, 1, shape), rng.normal(0, 5, shape)])


#: Turning at 1.4 m/s with every velocity and rate of one sign over the 2 s of the order check.
REMUS100_CRUISE = (np.array([1.4, 0.05, 0.03, 0.02, 0.02, 0.1, 60.0, 3.0, 5.0, 0.02, 0.05, 2.0]),
                   np.array([1500.0, 0.3, 1.0]))


# --------------------------------------------------------------------------- registry
@dataclass(frozen=True)
class ReferenceModel:
    """NumPy oracle of one model.

    xdot(x, u, p, w=None), h(x, p): the equations; x is (n_x,) or (n_x, N).
    sample_state(rng, n=None), sample_input(rng, n=None): plausible random points, (n,) or (n, N).
    exact_flow: True when the held-input flow is a polynomial in time of degree <= the order of the
        model's discretisation, so the discrete step must equal the exact solution (no order to show).
    cruise: (state, input) of a realistic manoeuvre for the order check, None to sample one. |v| v
        damping is only C^1 where a velocity crosses zero, which caps Runge-Kutta's observed order,
        so a cruise keeps every velocity's sign over the check's horizon.
    """

    name: str
    parameter_names: tuple[str, ...]
    xdot: Callable
    h: Callable
    sample_state: Callable
    sample_input: Callable
    exact_flow: bool = False
    cruise: tuple[np.ndarray, np.ndarray] | None = None


REFERENCES: dict[str, ReferenceModel] = {
    "rov4dof": ReferenceModel("rov4dof", ROV4DOF_PARAMETERS, rov4dof_xdot, rov4dof_h, rov4dof_state, rov4dof_input,
                              cruise=ROV4DOF_CRUISE),
    # x_dot does not depend on x: explicit Euler is exact for a held input.
    "cn2d": ReferenceModel("cn2d", ("leader0_x_r", "leader0_y_r", "leader1_x_r", "leader1_y_r"), cn2d_xdot, cn2d_h,
                           cn2d_state, cn2d_input, exact_flow=True),
    # quadratic in time: RK4 is exact for a held input.
    "linear_cv": ReferenceModel("linear_cv", ("s_x", "s_y"), linear_cv_xdot, linear_cv_h, linear_cv_state,
                                linear_cv_input, exact_flow=True),
    # REMUS 100 (seed 004), a block of its own above
    "remus100": ReferenceModel("remus100", REMUS100_PARAMETERS, remus100_xdot, remus100_h, remus100_state,
                               remus100_input, cruise=REMUS100_CRUISE),
}


def step(ref: ReferenceModel, x, u, p, dt: float, discretisation: str, substeps: int = 1, w=None) -> np.ndarray:
    """One discrete step over dt in `substeps` equal parts, u, p and w held (explicit Euler or classic RK4)."""
    h = dt / substeps
    x = np.asarray(x, dtype=float)
    for _ in range(substeps):
        if discretisation == "euler":
            x = x + h * ref.xdot(x, u, p, w)
        elif discretisation == "rk4":
            k1 = ref.xdot(x, u, p, w)
            k2 = ref.xdot(x + 0.5 * h * k1, u, p, w)
            k3 = ref.xdot(x + 0.5 * h * k2, u, p, w)
            k4 = ref.xdot(x + h * k3, u, p, w)
            x = x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        else:
            raise ValueError(f"unknown discretisation {discretisation!r} (expected 'euler' or 'rk4')")
    return x
