"""CyberShip II, a 1:70 model of an offshore supply vessel, in surge, sway and yaw (3 DOF).

A vehicle that is not built into abyssal, written the way a user would: one file, one function
returning a Model, the equations numbered as in Fossen's Handbook of Marine Craft Hydrodynamics
and Motion Control (2011). Coefficients: Skjetne, Smogeli and Fossen (2004), "Modeling,
identification, and adaptive maneuvering of CyberShip II", linear part (the nonlinear damping
terms are left out; their values are not needed to show the workflow).

State x = [x y psi u v r] (NED position, heading, body velocities); input tau = [X Y N]
(thruster forces and yaw moment); measurement [x y psi] (GNSS position and compass).

    eta_dot = R(psi) nu                               (eq. 2.80, 3-DOF)
    M nu_dot + C(nu) nu + D nu = tau + w              (eq. 6.98 with M = M_RB + M_A, eq. 6.99)

C(nu) is derived from M by abyssal.fossen.coriolis (never typed in). Y_rdot = N_vdot = 0 here, so
M is symmetric as printed. The linear D is not symmetric (Y_r = -7.25, N_v = 0.0313): that is the
identified model, kept as published.
"""
import casadi as ca

from abyssal import Model, Parameter, Quantity, fossen, symbols

STATES = (
    Quantity("x", "m", "north position"),
    Quantity("y", "m", "east position"),
    Quantity("psi", "rad", "heading"),
    Quantity("u", "m/s", "surge velocity"),
    Quantity("v", "m/s", "sway velocity"),
    Quantity("r", "rad/s", "yaw rate"),
)
INPUTS = (Quantity("tau_X", "N", "surge force"), Quantity("tau_Y", "N", "sway force"),
          Quantity("tau_N", "N m", "yaw moment"))
PARAMETERS = (  # Skjetne et al. (2004); derivatives with Fossen's signs
    Parameter("m", "kg", 23.8, "mass"),
    Parameter("x_g", "m", 0.046, "centre of gravity ahead of CO"),
    Parameter("I_z", "kg m^2", 1.760, "yaw inertia"),
    Parameter("X_udot", "kg", -2.0, "added mass, surge"),
    Parameter("Y_vdot", "kg", -10.0, "added mass, sway"),
    Parameter("Y_rdot", "kg m", 0.0, "added mass, sway from yaw"),
    Parameter("N_vdot", "kg m", 0.0, "added inertia, yaw from sway"),
    Parameter("N_rdot", "kg m^2", -1.0, "added inertia, yaw"),
    Parameter("X_u", "kg/s", -0.72253, "linear damping, surge"),
    Parameter("Y_v", "kg/s", -0.88965, "linear damping, sway"),
    Parameter("Y_r", "kg m/s", -7.250, "linear damping, sway from yaw rate"),
    Parameter("N_v", "kg m/s", 0.03130, "linear damping, yaw from sway"),
    Parameter("N_r", "kg m^2/s", -1.900, "linear damping, yaw"),
)
NOISES = (Quantity("w_X", "N", "surge force noise"), Quantity("w_Y", "N", "sway force noise"),
          Quantity("w_N", "N m", "yaw moment noise"))
OUTPUTS = (Quantity("x", "m", "GNSS north"), Quantity("y", "m", "GNSS east"), Quantity("psi", "rad", "compass"))


def cybership() -> Model:
    x, u, p, w = symbols("x", STATES), symbols("u", INPUTS), symbols("p", PARAMETERS), symbols("w", NOISES)
    c = {q.name: p[i] for i, q in enumerate(PARAMETERS)}
    psi, nu = x[2], x[3:6]

    M = fossen.rigid_body_mass_horizontal(c["m"], c["x_g"], c["I_z"]) + fossen.added_mass_horizontal(
        c["X_udot"], c["Y_vdot"], c["Y_rdot"], c["N_vdot"], c["N_rdot"])              # eqs. 6.90-6.91
    D = fossen.linear_damping_horizontal(c["X_u"], c["Y_v"], c["Y_r"], c["N_v"], c["N_r"])  # eq. 6.104
    eta_dot = fossen.kinematics_horizontal(psi, nu)                                    # eq. 2.80
    nu_dot = fossen.rigid_body_equations(M, nu, u + w, ca.mtimes(D, nu), dofs=fossen.HORIZONTAL)  # eq. 6.98

    return Model(
        name="cybership",
        states=STATES, inputs=INPUTS, parameters=PARAMETERS, noises=NOISES, outputs=OUTPUTS,
        x=x, u=u, p=p, w=w,
        xdot=ca.vertcat(eta_dot, nu_dot),
        y=x[0:3],
        discretisation="rk4",
        angle_outputs=(2,),
        angle_states=(2,),
        notes=("linear damping only (Skjetne et al. 2004, linear part)",),
    )
