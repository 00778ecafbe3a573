"""Euler and RK4 steps with a symbolic dt (symbolic/discretise.py)."""
from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest

from abyssal.symbolic import discretise
from abyssal.symbolic.models import REGISTRY


def scalar_step(scheme, a: float, h: float, substeps: int = 1) -> float:
    """One step of x_dot = a x from x = 1, evaluated through a CasADi Function of (x, dt)."""
    x, dt = ca.SX.sym("x"), ca.SX.sym("dt")
    fn = ca.Function("step", [x, dt], [scheme(lambda s: a * s, x, dt, substeps)])
    return float(fn(1.0, h))


@pytest.mark.parametrize("a, h", [(-1.0, 0.1), (0.7, 0.3), (-3.0, 0.05)])
def test_euler_and_rk4_match_their_taylor_polynomials(a, h):
    z = a * h
    assert scalar_step(discretise.euler_step, a, h) == pytest.approx(1 + z, rel=1e-15)
    assert scalar_step(discretise.rk4_step, a, h) == pytest.approx(1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24, rel=1e-15)


@pytest.mark.parametrize("scheme", [discretise.euler_step, discretise.rk4_step])
def test_substeps_equal_repeated_smaller_steps(scheme):
    a, h = -1.3, 0.4
    assert scalar_step(scheme, a, h, substeps=3) == pytest.approx(scalar_step(scheme, a, h / 3) ** 3, rel=1e-14)


def test_rk4_global_error_is_fourth_order():
    a, horizon = -1.0, 2.0
    errors = []
    for n in (10, 20):
        errors.append(abs(scalar_step(discretise.rk4_step, a, horizon / n) ** n - math.exp(a * horizon)))
    assert 14 < errors[0] / errors[1] < 18


def test_euler_global_error_is_first_order():
    a, horizon = -1.0, 2.0
    errors = [abs(scalar_step(discretise.euler_step, a, horizon / n) ** n - math.exp(a * horizon)) for n in (200, 400)]
    assert 1.8 < errors[0] / errors[1] < 2.2


def test_discrete_step_uses_the_models_scheme_and_holds_inputs():
    """cn2d (euler): x + dt * xdot exactly; dt stays a free symbol (a runtime input)."""
    model = REGISTRY["cn2d"]()
    dt = ca.SX.sym("dt")
    step = discretise.discrete_step(model, model.x, model.u, model.p, model.w, dt)
    fn = ca.Function("f", [model.x, model.u, model.p, model.w, dt], [step])
    rhs = ca.Function("rhs", [model.x, model.u, model.p, model.w], [model.xdot])
    x, u, p, w = np.array([3.0, -2.0]), np.array([1.5, 0.2, 0.4]), np.zeros(4), np.array([0.01, -0.02])
    for h in (0.1, 1.0):
        np.testing.assert_allclose(np.array(fn(x, u, p, w, h)).ravel(), x + h * np.array(rhs(x, u, p, w)).ravel(), rtol=1e-15)


@pytest.mark.parametrize("name, order", [("euler", 1), ("rk4", 4)])
def test_each_scheme_has_its_order_on_exponential_decay(name, order):
    """x' = -x over 1 s: halving the step divides the global error by 2^order."""
    scheme = discretise.SCHEMES[name]

    def error(steps):
        x = 1.0
        for _ in range(steps):
            x = float(scheme(lambda s: -s, ca.DM(x), 1.0 / steps))
        return abs(x - np.exp(-1.0))

    assert error(16) / error(32) == pytest.approx(2.0 ** order, rel=0.1)


@pytest.mark.parametrize("name", sorted(REGISTRY))
def test_variational_jacobian_equals_ad_of_the_unrolled_step(name):
    """step_and_jacobian's F (scheme applied to dJ/dt = A J) vs CasADi's AD of the whole step."""
    model = REGISTRY[name]()
    dt = ca.SX.sym("dt")
    x_next, F = discretise.step_and_jacobian(model, model.x, model.u, model.p, dt)
    reference = discretise.discrete_step(model, model.x, model.u, model.p, ca.DM.zeros(model.w.shape), dt)
    args = [model.x, model.u, model.p, dt]
    ours = ca.Function("ours", args, [x_next, F])
    ad = ca.Function("ad", args, [reference, ca.jacobian(reference, model.x)])
    rng = np.random.default_rng(5)
    for _ in range(5):
        point = [rng.normal(size=model.n_x) * 0.5, rng.normal(size=model.n_u), np.array(model.parameter_defaults), 0.1]
        (x1, F1), (x2, F2) = [[np.array(v) for v in fn(*point)] for fn in (ours, ad)]
        np.testing.assert_array_equal(x1, x2)
        np.testing.assert_allclose(F1, F2, rtol=0, atol=1e-13 * max(1.0, np.abs(F2).max()))
