"""rov4dof (symbolic/models/rov4dof.py, written with the Fossen DOF blocks) against the independent NumPy
reference of seed 000 (verify's reference_models, which never imports CasADi): the discrete step f, its
state Jacobian F and the measurement h at random states, inputs, parameters and steps, to 1e-12.

F of the reference comes from the complex step, Im f(x + i h e_j) / h with h = 1e-30, which is exact to
rounding (no truncation error, no cancellation); |v| v damping is continued analytically as sign(Re v) v.
"""
from __future__ import annotations

import importlib

import casadi as ca
import numpy as np
import pytest

from abyssal.symbolic.discretise import discrete_step
from abyssal.symbolic.models.rov4dof import SUBSTEPS, rov4dof


REF = importlib.import_module("abyssal.verify.reference_models")  # abyssal.verify is also a function name
ROV = REF.REFERENCES["rov4dof"]
TOLERANCE = 1e-12  # relative to max(1, |value|)
H_STEP = 1e-30


class _ComplexStep(np.ndarray):
    """Columns x + i h e_j whose absolute value is sign(Re z) z, the analytic continuation of |z| off z = 0."""

    def __array_ufunc__(self, ufunc, method, *inputs, **kwargs):
        plain = [np.asarray(a) if isinstance(a, _ComplexStep) else a for a in inputs]
        if ufunc is np.absolute and method == "__call__":
            out = np.where(plain[0].real < 0, -plain[0], plain[0])
        else:
            out = getattr(ufunc, method)(*plain, **kwargs)
        return out.view(_ComplexStep) if isinstance(out, np.ndarray) else out


def reference_step_and_jacobian(x, u, p, dt):
    """(f, F) of the reference: RK4 in SUBSTEPS substeps, w = 0; F by the complex step, one column per state."""
    columns = (x[:, None] + 1j * H_STEP * np.eye(x.size)).view(_ComplexStep)
    stepped = np.asarray(rk4(ROV.xdot, columns, u, p, dt, SUBSTEPS))
    # the same step as the reference's own (complex division rounds the real part differently: not bit-equal)
    assert _relative(stepped.real[:, 0], REF.step(ROV, x, u, p, dt, "rk4", substeps=SUBSTEPS)) <= 1e-14
    return stepped.real[:, 0], stepped.imag / H_STEP


def rk4(xdot, x, u, p, dt, substeps):
    """Classic RK4 in equal substeps, u and p held (the reference's ``step`` casts to float: no complex step)."""
    h = dt / substeps
    for _ in range(substeps):
        k1 = xdot(x, u, p)
        k2 = xdot(x + 0.5 * h * k1, u, p)
        k3 = xdot(x + 0.5 * h * k2, u, p)
        k4 = xdot(x + h * k3, u, p)
        x = x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return x


@pytest.fixture(scope="module")
def model_functions():
    model = rov4dof()
    dt = ca.SX.sym("dt")
    f = discrete_step(model, model.x, model.u, model.p, ca.DM.zeros(model.n_w), dt)
    return (ca.Function("f", [model.x, model.u, model.p, dt], [f]),
            ca.Function("F", [model.x, model.u, model.p, dt], [ca.jacobian(f, model.x)]),
            ca.Function("h", [model.x, model.p], [model.y]),
            np.array(model.parameter_defaults, dtype=np.float64))


def random_points(n: int, seed: int = 2023):
    """Reference-sampled states and inputs (a cleaning ROV) and, every third point, three times larger; the
    parameters scattered 20 % about the paper's (W != B, so the heave restoring force is exercised)."""
    rng = np.random.default_rng(seed)
    names = list(REF.ROV4DOF_PARAMETERS)
    for k in range(n):
        scale = 3.0 if k % 3 == 2 else 1.0
        x = scale * ROV.sample_state(rng)
        u = scale * ROV.sample_input(rng)
        yield x, u, rng.uniform(0.8, 1.2, len(names)), rng.uniform(0.01, 0.5)


def _relative(a, b) -> float:
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    return float(np.max(np.abs(a - b) / np.maximum(1.0, np.abs(b))))


def test_the_reference_jacobian_is_exact_on_a_case_with_a_closed_form():
    """The complex step through the reference on x_dot of a pure surge decay, u_dot = (X_u + X_uu |u|) u / m11:
    d(u_dot)/du = (X_u + 2 X_uu |u|) / m11 exactly, on either side of u = 0 (|.| continued correctly)."""
    # the paper's numbers (section 5.1) in the reference's parameter order
    p = np.array([26.0, 1.04, -24.56, -34.27, -39.19, -2.01, -30.57, -42.21, -89.1, -0.028, -97.43, -79.39, -117.4, -1.25,
                  255.06, 255.06, 100.0])
    prm = dict(zip(REF.ROV4DOF_PARAMETERS, p))
    for surge in (0.7, -0.7):
        x = np.zeros(12)
        x[4] = surge
        columns = (x[:, None] + 1j * H_STEP * np.eye(12)).view(_ComplexStep)
        jac = np.asarray(ROV.xdot(columns, np.zeros(4), p)).imag / H_STEP
        exact = (prm["X_u"] + 2 * prm["X_uu"] * abs(surge)) / (prm["m"] - prm["X_udot"])
        assert jac[4, 4] == pytest.approx(exact, rel=1e-15)


def test_f_F_and_h_equal_the_independent_reference(model_functions):
    f, F, h, p_default = model_functions
    worst = {"f": 0.0, "F": 0.0, "h": 0.0}
    for x, u, scatter, dt in random_points(300):
        p = p_default * scatter
        f_ref, F_ref = reference_step_and_jacobian(x, u, p, dt)
        worst["f"] = max(worst["f"], _relative(np.array(f(x, u, p, dt)).ravel(), f_ref))
        worst["F"] = max(worst["F"], _relative(np.array(F(x, u, p, dt)), F_ref))
        worst["h"] = max(worst["h"], _relative(np.array(h(x, p)).ravel(), np.asarray(ROV.h(x, p))))
    assert all(v <= TOLERANCE for v in worst.values()), worst


def test_a_sign_error_in_the_coriolis_terms_would_be_caught(model_functions):
    """The comparison can fail: the reference with the Munk moment's sign flipped differs by far more than 1e-12."""
    f, _, _, p = model_functions
    x, u, _, dt = next(random_points(1, seed=5))
    x[4:8] = (0.8, 0.6, 0.2, 0.5)  # a surge-sway product large enough to matter

    def flipped(x, u, p, w=None):
        out = np.array(ROV.xdot(x, u, p, w), dtype=np.result_type(x, float))
        prm = dict(zip(REF.ROV4DOF_PARAMETERS, p))
        munk = ((prm["m"] - prm["Y_vdot"]) - (prm["m"] - prm["X_udot"])) * x[4] * x[5]
        out[7] += 2 * munk / (prm["I_z"] - prm["N_rdot"])  # - (m22 - m11) u v  ->  + (m22 - m11) u v
        return out

    wrong = REF.step(REF.ReferenceModel("rov4dof", ROV.parameter_names, flipped, ROV.h, ROV.sample_state,
                                        ROV.sample_input), x, u, p, dt, "rk4", substeps=SUBSTEPS)
    assert _relative(np.array(f(x, u, p, dt)).ravel(), wrong) > 1e-6
