"""Fossen's marine-vehicle building blocks as CasADi SX expressions.

Conventions (Fossen, *Handbook of Marine Craft Hydrodynamics and Motion Control*, 2011):
NED earth frame, body frame x forward / y starboard / z down; generalised velocity
nu = [u v w p q r], pose eta = [x y z phi theta psi]; equations of motion
``M nu_dot + C(nu) nu + D(nu) nu + g(eta) = tau``, with M = M_RB + M_A symmetric positive
definite, C(nu) skew-symmetric and derived from M (never typed in), D(nu) positive definite.
Hydrodynamic derivatives keep Fossen's signs: added-mass and damping derivatives are
negative numbers (X_udot < 0, X_u < 0), so M_A = -diag(X_udot, ...) and D = -diag(X_u, ...).

Ocean currents (Fossen 2011, Sec. 8.3): the hydrodynamic terms act on the velocity relative to the
water, nu_r = nu - nu_c. For a current that is irrotational and constant in NED, the rigid-body terms
may be written in nu_r too (M_RB nu_dot + C_RB(nu) nu = M_RB nu_r_dot + C_RB(nu_r) nu_r, Fossen's
Property 8.1), so the whole equation of motion is M nu_r_dot + C(nu_r) nu_r + D(nu_r) nu_r + g(eta)
= tau, and nu_dot = nu_r_dot + nu_c_dot, where nu_c_dot is the current's rate as seen from the
turning body. ``relative_velocity`` gives nu_r and nu_c_dot; a model file then reads

    nu_r, nu_c_dot = fossen.relative_velocity(eta, nu, current, dofs)
    nu_dot = fossen.rigid_body_equations(M, nu_r, tau, damping(nu_r), restoring, dofs) + nu_c_dot
    eta_dot = fossen.kinematics(eta, nu, dofs)        # the pose moves with nu, not nu_r
"""
from __future__ import annotations

import casadi as ca


def skew(a) -> ca.SX:
    """S(a) with S(a) b = a x b (Fossen eq. 2.10)."""
    return ca.vertcat(
        ca.horzcat(0, -a[2], a[1]),
        ca.horzcat(a[2], 0, -a[0]),
        ca.horzcat(-a[1], a[0], 0),
    )


def rotation_z(psi) -> ca.SX:
    """Rotation about z by yaw psi, body -> earth (3x3)."""
    c, s = ca.cos(psi), ca.sin(psi)
    return ca.vertcat(ca.horzcat(c, -s, 0), ca.horzcat(s, c, 0), ca.horzcat(0, 0, 1))


def rotation_zyx(phi, theta, psi) -> ca.SX:
    """R_b^n(Theta) for zyx Euler angles, body -> earth (Fossen eq. 2.18)."""
    cphi, sphi = ca.cos(phi), ca.sin(phi)
    cth, sth = ca.cos(theta), ca.sin(theta)
    cpsi, spsi = ca.cos(psi), ca.sin(psi)
    return ca.vertcat(
        ca.horzcat(cpsi * cth, -spsi * cphi + cpsi * sth * sphi, spsi * sphi + cpsi * cphi * sth),
        ca.horzcat(spsi * cth, cpsi * cphi + sphi * sth * spsi, -cpsi * sphi + sth * spsi * cphi),
        ca.horzcat(-sth, cth * sphi, cth * cphi),
    )


def euler_rate_transform(phi, theta) -> ca.SX:
    """T(Theta): Euler-angle rates from body angular velocity (Fossen eq. 2.29); singular at theta = +-90 deg."""
    cphi, sphi = ca.cos(phi), ca.sin(phi)
    cth, tth = ca.cos(theta), ca.tan(theta)
    return ca.vertcat(
        ca.horzcat(1, sphi * tth, cphi * tth),
        ca.horzcat(0, cphi, -sphi),
        ca.horzcat(0, sphi / cth, cphi / cth),
    )


def kinematics_6dof(eta, nu) -> ca.SX:
    """eta_dot = J(eta) nu with J = blockdiag(R_b^n, T) (Fossen eq. 2.40)."""
    phi, theta, psi = eta[3], eta[4], eta[5]
    return ca.vertcat(
        ca.mtimes(rotation_zyx(phi, theta, psi), nu[0:3]),
        ca.mtimes(euler_rate_transform(phi, theta), nu[3:6]),
    )


def coriolis_from_mass(M, nu) -> ca.SX:
    """Coriolis-centripetal matrix of a 6x6 mass matrix M (Fossen eq. 3.46 / 6.43).

    C(nu) = [[0, -S(M11 nu1 + M12 nu2)], [-S(M11 nu1 + M12 nu2), -S(M21 nu1 + M22 nu2)]],
    skew-symmetric for symmetric M, so it does no work. Used for both C_RB and C_A.
    """
    nu1, nu2 = nu[0:3], nu[3:6]
    a = ca.mtimes(M[0:3, 0:3], nu1) + ca.mtimes(M[0:3, 3:6], nu2)
    b = ca.mtimes(M[3:6, 0:3], nu1) + ca.mtimes(M[3:6, 3:6], nu2)
    zero = ca.SX.zeros(3, 3)
    return ca.vertcat(ca.horzcat(zero, -skew(a)), ca.horzcat(-skew(a), -skew(b)))


def rigid_body_mass(m, r_g, inertia) -> ca.SX:
    """M_RB for mass m, centre of gravity r_g (3,) in body axes and 3x3 inertia about CO (Fossen eq. 3.44)."""
    S = skew(r_g)
    return ca.vertcat(
        ca.horzcat(m * ca.SX.eye(3), -m * S),
        ca.horzcat(m * S, inertia),
    )


def linear_plus_quadratic_damping(nu, linear, quadratic) -> ca.SX:
    """D(nu) nu with D(nu) = diag(linear) + diag(quadratic * |nu|); coefficients positive.

    The damping *force* opposes motion: -D(nu) nu. Positive coefficients keep D positive definite.
    """
    return linear * nu + quadratic * ca.fabs(nu) * nu


def restoring_forces(W, B, r_g, r_b, phi, theta) -> ca.SX:
    """g(eta) for weight W, buoyancy B, centres r_g and r_b (Fossen eq. 4.6)."""
    sth, cth, sphi, cphi = ca.sin(theta), ca.cos(theta), ca.sin(phi), ca.cos(phi)
    xg, yg, zg = r_g[0], r_g[1], r_g[2]
    xb, yb, zb = r_b[0], r_b[1], r_b[2]
    return ca.vertcat(
        (W - B) * sth,
        -(W - B) * cth * sphi,
        -(W - B) * cth * cphi,
        -(yg * W - yb * B) * cth * cphi + (zg * W - zb * B) * cth * sphi,
        (zg * W - zb * B) * sth + (xg * W - xb * B) * cth * cphi,
        -(xg * W - xb * B) * cth * sphi - (yg * W - yb * B) * sth,
    )


def solve_mass(M, rhs) -> ca.SX:
    """M^{-1} rhs; a structurally diagonal M (the usual decoupled model) becomes a product with
    1/diag(M), which common-subexpression elimination then shares between Runge-Kutta stages."""
    if M.sparsity().is_diag():
        return rhs * (1 / ca.diag(M))
    return ca.solve(M, rhs)


# --------------------------------------------------------------------------- DOF subsets
# A vehicle rarely uses all six degrees of freedom. A subset is named by its indices in Fossen's
# 6-DOF ordering [surge sway heave roll pitch yaw]; the blocks below take and return matrices and
# vectors of the subset's size, doing the embedding into 6-DOF (where Fossen's formulas live)
# themselves, so a model file never pads matrices by hand.
SIX_DOF = (0, 1, 2, 3, 4, 5)
HORIZONTAL = (0, 1, 5)          # surge, sway, yaw: surface vessels, planar AUV models (Fossen ch. 6.5 / 7)
FOUR_DOF = (0, 1, 2, 5)         # surge, sway, heave, yaw: ROVs whose roll and pitch are passively stable


def embed(value, dofs) -> ca.SX:
    """A (k,) vector or (k, k) matrix on `dofs` as its 6-DOF version (zeros elsewhere)."""
    value = ca.SX(value)
    k = len(dofs)
    if value.shape == (k, k):
        out = ca.SX.zeros(6, 6)
        for a, i in enumerate(dofs):
            for b, j in enumerate(dofs):
                out[i, j] = value[a, b]
        return out
    if value.numel() == k:
        out = ca.SX.zeros(6, 1)
        for a, i in enumerate(dofs):
            out[i] = value[a]
        return out
    raise ValueError(f"expected a ({k},) vector or ({k}, {k}) matrix for DOFs {tuple(dofs)}, got shape {value.shape}")


def restrict(value, dofs) -> ca.SX:
    """The rows (and columns, for a matrix) of a 6-DOF quantity on `dofs`."""
    value = ca.SX(value)
    dofs = list(dofs)
    return value[dofs, dofs] if value.shape == (6, 6) else value[dofs]


def coriolis(M, nu, dofs=SIX_DOF) -> ca.SX:
    """C(nu) of a symmetric mass matrix M on a DOF subset (k x k), derived from M (Fossen eq. 3.46).

    For the horizontal subset and M = [[m11, 0, 0], [0, m22, m23], [0, m23, m33]] this is Fossen's
    eq. 6.99: C = [[0, 0, -m22 v - m23 r], [0, 0, m11 u], [m22 v + m23 r, -m11 u, 0]].
    Skew-symmetric, so it does no work (nu^T C nu = 0).
    """
    return restrict(coriolis_from_mass(embed(M, dofs), embed(nu, dofs)), dofs)


def rigid_body_mass_horizontal(m, x_g, I_z) -> ca.SX:
    """M_RB of a vessel in surge, sway, yaw with its centre of gravity x_g ahead of CO (Fossen eq. 6.90)."""
    return restrict(rigid_body_mass(m, ca.vertcat(x_g, 0, 0), ca.diag(ca.vertcat(0, 0, I_z))), HORIZONTAL)


def added_mass_horizontal(X_udot, Y_vdot, Y_rdot, N_vdot, N_rdot) -> ca.SX:
    """M_A in surge, sway, yaw from the hydrodynamic derivatives (Fossen's signs: all usually < 0).

    Symmetrised (Y_rdot and N_vdot averaged), as Fossen does for the Coriolis matrix of a vessel
    at rest (eq. 6.99 uses (m23 + m32) / 2): M_A = -[[X_udot, 0, 0], [0, Y_vdot, s], [0, s, N_rdot]]
    with s = (Y_rdot + N_vdot) / 2.
    """
    s = (Y_rdot + N_vdot) / 2
    return -ca.vertcat(ca.horzcat(X_udot, 0, 0), ca.horzcat(0, Y_vdot, s), ca.horzcat(0, s, N_rdot))


def linear_damping_horizontal(X_u, Y_v, Y_r, N_v, N_r) -> ca.SX:
    """D in surge, sway, yaw from the linear damping derivatives (Fossen eq. 6.104, signs < 0 usually)."""
    return -ca.vertcat(ca.horzcat(X_u, 0, 0), ca.horzcat(0, Y_v, Y_r), ca.horzcat(0, N_v, N_r))


def kinematics_horizontal(psi, nu) -> ca.SX:
    """[x_dot, y_dot, psi_dot] = R(psi) [u, v, r] (Fossen eq. 2.80, 3-DOF)."""
    return ca.mtimes(rotation_z(psi), nu)


def kinematics(eta, nu, dofs=SIX_DOF) -> ca.SX:
    """eta_dot = J(eta) nu on a DOF subset; roll and pitch not in the subset are held at zero.

    eta and nu are (k,) on `dofs`, in the same order (e.g. [x y psi] and [u v r] for HORIZONTAL).
    """
    eta6, nu6 = embed(eta, dofs), embed(nu, dofs)
    return restrict(kinematics_6dof(eta6, nu6), dofs)


def rigid_body_equations(M, nu, tau, damping, restoring=0, dofs=SIX_DOF) -> ca.SX:
    """nu_dot = M^-1 (tau - C(nu) nu - D(nu) nu - g(eta)) on a DOF subset (Fossen eq. 7.1/3.1).

    M: the total mass matrix M_RB + M_A (k x k, symmetric); damping: the vector D(nu) nu (k,);
    restoring: g(eta) (k,) or 0. C(nu) is derived from M on the subset (``coriolis``). In a current,
    pass nu_r and D(nu_r) nu_r: the result is nu_r_dot, and nu_dot = nu_r_dot + nu_c_dot (module
    docstring, ``relative_velocity``).
    """
    return solve_mass(M, tau - ca.mtimes(coriolis(M, nu, dofs), nu) - damping - restoring)


def relative_velocity(eta, nu, current, dofs=SIX_DOF) -> tuple[ca.SX, ca.SX]:
    """(nu_r, nu_c_dot) in an ocean current that is irrotational and constant in NED (Fossen 2011, Sec. 8.3).

    current: the water's velocity in NED, [V_north, V_east] or [V_north, V_east, V_down] in m/s (numbers, or
    CasADi symbols such as a model's parameters; for a current of speed V_c towards direction beta_c,
    [V_c cos(beta_c), V_c sin(beta_c)]). In body axes it is v_c = R_b^n(Theta)^T current, so
    nu_c = [v_c, 0, 0, 0] and nu_r = nu - nu_c; since R_dot = R S(omega), the current seen from the turning
    body changes at nu_c_dot = [-omega x v_c, 0, 0, 0] (for a vessel in the horizontal plane:
    [r v_c, -r u_c, 0]). eta and nu are on `dofs`, as in ``kinematics``; both results are too.
    """
    current = ca.vertcat(*current) if isinstance(current, (list, tuple)) else ca.SX(current)
    if current.numel() not in (2, 3):
        raise ValueError(f"current must be the water's NED velocity [V_north, V_east(, V_down)], got {current.numel()} "
                         "entries")
    if current.numel() == 2:
        current = ca.vertcat(current, 0)
    eta6, nu6 = embed(eta, dofs), embed(nu, dofs)
    v_c = ca.mtimes(rotation_zyx(eta6[3], eta6[4], eta6[5]).T, current)
    nu_c = ca.vertcat(v_c, ca.SX.zeros(3, 1))
    nu_c_dot = ca.vertcat(-ca.cross(nu6[3:6], v_c), ca.SX.zeros(3, 1))
    return restrict(nu6 - nu_c, dofs), restrict(nu_c_dot, dofs)
