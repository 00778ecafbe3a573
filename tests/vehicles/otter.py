"""An Otter-like USV (Maritime Robotics' Otter, 2 m catamaran) in surge, sway and yaw, with its two propellers'
first-order lag: a user's model ported in the style of Fossen's PythonVehicleSimulator (``otter.py``, its
``crossFlowDrag`` and ``Hoerner`` in ``gnc.py``), restricted to the horizontal plane, for `abyssal verify`'s tests.
No operating envelope is declared (that is the case under test).

State x = [x y psi u v r n_1 n_2] (NED position, heading, body velocities, the left and right propeller shaft
speeds); input u = [n_1c n_2c] (commanded shaft speeds, rad/s); runtime parameters: the propeller time constant
T_n (0.1 s, as otter.py's), the current's speed V_c and direction beta_c; measurement [x y psi n_1 n_2] (GNSS,
compass, the shaft speeds).

    eta_dot = R(psi) nu                                                     (Fossen 2021, eq. 2.83, 3 DOF)
    nu_r = nu - nu_c,  nu_c = V_c [cos(beta_c - psi), sin(beta_c - psi), 0]  (an irrotational current)
    M (nu_dot - Dnu_c) = tau - D nu_r - N_rr |r_r| r_r e_r + tau_cf - C_RB(nu) nu_r   (eq. 6.98; otter.py's sum)
        Dnu_c = [r v_c, -r u_c, 0]                                          (d nu_c / dt in BODY)
        M = M_RB + M_A: the (surge, sway, yaw) block of otter.py's 6-DOF M (hull 55 kg, payload 25 kg
            at r_p = [0.05 0 -0.35] m; M_RB = H(r_g)^T M_RB,CG H(r_g); M_A = -diag(X_udot, Y_vdot, N_rdot))
        C_RB(nu) = [[0, 0, -m (x_g r + v)], [0, 0, m u], [m (x_g r + v), -m u, 0]]   (eq. 6.99)
        C_A = 0: otter.py cancels the Munk moment (its C_A[5,0:2], C_A[0:2,5]), which in 3 DOF is all of C_A
        D = diag(-X_u, 0, -N_r), X_u = -24.4 g / U_max, N_r = -M[yaw, yaw] / T_yaw (T_yaw = 1 s);
            N_rr = 10 (-N_r), otter.py's nonlinear yaw damping
        tau_cf = L * sum over 21 strips x_i = -L/2 ... L/2 of -1/2 rho T C_d |v_r + x_i r| (v_r + x_i r) dx [0, 1, x_i]
            (cross-flow drag, otter.py's factor L included; C_d from Hoerner's curve at B_pont / (2 T))
        tau = [T_1 + T_2, 0, -l_1 T_1 - l_2 T_2],  T_i = k n_i |n_i|, k = k_pos for n_i > 0 else k_neg,
            n_i saturated to [n_min, n_max]
    n_dot = (n_c - n) / T_n                                                 (the propellers' first-order lag)

The lag is the stiffest mode at rest (-1 / T_n = -10 1/s: one RK4 step is stable up to dt = 0.279 s, and errs by
~5e-4 relative at dt = 0.1 s, ordinary RK4 error); the nonlinear yaw damping is stiffer at speed (-21 1/s at
r = 1 rad/s). Process noise: generalised forces on surge, sway and yaw. RK4, one step per call.
"""
import math

import casadi as ca
import numpy as np

from abyssal import Model, Parameter, Quantity, symbols

RHO, G = 1026.0, 9.81

STATES = (
    Quantity("x", "m", "north position"), Quantity("y", "m", "east position"), Quantity("psi", "rad", "heading"),
    Quantity("u", "m/s", "surge velocity"), Quantity("v", "m/s", "sway velocity"), Quantity("r", "rad/s", "yaw rate"),
    Quantity("n_1", "rad/s", "left propeller shaft speed"), Quantity("n_2", "rad/s", "right propeller shaft speed"),
)
INPUTS = (Quantity("n_1c", "rad/s", "commanded left shaft speed"), Quantity("n_2c", "rad/s", "commanded right shaft speed"))
PARAMETERS = (
    Parameter("T_n", "s", 0.1, "propeller time constant (otter.py)"),
    Parameter("V_c", "m/s", 0.0, "current speed"),
    Parameter("beta_c", "rad", 0.0, "current direction (NED, towards)"),
)
NOISES = (Quantity("w_X", "N", "surge force noise"), Quantity("w_Y", "N", "sway force noise"),
          Quantity("w_N", "N m", "yaw moment noise"))
OUTPUTS = (Quantity("x", "m", "GNSS north"), Quantity("y", "m", "GNSS east"), Quantity("psi", "rad", "compass"),
           Quantity("n_1", "rad/s", "left shaft speed"), Quantity("n_2", "rad/s", "right shaft speed"))


def _skew(a) -> np.ndarray:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def _transport(r) -> np.ndarray:
    """otter.py's Hmtrx(r): the 6x6 transformation from CG to CO."""
    H = np.eye(6)
    H[0:3, 3:6] = _skew(r).T
    return H


def _hoerner(B: float, T: float) -> float:
    """The 2D cross-flow drag coefficient of Hoerner's curve at B / (2 T) (gnc.py's Hoerner)."""
    ratio = [0.0109, 0.1766, 0.3530, 0.4519, 0.4728, 0.4929, 0.4933, 0.5585, 0.6464, 0.8336, 0.9880, 1.3081, 1.6392,
             1.8600, 2.3129, 2.6000, 3.0088, 3.4508, 3.7379, 4.0017]
    drag = [1.9661, 1.9657, 1.8976, 1.7872, 1.5837, 1.2786, 1.2108, 1.0836, 0.9986, 0.8796, 0.8284, 0.7599, 0.6914,
            0.6571, 0.6307, 0.5962, 0.5868, 0.5859, 0.5599, 0.5593]
    return float(np.interp(B / (2 * T), ratio, drag))


def constants() -> dict:
    """otter.py's numbers: mass, centre of gravity, the 3-DOF mass matrix, damping, drag and propeller data."""
    m_hull, m_p, r_p = 55.0, 25.0, np.array([0.05, 0.0, -0.35])
    L, B_pont, y_pont, Cb_pont = 2.0, 0.25, 0.395, 0.4
    m = m_hull + m_p
    r_g = (m_hull * np.array([0.2, 0.0, -0.2]) + m_p * r_p) / m
    nabla = m / RHO
    T = nabla / (2 * Cb_pont * B_pont * L)  # draft
    Ig_CG = m_hull * np.diag([(0.4 * 1.08) ** 2, (0.25 * L) ** 2, (0.25 * L) ** 2])
    Ig = Ig_CG - m_hull * _skew(r_g) @ _skew(r_g) - m_p * _skew(r_p) @ _skew(r_p)
    M_RB_CG = np.zeros((6, 6))
    M_RB_CG[0:3, 0:3], M_RB_CG[3:6, 3:6] = m * np.eye(3), Ig
    H = _transport(r_g)
    M_RB = H.T @ M_RB_CG @ H
    M_A = np.diag([0.1 * m_hull, 1.5 * m_hull, 1.0 * m_hull, 0.2 * Ig[0, 0], 0.8 * Ig[1, 1], 1.7 * Ig[2, 2]])
    M6 = M_RB + M_A
    planar = [0, 1, 5]
    k_pos, k_neg = 0.02216 / 2, 0.01289 / 2
    U_max = 6 * 0.5144
    return {
        "m": m, "x_g": float(r_g[0]), "L": L, "T": T, "M": M6[np.ix_(planar, planar)],
        "X_u": -24.4 * G / U_max, "N_r": -M6[5, 5] / 1.0, "C_d": _hoerner(B_pont, T),
        "l_1": -y_pont, "l_2": y_pont, "k_pos": k_pos, "k_neg": k_neg,
        "n_max": math.sqrt(0.5 * 24.4 * G / k_pos), "n_min": -math.sqrt(0.5 * 13.6 * G / k_neg),
    }


def _thrust(n, c: dict):
    n = ca.fmin(ca.fmax(n, c["n_min"]), c["n_max"])
    return ca.if_else(n > 0, c["k_pos"], c["k_neg"]) * n * ca.fabs(n)


def _cross_flow(v_r, r, c: dict):
    """(sway force, yaw moment) of the cross-flow drag, 21 strips as gnc.py's crossFlowDrag, times L as otter.py."""
    strips, dx = 20, c["L"] / 20
    Y = N = 0
    for i in range(strips + 1):
        x_i = -c["L"] / 2 + i * dx
        flow = ca.fabs(v_r + x_i * r) * (v_r + x_i * r)
        Y -= 0.5 * RHO * c["T"] * c["C_d"] * flow * dx
        N -= 0.5 * RHO * c["T"] * c["C_d"] * x_i * flow * dx
    return c["L"] * Y, c["L"] * N


def otter() -> Model:
    c = constants()
    x, n_c, p, w = symbols("x", STATES), symbols("u", INPUTS), symbols("p", PARAMETERS), symbols("w", NOISES)
    psi, u, v, r, n = x[2], x[3], x[4], x[5], x[6:8]
    T_n, V_c, beta_c = p[0], p[1], p[2]
    u_c, v_c = V_c * ca.cos(beta_c - psi), V_c * ca.sin(beta_c - psi)
    u_r, v_r, r_r = u - u_c, v - v_c, r
    m, x_g = c["m"], c["x_g"]
    C_RB = ca.SX(3, 3)
    C_RB[0, 2], C_RB[1, 2] = -m * (x_g * r + v), m * u
    C_RB[2, 0], C_RB[2, 1] = m * (x_g * r + v), -m * u
    nu_r = ca.vertcat(u_r, v_r, r_r)
    T_1, T_2 = _thrust(n[0], c), _thrust(n[1], c)
    Y_cf, N_cf = _cross_flow(v_r, r_r, c)
    tau = ca.vertcat(T_1 + T_2, 0, -c["l_1"] * T_1 - c["l_2"] * T_2)
    damping = ca.vertcat(c["X_u"] * u_r, 0, c["N_r"] * r_r - 10 * (-c["N_r"]) * ca.fabs(r_r) * r_r)
    forces = tau + damping + ca.vertcat(0, Y_cf, N_cf) - ca.mtimes(C_RB, nu_r) + w
    nu_dot = ca.vertcat(r * v_c, -r * u_c, 0) + ca.solve(ca.SX(ca.DM(c["M"])), forces)
    eta_dot = ca.vertcat(u * ca.cos(psi) - v * ca.sin(psi), u * ca.sin(psi) + v * ca.cos(psi), r)
    n_dot = (n_c - n) / T_n
    return Model(
        name="otter",
        states=STATES, inputs=INPUTS, parameters=PARAMETERS, noises=NOISES, outputs=OUTPUTS,
        x=x, u=n_c, p=p, w=w,
        xdot=ca.vertcat(eta_dot, nu_dot, n_dot),
        y=x[[0, 1, 2, 6, 7]],
        discretisation="rk4", substeps=1,
        angle_outputs=(2,), angle_states=(2,),
        notes=("Otter-like USV in 3 DOF after Fossen's PythonVehicleSimulator otter.py (tests' model, no envelope)",),
    )
