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
    """Acoustic range to the leader at p = [x_r, y_r] (eq. 3)."""
    return _stack([np.hypot(x[0] - p[0], x[1] - p[1])])


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
    "cn2d": ReferenceModel("cn2d", ("x_r", "y_r"), cn2d_xdot, cn2d_h, cn2d_state, cn2d_input, exact_flow=True),
    # quadratic in time: RK4 is exact for a held input.
    "linear_cv": ReferenceModel("linear_cv", ("s_x", "s_y"), linear_cv_xdot, linear_cv_h, linear_cv_state,
                                linear_cv_input, exact_flow=True),
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
