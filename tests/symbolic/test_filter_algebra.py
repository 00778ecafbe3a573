"""The symbolic filter algebra, evaluated by CasADi itself (no compilation)."""
import math

import casadi as ca
import numpy as np
import pytest

from abyssal.symbolic.filters import filter_units
from abyssal.symbolic.filters.linalg import cholesky_solve, guarded_cholesky, wrap_angle
from abyssal.symbolic.filters.robust import correntropy_noise, huber_noise
from abyssal.symbolic.filters.sigma_points import cubature_rule, scaled_unscented_rule
from abyssal.symbolic.models import REGISTRY


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


def robust_inflation(noise, R, innovation, Pzz):
    m = len(innovation)
    a_sym, nu, pzz = ca.SX.sym("a", m, m), ca.SX.sym("nu", m), ca.SX.sym("Pzz", m, m)
    fn = ca.Function("noise", [a_sym, pzz, nu], [noise(a_sym, pzz, nu)])
    return np.array(fn(np.linalg.cholesky(R), Pzz, innovation))


def test_correntropy_inflates_outlier_entries_only_and_vanishes_as_sigma_grows():
    R = np.diag([0.5, 2.0])
    Pzz = np.eye(2) * 0.1
    innovation = np.array([0.1, 40.0])  # second entry: a 28-sigma outlier
    R_tilde = robust_inflation(correntropy_noise(2.0), R, innovation, Pzz)
    assert R_tilde[0, 0] == pytest.approx(R[0, 0] * math.exp(0.1**2 / 0.5 / 8), rel=1e-12)
    assert R_tilde[1, 1] > 1e3 * R[1, 1]  # inflated by orders of magnitude
    np.testing.assert_allclose(robust_inflation(correntropy_noise(math.inf), R, innovation, Pzz), R, rtol=1e-15)


def test_huber_keeps_inliers_and_inflates_outliers():
    R = np.diag([0.5, 2.0])
    Pzz = np.eye(2) * 0.1
    inlier = np.array([0.1, -0.2])
    np.testing.assert_allclose(robust_inflation(huber_noise(1.345), R, inlier, Pzz), R, rtol=1e-15)
    R_tilde = robust_inflation(huber_noise(1.345), R, np.array([0.1, 40.0]), Pzz)
    assert R_tilde[0, 0] == pytest.approx(R[0, 0])
    assert R_tilde[1, 1] > 10 * R[1, 1]
    np.testing.assert_allclose(robust_inflation(huber_noise(math.inf), R, np.array([0.1, 40.0]), Pzz), R, rtol=1e-15)


def test_filter_units_follow_the_naming_contract():
    model = REGISTRY["cn2d"]()
    units = {u.name: u for u in filter_units(model)}
    assert set(units) == {"ekf", "sigma_points"}  # fused steps beside their predict and update; the EKF's file holds F
    functions = {fn.name(): fn for u in units.values() for fn in u.functions}
    predict_in = ["x", "P", "u", "p", "dt", "Q"]
    update_in = ["x", "P", "z", "p", "R", "mask"]
    predict_out = ["x_pred", "P_pred", "ok"]
    update_out = ["x_post", "P_post", "innovation", "S", "ok"]
    expected = {
        "cn2d_ekf_predict": (predict_in, predict_out), "cn2d_ekf_update": (update_in, update_out),
        "cn2d_ckf_predict": (predict_in, predict_out), "cn2d_ckf_update": (update_in, update_out),
        "cn2d_ukf_predict": (predict_in + ["abk"], predict_out), "cn2d_ukf_update": (update_in + ["abk"], update_out),
        "cn2d_mcukf_update": (update_in + ["abk", "sigma"], update_out),
        "cn2d_huber_ukf_update": (update_in + ["abk", "gamma"], update_out),
        "cn2d_ekf_step": (predict_in + ["z", "R", "mask"], update_out),
        "cn2d_F": (["x", "u", "p", "dt"], ["dfdx"]),
        "cn2d_ckf_step": (predict_in + ["z", "R", "mask"], update_out),
        # the rule of a sigma-point predict, for the C runtime (it propagates X through the SIMD kernel)
        "cn2d_ckf_predict_points": (["x", "P"], ["X", "ok"]), "cn2d_ckf_predict_weights": ([], ["wm", "wc"]),
        "cn2d_ukf_predict_points": (["x", "P", "abk"], ["X", "ok"]), "cn2d_ukf_predict_weights": (["abk"], ["wm", "wc"]),
    }
    assert set(functions) == set(expected)
    for name, (ins, outs) in expected.items():
        fn = functions[name]
        assert fn.name_in() == ins and fn.name_out() == outs, name
        if name == "cn2d_F":
            assert fn.size_out(0) == (model.n_x, model.n_x)
            continue
        if name.endswith("_predict_points"):  # the points as rows: the SIMD kernel's layout
            points = 2 * model.n_x + ("ukf" in name)
            assert fn.size_out("X") == (points, model.n_x) and fn.size_out("ok") == (1, 1)
            continue
        if name.endswith("_predict_weights"):
            assert fn.size_out("wm") == fn.size_out("wc") == (2 * model.n_x + ("ukf" in name), 1)
            continue
        assert fn.size_out("ok") == (1, 1)
        assert fn.size_out(1) == (model.n_x, model.n_x)


def test_shared_reciprocals_remove_divisions_and_keep_values():
    from abyssal.symbolic.filters.reciprocals import share_reciprocals

    x, b = ca.SX.sym("x", 3), ca.SX.sym("b")
    fn = ca.Function("f", [x, b], [ca.vertcat(x[0] / b, x[1] / b, (x[2] + 1) / (b * b), x[0] / 6)], ["x", "b"], ["y"])
    shared = share_reciprocals(fn)
    divisions = [k for k in range(shared.n_instructions()) if shared.instruction_id(k) == ca.OP_DIV]
    assert not divisions
    assert shared.name_in() == ["x", "b"] and shared.name_out() == ["y"]
    for args in ([1.0, 2.0, 3.0], 0.7), ([0.0, -1.0, 5.0], -3.0):
        np.testing.assert_allclose(np.array(shared(*args)), np.array(fn(*args)), rtol=1e-15)
    assert np.isinf(np.array(shared([1.0, 1.0, 1.0], 0.0))[0])  # division by zero still gives inf
