"""The symbolic algebra the GP-UKF's generated predict is built from (guarded Cholesky, solves, the sigma-point
rules), evaluated by CasADi itself (no compilation). Every other filter's algebra is the C runtime's
(tests/runtime/test_kalman*.py)."""
import math

import casadi as ca
import numpy as np
import pytest

from abyssal.symbolic.filters.linalg import cholesky_solve, guarded_cholesky, wrap_angle
from abyssal.symbolic.filters.sigma_points import cubature_rule, scaled_unscented_rule


def cholesky_of(A):
    n = A.shape[0]
    S = ca.SX.sym("A", n, n)
    L, ok = guarded_cholesky(S)
    fn = ca.Function("chol", [S], [L, ok])
    L_val, ok_val = fn(A)
    return np.array(L_val), float(ok_val)


def test_guarded_cholesky_matches_numpy_on_positive_definite():
    rng = np.random.default_rng(0)
    B = rng.normal(size=(6, 6))
    A = B @ B.T + 0.1 * np.eye(6)
    L, ok = cholesky_of(A)
    assert ok == 1.0
    np.testing.assert_allclose(L, np.linalg.cholesky(A), rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("kind", ["indefinite", "singular", "negative diagonal"])
def test_guarded_cholesky_flags_non_positive_definite_without_nan(kind):
    rng = np.random.default_rng(1)
    v = rng.normal(size=(5, 1))
    A = {
        "indefinite": np.diag([1.0, 2.0, -0.5, 1.0, 3.0]) + 0.1,
        "singular": v @ v.T,  # rank one
        "negative diagonal": -np.eye(5),
    }[kind]
    L, ok = cholesky_of(A)
    assert ok == 0.0
    assert np.all(np.isfinite(L))


def test_cholesky_solve_solves():
    rng = np.random.default_rng(2)
    B = rng.normal(size=(4, 4))
    A = B @ B.T + np.eye(4)
    b = rng.normal(size=(4, 2))
    S, R = ca.SX.sym("A", 4, 4), ca.SX.sym("b", 4, 2)
    L, _ = guarded_cholesky(S)
    x = np.array(ca.Function("solve", [S, R], [cholesky_solve(L, R)])(A, b))
    np.testing.assert_allclose(x, np.linalg.solve(A, b), rtol=1e-12)


def test_wrap_angle_range_and_identity_inside():
    d = ca.SX.sym("d")
    fn = ca.Function("wrap", [d], [wrap_angle(d)])
    for value in np.linspace(-20, 20, 401):
        w = float(fn(value))
        assert -math.pi < w <= math.pi
        assert math.isclose(math.remainder(w - value, 2 * math.pi), 0.0, abs_tol=1e-12)
    for value in (0.3, -3.0, math.pi, 1e-9):
        assert float(fn(value)) == value  # bitwise unchanged inside (-pi, pi]
    assert float(fn(-math.pi)) == pytest.approx(math.pi)


@pytest.mark.parametrize("rule_name", ["cubature", "merwe", "julier"])
def test_sigma_point_rules_reproduce_mean_and_covariance(rule_name):
    n = 5
    rule = {
        "cubature": cubature_rule(n),
        "merwe": scaled_unscented_rule(n, 0.5, 2.0, 0.0),
        "julier": scaled_unscented_rule(n, 1.0, 0.0, 3.0 - n),
    }[rule_name]
    rng = np.random.default_rng(3)
    B = rng.normal(size=(n, n))
    P = B @ B.T + np.eye(n)
    x = rng.normal(size=n)
    X = np.array(ca.DM(ca.evalf(rule.points(ca.DM(x), ca.DM(np.linalg.cholesky(P))))))
    wm = np.array([float(ca.evalf(w)) for w in rule.wm])
    wc = np.array([float(ca.evalf(w)) for w in rule.wc])
    assert wm.sum() == pytest.approx(1.0)
    mean = X @ wm
    D = X - mean[:, None]
    np.testing.assert_allclose(mean, x, atol=1e-12)
    # the centre point sits on the mean, so its covariance weight (which carries beta) does not matter
    np.testing.assert_allclose((D * wc) @ D.T, P, rtol=1e-10, atol=1e-10)
    assert rule.n_points == (2 * n if rule_name == "cubature" else 2 * n + 1)
