"""BlueROV2 Heavy, an open-frame observation ROV with 8 thrusters, in all six degrees of freedom.

A vehicle that is not built into abyssal, written the way a user would: one file, one function
returning a Model, the equations numbered as in Fossen's Handbook of Marine Craft Hydrodynamics
and Motion Control (2011; the same equations are in the 2021 edition). Coefficients: approximately
those of von Benzon et al. (2022), "An open-source benchmark simulator: control of a BlueROV2
underwater robot", J. Mar. Sci. Eng. 10(12), 1898, for the Heavy configuration, and approximate
positions of the Heavy's thrusters. Treat every number as approximate: check it against the
paper (or identify your own vehicle) before quoting results.

State x = [eta; nu] with eta = [x y z phi theta psi] (NED position, zyx Euler angles) and
nu = [u v w p q r] (body velocities); input f = [f_1 ... f_8], the thrust of each thruster in N;
measurement y = [z  phi theta psi  u v w  x y]: a pressure depth sensor, an AHRS, a DVL (body
velocities) and a USBL fix of the horizontal position.

    eta_dot = J(eta) nu,  J = blockdiag(R_b^n(Theta), T(Theta))          (eqs. 2.18, 2.29, 2.40)
    M nu_dot + C(nu) nu + D(nu) nu + g(eta) = tau + w                    (eq. 7.1)
        M = M_RB + M_A, M_RB from m, r_g, I (eq. 3.44); M_A diagonal (ch. 6: three planes of symmetry)
        C(nu) = C_RB(nu) + C_A(nu), both derived from M                 (eq. 3.46 / 6.43)
        D(nu) = D_L + D_NL |nu|, diagonal (decoupled, ch. 6)
        g(eta) from weight W = m g and buoyancy B                       (eq. 4.6)
    tau = k_T T f,  T = [d_i; r_i x d_i] per thruster                   (ch. 12: tau = T K u)

Choices (not from the paper):
- The body origin CO is the centre of buoyancy (r_b = [x_b 0 z_b] = 0 by default) and the centre of
  gravity is 2 cm below it (r_g = [0 0 z_g], the offset commonly used for the BlueROV2; the
  least certain number here, and the one that sets the roll and pitch stiffness). B is taken 1 N
  above W = m g (a slightly buoyant vehicle, as BlueROV2s are trimmed). The inertias are taken
  about CO (with z_g = 2 cm the difference is ~0.005 kg m^2).
- The Heavy's 8 thrusters: 4 horizontal, vectored at 45 deg, 85 mm below CO; 4 vertical. A
  positive f_i pushes the vehicle along d_i (the thrusters' own spin direction and the T200's
  asymmetric thrust curve are the autopilot's business, not the model's). k_T scales all thrusts
  (a runtime parameter, 1 by default: a thrust calibration error is one number to estimate).
- Linear damping in sway, roll and yaw is zero by default (as we read the benchmark's values; the
  quadratic terms damp those motions); kept as parameters.
- The process noise w is a generalised force (6), added to tau.

Discretisation: RK4 with SUBSTEPS = 2 per step. The quadratic sway damping is the stiffest term:
its Jacobian (Y_v + 2 Y_vv |v|) / (m - Y_vdot) is ~21 1/s at |v| = 1 m/s, 2.1 for one RK4 step of
dt = 0.1 s against RK4's real-axis limit of 2.785; two substeps give a margin of 2.6x there.
"""
import casadi as ca

from abyssal import Envelope, Model, Parameter, Quantity, fossen, symbols

#: RK4 substeps per call (see the module docstring)
SUBSTEPS = 2
#: gravity, m/s^2 (W = m g)
G = 9.81

STATES = (
    Quantity("x", "m", "north position"),
    Quantity("y", "m", "east position"),
    Quantity("z", "m", "depth"),
    Quantity("phi", "rad", "roll"),
    Quantity("theta", "rad", "pitch"),
    Quantity("psi", "rad", "yaw"),
    Quantity("u", "m/s", "surge velocity"),
    Quantity("v", "m/s", "sway velocity"),
    Quantity("w", "m/s", "heave velocity"),
    Quantity("p", "rad/s", "roll rate"),
    Quantity("q", "rad/s", "pitch rate"),
    Quantity("r", "rad/s", "yaw rate"),
)
INPUTS = tuple(Quantity(f"f_{i}", "N", f"thrust of thruster {i} ({'horizontal' if i <= 4 else 'vertical'})")
               for i in range(1, 9))
PARAMETERS = (  # approximately von Benzon et al. (2022), Heavy configuration; derivatives with Fossen's signs
    Parameter("m", "kg", 13.5, "mass (W = m g)"),
    Parameter("I_x", "kg m^2", 0.26, "roll inertia about CO"),
    Parameter("I_y", "kg m^2", 0.23, "pitch inertia about CO"),
    Parameter("I_z", "kg m^2", 0.37, "yaw inertia about CO"),
    Parameter("X_udot", "kg", -6.36, "added mass, surge"),
    Parameter("Y_vdot", "kg", -7.12, "added mass, sway"),
    Parameter("Z_wdot", "kg", -18.68, "added mass, heave"),
    Parameter("K_pdot", "kg m^2", -0.189, "added inertia, roll"),
    Parameter("M_qdot", "kg m^2", -0.135, "added inertia, pitch"),
    Parameter("N_rdot", "kg m^2", -0.222, "added inertia, yaw"),
    Parameter("X_u", "N s/m", -13.7, "linear damping, surge"),
    Parameter("Y_v", "N s/m", 0.0, "linear damping, sway"),
    Parameter("Z_w", "N s/m", -33.0, "linear damping, heave"),
    Parameter("K_p", "N m s", 0.0, "linear damping, roll"),
    Parameter("M_q", "N m s", -0.8, "linear damping, pitch"),
    Parameter("N_r", "N m s", 0.0, "linear damping, yaw"),
    Parameter("X_uu", "N s^2/m^2", -141.0, "quadratic damping, surge"),
    Parameter("Y_vv", "N s^2/m^2", -217.0, "quadratic damping, sway"),
    Parameter("Z_ww", "N s^2/m^2", -190.0, "quadratic damping, heave"),
    Parameter("K_pp", "N m s^2", -1.19, "quadratic damping, roll"),
    Parameter("M_qq", "N m s^2", -0.47, "quadratic damping, pitch"),
    Parameter("N_rr", "N m s^2", -1.5, "quadratic damping, yaw"),
    Parameter("z_g", "m", 0.02, "centre of gravity below CO"),
    Parameter("x_b", "m", 0.0, "centre of buoyancy ahead of CO"),
    Parameter("z_b", "m", 0.0, "centre of buoyancy below CO (negative: above)"),
    Parameter("B", "N", 133.4, "buoyancy (slightly more than W: the vehicle floats up when idle)"),
    Parameter("k_T", "1", 1.0, "thrust scale factor (calibration)"),
)
NOISES = (
    Quantity("w_X", "N", "surge force noise"),
    Quantity("w_Y", "N", "sway force noise"),
    Quantity("w_Z", "N", "heave force noise"),
    Quantity("w_K", "N m", "roll moment noise"),
    Quantity("w_M", "N m", "pitch moment noise"),
    Quantity("w_N", "N m", "yaw moment noise"),
)
OUTPUTS = (
    Quantity("z", "m", "pressure sensor depth"),
    Quantity("phi", "rad", "AHRS roll"),
    Quantity("theta", "rad", "AHRS pitch"),
    Quantity("psi", "rad", "AHRS heading"),
    Quantity("u", "m/s", "DVL surge velocity"),
    Quantity("v", "m/s", "DVL sway velocity"),
    Quantity("w", "m/s", "DVL heave velocity"),
    Quantity("x", "m", "USBL north"),
    Quantity("y", "m", "USBL east"),
)
#: the measurement: indices of the measured states, in the order of OUTPUTS
MEASURED = (2, 3, 4, 5, 6, 7, 8, 0, 1)

#: thruster positions r_i (m, body axes from CO) and thrust directions d_i (unit vectors)
S = 0.5 ** 0.5  # cos 45 deg
THRUSTERS = (
    ((0.156, 0.111, 0.085), (S, -S, 0.0)),     # 1 front starboard, horizontal
    ((0.156, -0.111, 0.085), (S, S, 0.0)),     # 2 front port
    ((-0.156, 0.111, 0.085), (-S, -S, 0.0)),   # 3 rear starboard
    ((-0.156, -0.111, 0.085), (-S, S, 0.0)),   # 4 rear port
    ((0.120, 0.218, 0.0), (0.0, 0.0, 1.0)),    # 5 front starboard, vertical
    ((0.120, -0.218, 0.0), (0.0, 0.0, 1.0)),   # 6 front port
    ((-0.120, 0.218, 0.0), (0.0, 0.0, 1.0)),   # 7 rear starboard
    ((-0.120, -0.218, 0.0), (0.0, 0.0, 1.0)),  # 8 rear port
)


def thrust_configuration() -> ca.DM:
    """T (6 x 8): column i is [d_i; r_i x d_i], the force and moment of a unit thrust of thruster i."""
    columns = [ca.vertcat(ca.DM(d), ca.cross(ca.DM(r), ca.DM(d))) for r, d in THRUSTERS]
    return ca.horzcat(*columns)


def bluerov2() -> Model:
    x, f, p, w = symbols("x", STATES), symbols("u", INPUTS), symbols("p", PARAMETERS), symbols("w", NOISES)
    c = {q.name: p[i] for i, q in enumerate(PARAMETERS)}
    eta, nu = x[0:6], x[6:12]
    phi, theta = eta[3], eta[4]
    r_g = ca.vertcat(0, 0, c["z_g"])
    r_b = ca.vertcat(c["x_b"], 0, c["z_b"])

    M_RB = fossen.rigid_body_mass(c["m"], r_g, ca.diag(ca.vertcat(c["I_x"], c["I_y"], c["I_z"])))    # eq. 3.44
    M_A = -ca.diag(ca.vertcat(c["X_udot"], c["Y_vdot"], c["Z_wdot"], c["K_pdot"], c["M_qdot"], c["N_rdot"]))  # ch. 6
    M = M_RB + M_A                                                                 # symmetric, positive definite
    D_L = -ca.vertcat(c["X_u"], c["Y_v"], c["Z_w"], c["K_p"], c["M_q"], c["N_r"])
    D_NL = -ca.vertcat(c["X_uu"], c["Y_vv"], c["Z_ww"], c["K_pp"], c["M_qq"], c["N_rr"])
    damping = fossen.linear_plus_quadratic_damping(nu, D_L, D_NL)                                 # D(nu) nu
    restoring = fossen.restoring_forces(c["m"] * G, c["B"], r_g, r_b, phi, theta)                 # eq. 4.6
    tau = c["k_T"] * ca.mtimes(thrust_configuration(), f)                                          # tau = T K u

    eta_dot = fossen.kinematics_6dof(eta, nu)                                                     # eq. 2.40
    nu_dot = fossen.rigid_body_equations(M, nu, tau + w, damping, restoring)                      # eq. 7.1, C from M

    return Model(
        name="bluerov2",
        states=STATES, inputs=INPUTS, parameters=PARAMETERS, noises=NOISES, outputs=OUTPUTS,
        x=x, u=f, p=p, w=w,
        xdot=ca.vertcat(eta_dot, nu_dot),
        y=x[list(MEASURED)],
        discretisation="rk4",
        substeps=SUBSTEPS,
        angle_outputs=(1, 2, 3),
        angle_states=(3, 4, 5),
        envelope=Envelope(
            states={"x": (-50.0, 50.0), "y": (-50.0, 50.0), "z": (0.0, 100.0),  # a tether's reach; rated depth
                    "phi": (-1.2, 1.2), "theta": (-1.2, 1.2),  # T(Theta) is singular at theta = +-pi/2
                    "psi": (-3.2, 3.2),
                    "u": (-1.5, 1.5), "v": (-1.0, 1.0), "w": (-1.0, 1.0),  # ~1.5 m/s (3 kn) ahead at full thrust
                    "p": (-1.5, 1.5), "q": (-1.5, 1.5), "r": (-1.5, 1.5)},
            inputs={q.name: (-40.0, 40.0) for q in INPUTS},  # a T200 gives about -40..50 N at 16 V
            max_dt=0.1),
        notes=("coefficients approximately von Benzon et al. (2022), BlueROV2 Heavy: check before quoting",
               "inertia taken about CO; r_g = [0 0 z_g], r_b = [x_b 0 z_b]",
               "thruster geometry read off the Heavy frame; positive thrust along d_i"),
    )
