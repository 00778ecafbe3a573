"""Fossen building blocks (symbolic/fossen.py), the rov4dof mass and damping, and Model validation."""
from __future__ import annotations

import importlib

import casadi as ca
import numpy as np
import pytest

from abyssal.symbolic import Model, Parameter, Quantity, fossen
from abyssal.symbolic.model import symbols

# the module (the package re-exports the function of the same name)
rov_module = importlib.import_module("abyssal.symbolic.models.rov4dof")


def evaluate(expr) -> np.ndarray:
    return np.array(ca.evalf(expr))


@pytest.fixture
def rng():
    return np.random.default_rng(7)


def test_skew_is_the_cross_product_and_antisymmetric(rng):
    for _ in range(10):
        a, b = rng.normal(size=3), rng.normal(size=3)
        S = evaluate(fossen.skew(ca.DM(a)))
        np.testing.assert_allclose(S @ b, np.cross(a, b), rtol=0, atol=1e-14)
        np.testing.assert_array_equal(S, -S.T)


@pytest.mark.parametrize("make", [
    lambda phi, theta, psi: fossen.rotation_zyx(phi, theta, psi),
    lambda phi, theta, psi: fossen.rotation_z(psi),
], ids=["zyx", "z"])
def test_rotations_are_orthonormal_with_unit_determinant(make, rng):
    for phi, theta, psi in rng.uniform(-np.pi, np.pi, size=(10, 3)):
        R = evaluate(make(phi, theta, psi))
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-14)
        assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-14)


def test_rotation_zyx_reduces_to_yaw_rotation(rng):
    psi = rng.uniform(-np.pi, np.pi)
    np.testing.assert_allclose(evaluate(fossen.rotation_zyx(0, 0, psi)), evaluate(fossen.rotation_z(psi)), atol=1e-15)


def random_spd(rng, n=6) -> np.ndarray:
    A = rng.normal(size=(n, n))
    return A @ A.T + n * np.eye(n)


def test_coriolis_from_mass_is_skew_symmetric_and_does_no_work(rng):
    for _ in range(10):
        M, nu = random_spd(rng), rng.normal(size=6)
        C = evaluate(fossen.coriolis_from_mass(ca.DM(M), ca.DM(nu)))
        np.testing.assert_allclose(C, -C.T, atol=1e-12)
        assert abs(nu @ C @ nu) < 1e-12


def test_coriolis_of_diagonal_mass_has_the_textbook_terms(rng):
    """Fossen 6.43 with p = q = 0 and diagonal M: surge -m22 v r, sway m11 u r, yaw (m22 - m11) u v."""
    m = rng.uniform(1, 5, size=6)
    u, v, w, r = rng.normal(size=4)
    nu = np.array([u, v, w, 0, 0, r])
    Cnu = evaluate(fossen.coriolis_from_mass(ca.DM(np.diag(m)), ca.DM(nu))) @ nu
    np.testing.assert_allclose(Cnu[[0, 1, 2, 5]], [-m[1] * v * r, m[0] * u * r, 0.0, (m[1] - m[0]) * u * v], atol=1e-12)


def rov_default(name: str) -> float:
    return next(p.default for p in rov_module.PARAMETERS if p.name == name)


def test_rov4dof_mass_matrix_is_positive_definite():
    m, I_z = rov_default("m"), rov_default("I_z")
    M_RB = evaluate(fossen.rigid_body_mass(m, ca.DM.zeros(3), ca.DM(np.diag([1.0, 1.0, I_z]))))
    M_A = -np.diag([rov_default(k) for k in ("X_udot", "Y_vdot", "Z_wdot")] + [0, 0, rov_default("N_rdot")])
    M = M_RB + M_A
    np.testing.assert_array_equal(M, M.T)
    assert np.all(np.linalg.eigvalsh(M) > 0)


def test_rov4dof_damping_dissipates_and_coriolis_does_no_work(rng):
    """With tau = w = 0, no bias and W = B, the kinetic energy rate nu^T M nu_dot equals -nu^T D(nu) nu < 0."""
    model = rov_module.rov4dof()
    xdot = ca.Function("xdot", [model.x, model.u, model.p, model.w], [model.xdot])
    p = np.array(model.parameter_defaults)
    M = np.diag([rov_default("m") - rov_default("X_udot"), rov_default("m") - rov_default("Y_vdot"),
                 rov_default("m") - rov_default("Z_wdot"), rov_default("I_z") - rov_default("N_rdot")])
    linear = -np.array([rov_default(k) for k in ("X_u", "Y_v", "Z_w", "N_r")])
    quadratic = -np.array([rov_default(k) for k in ("X_uu", "Y_vv", "Z_ww", "N_rr")])
    assert np.all(linear > 0) and np.all(quadratic > 0)  # D(nu) positive definite for every nu
    for _ in range(10):
        nu = rng.normal(0, 0.5, size=4)
        x = np.concatenate([rng.normal(size=4), nu, np.zeros(4)])
        nu_dot = np.array(xdot(x, np.zeros(4), p, np.zeros(8))).ravel()[4:8]
        power = nu @ M @ nu_dot
        dissipated = nu @ ((linear + quadratic * np.abs(nu)) * nu)
        assert power == pytest.approx(-dissipated, rel=1e-12)
        assert power < 0


def test_damping_opposes_motion(rng):
    nu = rng.normal(size=4)
    d = evaluate(fossen.linear_plus_quadratic_damping(ca.DM(nu), ca.DM([1, 2, 3, 4]), ca.DM([0.5, 0.5, 0.5, 0.5])))
    assert np.all(d.ravel() * nu > 0)  # the force -D(nu) nu opposes each velocity


def test_restoring_forces_vanish_when_neutrally_buoyant_and_upright():
    g = evaluate(fossen.restoring_forces(100.0, 100.0, ca.DM.zeros(3), ca.DM.zeros(3), 0, 0))
    np.testing.assert_array_equal(g.ravel(), np.zeros(6))
    g = evaluate(fossen.restoring_forces(110.0, 100.0, ca.DM.zeros(3), ca.DM.zeros(3), 0, 0))
    assert g[2, 0] == pytest.approx(-10.0)  # heavier than buoyant: net force down (z down) enters as -g


def test_solve_mass_diagonal_and_dense_agree(rng):
    M = random_spd(rng, 4)
    rhs = rng.normal(size=4)
    np.testing.assert_allclose(evaluate(fossen.solve_mass(ca.SX(ca.DM(M)), ca.DM(rhs))).ravel(),
                               np.linalg.solve(M, rhs), rtol=1e-12)
    diag = ca.diag(ca.SX(ca.DM(np.diag(M))))
    np.testing.assert_allclose(evaluate(fossen.solve_mass(diag, ca.DM(rhs))).ravel(), rhs / np.diag(M), rtol=1e-15)


# ----------------------------------------------------------------- Model validation
STATES = (Quantity("a", "m"), Quantity("b", "m"))
INPUTS = (Quantity("c", "m/s"),)
PARAMS = (Parameter("k", "1/s", 1.0),)


def make_model(**overrides) -> Model:
    x, u, p, w = symbols("x", STATES), symbols("u", INPUTS), symbols("p", PARAMS), ca.SX(0, 1)
    fields = dict(name="toy", states=STATES, inputs=INPUTS, parameters=PARAMS, noises=(),
                  outputs=(Quantity("y", "m"),), x=x, u=u, p=p, w=w,
                  xdot=ca.vertcat(x[1], -p[0] * x[0] + u[0]), y=x[0])
    fields.update(overrides)
    return Model(**fields)


def test_valid_model_builds():
    model = make_model()
    assert (model.n_x, model.n_u, model.n_p, model.n_w, model.n_y) == (2, 1, 1, 0, 1)
    assert model.equations_hash() == make_model().equations_hash()


@pytest.mark.parametrize("overrides, message", [
    (dict(states=STATES[:1]), "x/states"),
    (dict(outputs=()), "y/outputs"),
    (dict(xdot=ca.SX.sym("q", 3, 1)), "xdot has shape"),
    (dict(discretisation="rk45"), "discretisation"),
    (dict(substeps=0), "substeps"),
])
def test_model_rejects_inconsistent_descriptions(overrides, message):
    with pytest.raises(ValueError, match=message):
        make_model(**overrides)


def test_model_rejects_measurement_depending_on_input():
    u = symbols("u", INPUTS)
    x = symbols("x", STATES)
    with pytest.raises(ValueError, match="h may depend on x and p only"):
        make_model(x=x, u=u, xdot=ca.vertcat(x[1], u[0]), y=x[0] + u[0])


def test_equations_hash_changes_with_the_maths():
    x = symbols("x", STATES)
    u, p = symbols("u", INPUTS), symbols("p", PARAMS)
    changed = make_model(x=x, u=u, p=p, xdot=ca.vertcat(x[1], -2 * p[0] * x[0] + u[0]), y=x[0])
    assert changed.equations_hash() != make_model().equations_hash()


# --------------------------------------------------------------------------- ocean current
def test_relative_velocity_in_the_plane_is_the_simulators_current(rng):
    """Horizontal vessel: nu_c = V_c [cos(beta_c - psi), sin(beta_c - psi), 0] and its rate [r v_c, -r u_c, 0], as
    Fossen's PythonVehicleSimulator writes them (otter.py), at random states and currents."""
    for _ in range(20):
        psi, V_c, beta_c = rng.uniform(-np.pi, np.pi), rng.uniform(0, 2), rng.uniform(-np.pi, np.pi)
        nu = rng.normal(size=3)
        eta = np.array([rng.normal(), rng.normal(), psi])
        nu_r, nu_c_dot = fossen.relative_velocity(eta, nu, [V_c * np.cos(beta_c), V_c * np.sin(beta_c)],
                                                  fossen.HORIZONTAL)
        u_c, v_c = V_c * np.cos(beta_c - psi), V_c * np.sin(beta_c - psi)
        np.testing.assert_allclose(evaluate(nu_r).ravel(), nu - [u_c, v_c, 0], atol=1e-14)
        np.testing.assert_allclose(evaluate(nu_c_dot).ravel(), [nu[2] * v_c, -nu[2] * u_c, 0], atol=1e-14)


def test_relative_velocity_6dof_is_the_water_velocity_in_body_axes(rng):
    eta, nu, current = rng.normal(size=6), rng.normal(size=6), rng.normal(size=3)
    nu_r, nu_c_dot = fossen.relative_velocity(eta, nu, current)
    R = evaluate(fossen.rotation_zyx(*eta[3:6]))
    v_c = R.T @ current
    np.testing.assert_allclose(evaluate(nu_r).ravel(), nu - np.r_[v_c, 0, 0, 0], atol=1e-13)
    np.testing.assert_allclose(evaluate(nu_c_dot).ravel(), np.r_[-np.cross(nu[3:6], v_c), 0, 0, 0], atol=1e-13)
    with pytest.raises(ValueError, match="current"):
        fossen.relative_velocity(eta, nu, [1.0])


def test_a_turning_vessel_at_rest_in_the_water_drifts_with_the_current():
    """A vessel moving with the water (nu_r = 0 in surge and sway) while it yaws keeps drifting at exactly the
    current's NED velocity, integrated over 20 s of turning: the current's rate as seen from the turning body
    (nu_c_dot) is what keeps it so (without it the vessel would be flung off the current)."""
    M = fossen.rigid_body_mass_horizontal(25.0, 0.0, 3.0) + fossen.added_mass_horizontal(-2.0, -10.0, 0.0, 0.0, -1.0)
    D = fossen.linear_damping_horizontal(-5.0, -20.0, 0.0, 0.0, -0.5)
    current = [0.4, -0.3]
    x = ca.SX.sym("x", 6)
    eta, nu = x[0:3], x[3:6]
    nu_r, nu_c_dot = fossen.relative_velocity(eta, nu, current, fossen.HORIZONTAL)
    nu_dot = fossen.rigid_body_equations(M, nu_r, 0, ca.mtimes(D, nu_r), dofs=fossen.HORIZONTAL) + nu_c_dot
    xdot = ca.Function("xdot", [x], [ca.vertcat(fossen.kinematics_horizontal(eta[2], nu), nu_dot)])
    psi0 = 0.3
    u_c, v_c = np.array([[np.cos(psi0), np.sin(psi0)], [-np.sin(psi0), np.cos(psi0)]]) @ current
    state, dt = np.array([0.0, 0.0, psi0, u_c, v_c, 0.8]), 0.01
    for _ in range(2000):  # RK4
        k1 = np.array(xdot(state)).ravel()
        k2 = np.array(xdot(state + dt / 2 * k1)).ravel()
        k3 = np.array(xdot(state + dt / 2 * k2)).ravel()
        k4 = np.array(xdot(state + dt * k3)).ravel()
        state = state + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        ned_velocity = np.array(xdot(state)).ravel()[0:2]
        np.testing.assert_allclose(ned_velocity, current, atol=1e-9)
    assert abs(state[2] - psi0) > 0.5  # it did turn
    np.testing.assert_allclose(state[0:2], 20.0 * np.array(current), atol=1e-8)
