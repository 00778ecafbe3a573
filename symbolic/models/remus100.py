"""REMUS 100 AUV, 6-DOF, as simulated in seed paper 004 (Ariza Ramirez et al. 2019).

Implemented from ../shared/REMUS100-SPEC.md (section numbers below are the spec's), which
recovered the paper's Simulink model [S] and cross-checked it against Prestero (2001) [P].

State (spec 1): x = [u v w p q r x y z phi theta psi] (body velocities and rates, NED position
with z = depth, ZYX Euler angles); body origin at the centre of buoyancy.
Input: [n_rpm, tau_M, tau_N]: propeller speed (rev/min) and the paper's "elevator force" and
"rudder force", which are pitch and yaw moments in N m added to M and N (spec 1).
Measurement (spec 8): h(x) = [u v w p q r z phi theta psi] (DVL, gyro, depth, attitude).

    M nu_dot = [X Y Z K M N]^T + w             (spec 3: full 6x6 M with CG and added-mass terms)
    eta_dot  = J(eta) nu                        (spec 4: R_z(psi) R_y(theta) R_x(phi), Euler rates)

Decisions of the spec, kept as defaults; each is a named option:
- D1 ``surge_input="rpm"``: thrust X_prop = k_T n|n| with n = 2 pi n_rpm / 60 ([S]).
  ``surge_input="force"`` is the [M] script variant (input 0 is a force in N, clipped at 0;
  use it with B = 310 N).
- D2 propeller torque K_prop = k_Q n|n| is off: parameter ``prop_torque`` (0 or 1).
- D3 B = W = 299 N ([S]); B is a parameter.
- D4 Z_w|w| = -131 kg/m ([S], [M], [P] App. C). [P] Tab. 8.2 and DESIGN.md suggest -1310 is
  the physically consistent value (symmetry with Y_v|v|): set parameter ``Zww`` to -1310.
- D5 the Newton-Euler signs for general CG/CB offsets (they vanish for x_g = y_g = 0).
- ``fins=True`` (not used by the paper): inputs 1 and 2 are the stern-plane and rudder angles
  in rad with Prestero's fin-lift terms instead of direct moments.
- Process noise w (6 body forces/moments, N and N m) enters M nu_dot additively; the paper's
  simulator has none (w = 0 in the truth); filters use it through G for their Q.
"""
from __future__ import annotations

import math

import casadi as ca

from .. import fossen
from ..model import Envelope, Model, Parameter, Quantity, symbols

S, P = "[S] REMUS_CONTROL_helix.slx", "[P] Prestero 2001 App. C"

STATES = (
    Quantity("u", "m/s", "surge velocity"),
    Quantity("v", "m/s", "sway velocity"),
    Quantity("w", "m/s", "heave velocity"),
    Quantity("p", "rad/s", "roll rate"),
    Quantity("q", "rad/s", "pitch rate"),
    Quantity("r", "rad/s", "yaw rate"),
    Quantity("x", "m", "north position"),
    Quantity("y", "m", "east position"),
    Quantity("z", "m", "depth"),
    Quantity("phi", "rad", "roll"),
    Quantity("theta", "rad", "pitch"),
    Quantity("psi", "rad", "yaw"),
)
INPUTS = (
    Quantity("n_rpm", "rev/min", "propeller speed"),
    Quantity("tau_M", "N m", "pitch moment ('elevator force')"),
    Quantity("tau_N", "N m", "yaw moment ('rudder force')"),
)
FIN_INPUTS = (
    Quantity("n_rpm", "rev/min", "propeller speed"),
    Quantity("delta_s", "rad", "stern-plane angle"),
    Quantity("delta_r", "rad", "rudder angle"),
)
FORCE_INPUTS = (Quantity("X_prop", "N", "surge force (clipped at 0)"),) + INPUTS[1:]


def _p(name, unit, value, source=S, note=""):
    return Parameter(name, unit, value, f"{source}{'; ' + note if note else ''}")


PARAMETERS = (
    # spec 2, mass properties
    _p("g", "m/s^2", 9.81),
    _p("W", "N", 299.0, note="weight"),
    _p("B", "N", 299.0, note="buoyancy; D3 ([M] 310, [P] 308)"),
    _p("xg", "m", 0.0), _p("yg", "m", 0.0), _p("zg", "m", 0.0196),
    _p("xb", "m", 0.0), _p("yb", "m", 0.0), _p("zb", "m", 0.0),
    _p("Ixx", "kg m^2", 0.177), _p("Iyy", "kg m^2", 3.45), _p("Izz", "kg m^2", 3.45),
    # spec 2, added mass
    _p("Xudot", "kg", -0.93, P), _p("Yvdot", "kg", -35.5, P), _p("Zwdot", "kg", -35.5, P),
    _p("Yrdot", "kg m/rad", 1.93, P), _p("Zqdot", "kg m/rad", -1.93, P),
    _p("Mwdot", "kg m", -1.93, P), _p("Nvdot", "kg m", 1.93, P),
    _p("Kpdot", "kg m^2/rad", -0.0704, P, "adjusted (Tab. 4.2: -0.0141)"),
    _p("Mqdot", "kg m^2/rad", -4.88, P), _p("Nrdot", "kg m^2/rad", -4.88, P),
    # spec 2, surge
    _p("Xuu", "kg/m", -1.62, P), _p("Xwq", "kg/rad", -35.5, P), _p("Xqq", "kg m/rad", -1.93, P),
    _p("Xvr", "kg/rad", 35.5, P), _p("Xrr", "kg m/rad", -1.93, P),
    # sway
    _p("Yvv", "kg/m", -1310.0, P, "adjusted (Tab. 4.3: -131)"), _p("Yrr", "kg m/rad^2", 0.632, P),
    _p("Yuv", "kg/m", -28.6, P), _p("Ywp", "kg/rad", 35.5, P), _p("Yur", "kg/rad", 5.22, P),
    _p("Ypq", "kg m/rad", 1.93, P),
    # heave
    _p("Zww", "kg/m", -131.0, P, "D4: as printed; -1310 is the physically consistent variant"),
    _p("Zqq", "kg m/rad^2", -0.632, P), _p("Zuw", "kg/m", -28.6, P), _p("Zuq", "kg/rad", -5.22, P),
    _p("Zvp", "kg/rad", -35.5, P), _p("Zrp", "kg/rad", 1.93, P),
    # roll
    _p("Kpp", "kg m^2/rad^2", -0.130, P, "adjusted (Tab. 4.2: -1.30e-3)"),
    # pitch
    _p("Mww", "kg", 3.18, P), _p("Mqq", "kg m^2/rad^2", -188.0, P, "adjusted (Tab. 4.3: -9.40)"),
    _p("Muw", "kg", 24.0, P), _p("Muq", "kg m/rad", -2.00, P), _p("Mvp", "kg m/rad", -1.93, P),
    _p("Mrp", "kg m^2/rad^2", 4.86, P),
    # yaw
    _p("Nvv", "kg", -3.18, P), _p("Nrr", "kg m^2/rad^2", -94.0, P, "adjusted (Tab. 4.3: -9.40)"),
    _p("Nuv", "kg", -24.0, P), _p("Nur", "kg m/rad", -2.00, P), _p("Nwp", "kg m/rad", -1.93, P),
    _p("Npq", "kg m^2/rad^2", -4.86, P),
    # propeller (spec 1)
    _p("kT", "N s^2/rad^2", 1.569759e-4, S, "thrust k_T n|n| (3.873 N at 1500 rpm)"),
    _p("kQ", "N m s^2/rad^2", -2.242e-5, S, "torque k_Q n|n| (computed, unused in [S])"),
    _p("prop_torque", "1", 0.0, S, "D2: 1 applies K_prop to roll, 0 (default) leaves it off"),
)
FIN_PARAMETERS = (
    _p("Yuudr", "kg/(m rad)", 9.64, P), _p("Zuuds", "kg/(m rad)", -9.64, P),
    _p("Muuds", "kg/rad", -6.15, P), _p("Nuudr", "kg/rad", -6.15, P),
)
NOISES = (
    Quantity("w_X", "N", "surge force noise"), Quantity("w_Y", "N", "sway force noise"),
    Quantity("w_Z", "N", "heave force noise"), Quantity("w_K", "N m", "roll moment noise"),
    Quantity("w_M", "N m", "pitch moment noise"), Quantity("w_N", "N m", "yaw moment noise"),
)
OUTPUTS = (
    Quantity("u", "m/s", "DVL surge"), Quantity("v", "m/s", "DVL sway"), Quantity("w", "m/s", "DVL heave"),
    Quantity("p", "rad/s", "gyro roll rate"), Quantity("q", "rad/s", "gyro pitch rate"),
    Quantity("r", "rad/s", "gyro yaw rate"), Quantity("z", "m", "depth sensor"),
    Quantity("phi", "rad", "roll"), Quantity("theta", "rad", "pitch"), Quantity("psi", "rad", "compass"),
)
ANGLE_STATES = (9, 10, 11)
ANGLE_OUTPUTS = (7, 8, 9)
#: Operating envelope (used in remus100() below): a small-angle cruise, far from the Euler-angle singularity.
ENVELOPE_STATES = {"u": (0.3, 2.0), "v": (-0.15, 0.15), "w": (-0.15, 0.15), "p": (-0.15, 0.15), "q": (-0.15, 0.15),
                   "r": (-0.15, 0.15), "x": (-60.0, 60.0), "y": (-60.0, 60.0), "z": (0.0, 10.0),
                   "phi": (-0.3, 0.3), "theta": (-0.3, 0.3), "psi": (-math.pi, math.pi)}
ENVELOPE_INPUTS = {"n_rpm": (1000.0, 2400.0), "X_prop": (1.7, 9.9), "tau_M": (-3.0, 3.0), "tau_N": (-15.0, 15.0),
                   "delta_s": (-0.35, 0.35), "delta_r": (-0.35, 0.35)}

#: RK4 substeps per call, measured (one call at dt = 0.2 s vs 20 RK4 steps of 0.01 s, random cruise states):
#: 1 substep errs up to 1.1e-3 rad/s in r and 6e-4 in p (the gyro sigma is 1e-3 and 3e-4), 2 substeps <= 6e-5.
SUBSTEPS = 2


def remus100(surge_input: str = "rpm", fins: bool = False, name: str = "remus100") -> Model:
    """The REMUS 100 of the spec; the defaults are the paper's simulator (D1-D5)."""
    if surge_input not in ("rpm", "force"):
        raise ValueError("surge_input must be 'rpm' (D1, [S]) or 'force' ([M])")
    inputs = FIN_INPUTS if fins else (INPUTS if surge_input == "rpm" else FORCE_INPUTS)
    parameters = PARAMETERS + (FIN_PARAMETERS if fins else ())
    x, u, p, w = symbols("x", STATES), symbols("u", inputs), symbols("p", parameters), symbols("w", NOISES)
    c = {prm.name: p[i] for i, prm in enumerate(parameters)}
    vu, vv, vw, vp, vq, vr = (x[i] for i in range(6))
    phi, theta, psi = x[9], x[10], x[11]
    m = c["W"] / c["g"]
    xg, yg, zg, xb, yb, zb = c["xg"], c["yg"], c["zg"], c["xb"], c["yb"], c["zb"]
    W, B = c["W"], c["B"]
    Ixx, Iyy, Izz = c["Ixx"], c["Iyy"], c["Izz"]

    # spec 3: mass matrix (rigid body about the CB plus added mass)
    M = ca.vertcat(
        ca.horzcat(m - c["Xudot"], 0, 0, 0, m * zg, -m * yg),
        ca.horzcat(0, m - c["Yvdot"], 0, -m * zg, 0, m * xg - c["Yrdot"]),
        ca.horzcat(0, 0, m - c["Zwdot"], m * yg, -m * xg - c["Zqdot"], 0),
        ca.horzcat(0, -m * zg, m * yg, Ixx - c["Kpdot"], 0, 0),
        ca.horzcat(m * zg, 0, -m * xg - c["Mwdot"], 0, Iyy - c["Mqdot"], 0),
        ca.horzcat(-m * yg, m * xg - c["Nvdot"], 0, 0, 0, Izz - c["Nrdot"]),
    )

    # spec 3: restoring terms (gravity at r_G, buoyancy at r_B)
    sth, cth, sphi, cphi = ca.sin(theta), ca.cos(theta), ca.sin(phi), ca.cos(phi)
    X_HS = -(W - B) * sth
    Y_HS = (W - B) * cth * sphi
    Z_HS = (W - B) * cth * cphi
    K_HS = (yg * W - yb * B) * cth * cphi - (zg * W - zb * B) * cth * sphi
    M_HS = -(zg * W - zb * B) * sth - (xg * W - xb * B) * cth * cphi
    N_HS = (xg * W - xb * B) * cth * sphi + (yg * W - yb * B) * sth

    # spec 1: propulsion (D1, D2) and control moments (or fins)
    if surge_input == "rpm":
        n = 2 * math.pi * u[0] / 60
        X_prop = c["kT"] * n * ca.fabs(n)
        K_prop = c["prop_torque"] * c["kQ"] * n * ca.fabs(n)
    else:
        X_prop = ca.fmax(u[0], 0)
        K_prop = 0
    if fins:
        ds, dr = u[1], u[2]
        Y_fin, Z_fin = c["Yuudr"] * vu**2 * dr, c["Zuuds"] * vu**2 * ds
        M_fin, N_fin = c["Muuds"] * vu**2 * ds, c["Nuudr"] * vu**2 * dr
    else:
        Y_fin = Z_fin = 0
        M_fin, N_fin = u[1], u[2]

    # spec 3: external forces and moments, in the spec's order
    X = (X_HS + c["Xuu"] * vu * ca.fabs(vu) + (c["Xwq"] - m) * vw * vq + (c["Xqq"] + m * xg) * vq**2
         + (c["Xvr"] + m) * vv * vr + (c["Xrr"] + m * xg) * vr**2 - m * yg * vp * vq - m * zg * vp * vr + X_prop)
    Y = (Y_HS + c["Yvv"] * vv * ca.fabs(vv) + c["Yrr"] * vr * ca.fabs(vr) + c["Yuv"] * vu * vv
         + (c["Ywp"] + m) * vw * vp + (c["Yur"] - m) * vu * vr + (c["Ypq"] - m * xg) * vp * vq
         - m * zg * vq * vr + m * yg * (vp**2 + vr**2) + Y_fin)
    Z = (Z_HS + c["Zww"] * vw * ca.fabs(vw) + c["Zqq"] * vq * ca.fabs(vq) + c["Zuw"] * vu * vw
         + (c["Zuq"] + m) * vu * vq + (c["Zvp"] - m) * vv * vp + (c["Zrp"] - m * xg) * vr * vp
         + m * zg * (vp**2 + vq**2) - m * yg * vr * vq + Z_fin)
    K = (K_HS + c["Kpp"] * vp * ca.fabs(vp) - (Izz - Iyy) * vq * vr + m * yg * (vu * vq - vv * vp)
         - m * zg * (vw * vp - vu * vr) + K_prop)
    Mm = (M_HS + c["Mww"] * vw * ca.fabs(vw) + c["Mqq"] * vq * ca.fabs(vq) + c["Muw"] * vu * vw
          + (c["Muq"] - m * xg) * vu * vq + (c["Mvp"] + m * xg) * vv * vp + (c["Mrp"] - (Ixx - Izz)) * vr * vp
          + m * zg * (vv * vr - vw * vq) + M_fin)
    N = (N_HS + c["Nvv"] * vv * ca.fabs(vv) + c["Nrr"] * vr * ca.fabs(vr) + c["Nuv"] * vu * vv
         + (c["Nur"] - m * xg) * vu * vr + (c["Nwp"] + m * xg) * vw * vp + (c["Npq"] - (Iyy - Ixx)) * vp * vq
         - m * yg * (vv * vr - vw * vq) + N_fin)

    # M^-1 depends on the parameters only: common-subexpression elimination shares it between
    # Runge-Kutta stages and sigma points.
    nu_dot = ca.mtimes(ca.inv(M), ca.vertcat(X, Y, Z, K, Mm, N) + w)

    # spec 4: kinematics
    eta_dot = fossen.kinematics_6dof(ca.vertcat(x[6:9], phi, theta, psi), x[0:6])

    extra = {"angle_states": ANGLE_STATES} if "angle_states" in Model.__dataclass_fields__ else {}
    return Model(
        name=name,
        states=STATES,
        inputs=inputs,
        parameters=parameters,
        noises=NOISES,
        outputs=OUTPUTS,
        x=x,
        u=u,
        p=p,
        w=w,
        xdot=ca.vertcat(nu_dot, eta_dot),
        y=ca.vertcat(x[0:6], x[8:12]),  # spec 8, [S] order
        discretisation="rk4",
        substeps=SUBSTEPS,
        angle_outputs=ANGLE_OUTPUTS,
        notes=(
            "REMUS100-SPEC D1: input 0 is propeller rpm, X_prop = k_T n|n| ([S]); B = W = 299 N (D3)",
            "D2: propeller torque off (parameter prop_torque); D4: Zww = -131 kg/m as printed, -1310 consistent",
            "tau_M, tau_N are moments in N m added to M and N (no fin forces); process noise w: body forces",
        ),
        # the helix of reference_models.remus100_state/input (+-3 sigma; 1000-2400 rpm = 1.7-9.9 N), fins +-20 deg
        envelope=Envelope(states=ENVELOPE_STATES, inputs={q.name: ENVELOPE_INPUTS[q.name] for q in inputs}),
        **extra,
    )
