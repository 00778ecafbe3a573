"""The model checks of `abyssal verify` pass, and fail when either side is perturbed."""
from __future__ import annotations

import dataclasses
import re

import casadi as ca
import numpy as np
import pytest

from abyssal.runtime.checks import reference_models, verify_models
from abyssal.runtime.checks.reference_models import REFERENCES


@pytest.fixture(scope="module")
def rov_checks(rov):
    return verify_models.checks(rov)


def by_name(checks, fragment):
    found = [c for c in checks if fragment in c.name]
    assert found, f"no check named like {fragment!r} in {[c.name for c in checks]}"
    return found


def failing(checks):
    return sorted(c.name for c in checks if not c.ok)


def test_rov4dof_checks_all_pass_and_cover_every_model_function(rov_checks):
    assert failing(rov_checks) == []
    names = " | ".join(c.name for c in rov_checks)
    for fragment in ("f: compiled C vs CasADi", "F: compiled C vs CasADi", "G: compiled C vs CasADi",
                     "h: compiled C vs CasADi", "H: compiled C vs CasADi", "xdot: compiled C vs CasADi",
                     "xdot vs NumPy model", "h vs NumPy model", "f vs NumPy rk4 step",
                     "F vs central differences", "G vs central differences", "H vs central differences",
                     "one step vs solve_ivp", "order 4", "f_batch (SIMD, U shared)", "f_batch (SIMD, U per-column)",
                     "f _batch entry", "h_batch"):
        assert fragment in names


def test_cn2d_checks_pass_with_exactness_instead_of_order(cn):
    checks = verify_models.checks(cn)
    assert failing(checks) == []
    assert by_name(checks, "exact for held input vs solve_ivp")
    assert not [c for c in checks if "order" in c.name]


def test_rk4_order_ratio_is_near_sixteen(rov_checks):
    (order,) = by_name(rov_checks, "order 4")
    ratio = float(re.search(r"ratio ([0-9.]+)", order.reference).group(1))
    assert 12 <= ratio <= 20
    assert order.error == pytest.approx(abs(ratio - 16), abs=0.01)


def test_perturbed_reference_dynamics_fail(rov):
    """A sign error in the surge Coriolis term of the NumPy model (+m22 v r) is caught."""
    original = REFERENCES["rov4dof"]

    def wrong_coriolis(x, u, p, w=None):
        xdot = original.xdot(x, u, p, w)
        m22 = p[0] - p[3]
        m11 = p[0] - p[2]
        return xdot + np.stack([0 * x[0]] * 4 + [-2 * m22 * x[5] * x[7] / m11] + [0 * x[0]] * 7)

    checks = verify_models.checks(rov, reference=dataclasses.replace(original, xdot=wrong_coriolis))
    bad = failing(checks)
    assert "xdot vs NumPy model" in bad and "f vs NumPy rk4 step" in bad
    assert any(name.startswith("F vs central differences") for name in bad)
    assert not any("compiled C vs CasADi" in name for name in bad)  # the other oracle still agrees


def test_perturbed_reference_measurement_fails(cn):
    original = REFERENCES["cn2d"]
    wrong_range = dataclasses.replace(original, h=lambda x, p: original.h(x, p) * (1 + 1e-9))
    bad = failing(verify_models.checks(cn, reference=wrong_range))
    assert bad == ["h vs NumPy model"]


def test_parameter_order_mismatch_is_a_failure(cn):
    renamed = dataclasses.replace(REFERENCES["cn2d"], parameter_names=("x_leader", "y_leader"))
    checks = verify_models.checks(cn, reference=renamed)
    assert "parameter order vs NumPy model" in failing(checks)


class PerturbedBundle:
    """A bundle whose chosen outputs are off by a relative `eps`: stands in for a faulty build."""

    def __init__(self, bundle, eps, methods):
        self._bundle, self._eps, self._methods = bundle, eps, methods

    def __getattr__(self, name):
        attr = getattr(self._bundle, name)
        if name in self._methods:
            return lambda *args, **kwargs: attr(*args, **kwargs) * (1 + self._eps)
        return attr


@pytest.mark.parametrize("method, expected_failure", [
    ("F", "F vs central differences (NumPy step in x)"),
    ("H", "H vs central differences (NumPy measurement)"),
    ("f_batch", "f_batch (SIMD, U shared) vs one-at-a-time f"),
    ("xdot", "xdot vs NumPy model"),
])
def test_perturbed_bundle_output_fails(rov, method, expected_failure):
    eps = 1e-4 if method in ("F", "H") else 1e-12
    checks = verify_models.checks(PerturbedBundle(rov, eps, {method}))
    assert expected_failure in failing(checks)


def test_perturbed_casadi_side_fails(cn):
    """Compiled C vs CasADi fails when the symbolic F differs from what was compiled."""
    symbolic = verify_models.symbolic_functions("cn2d")
    F = symbolic["F"]
    args = [ca.MX.sym(F.name_in(i), F.sparsity_in(i)) for i in range(F.n_in())]
    symbolic["F"] = ca.Function("cn2d_F", args, [F(*args) * (1 + 1e-9)])
    bad = failing(verify_models.checks(cn, symbolic=symbolic))
    assert bad == ["F: compiled C vs CasADi"]


def test_relative_error_and_central_difference():
    assert verify_models.relative_error([1.0, 2.0], [1.0, 2.0]) == 0
    assert verify_models.relative_error([1.0, 2.2], [1.0, 2.0]) == pytest.approx(0.1)
    assert verify_models.relative_error([1e-3], [0.0]) == pytest.approx(1e-3)
    J = verify_models.central_difference(lambda z: np.array([z[0] * z[1], np.sin(z[0])]), np.array([0.5, 3.0]))
    np.testing.assert_allclose(J, [[3.0, 0.5], [np.cos(0.5), 0.0]], rtol=1e-9)


def test_reference_step_is_fourth_order_on_its_own(rov):
    """The NumPy RK4 of reference_models is itself 4th order (the oracle is sound)."""
    ref = REFERENCES["rov4dof"]
    x0, u = ref.cruise
    p = rov.params()
    exact = verify_models._integrate(ref, x0, u, p, 1.0)
    errors = []
    for n in (10, 20):
        x = x0.copy()
        for _ in range(n):
            x = reference_models.step(ref, x, u, p, 1.0 / n, "rk4")
        errors.append(np.max(np.abs(x - exact)))
    assert 12 < errors[0] / errors[1] < 20
