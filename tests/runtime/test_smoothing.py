"""Rauch-Tung-Striebel smoothing over the filter's history (filter.smooth(), the C runtime's abyssal_kalman_smooth),
against references that are not it:

* the exact Kalman smoother on the built-in linear_cv, written here from the textbook equations (with the input's
  B u in the prediction), for EKF, UKF and CKF (<= 1e-12: every rule is exact on a linear model);
* filterpy's KalmanFilter.rts_smoother on linear_cv without input (filterpy's smoother leaves B u out of its
  prediction, so it applies to an unforced model only), for the EKF;
* an unscented RTS smoother in NumPy written from Saerkkae (2008), "Unscented Rauch-Tung-Striebel smoother", IEEE
  Trans. Automatic Control 53(3), 845-849 (its backward recursion: sigma points of the filtered m_k, P_k through f,
  the predicted m-, P-, the cross-covariance C_{k+1}, the gain D_k = C_{k+1} (P-_{k+1})^-1), over a forward UKF/CKF
  also written here (Wan and van der Merwe's additive-noise form), on a nonlinear model (a damped pendulum with a
  nonlinear measurement), for the UKF and the CKF.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

import abyssal
from abyssal.runtime import CKF, EKF, UKF
from abyssal.symbolic import Model, Quantity, Sensor, symbols

DT = 0.5
STEPS = 40
SMOOTHING = dict(smoothing=True, history_entries=4 * STEPS + 4, history_seconds=1e6, gate_probability=0.0)


def per_step(t, x, P):
    """The smoothed state after each step's update (the last history row at each stamp): (STEPS + 1, ...)."""
    last = [int(np.flatnonzero(t == stamp)[-1]) for stamp in np.unique(t)]
    return x[last], P[last]


# ------------------------------------------------------------------------------------------ linear_cv

def linear_cv_run(cls, rng, with_input=True):
    model = abyssal.load("linear_cv")
    F = np.block([[np.eye(2), DT * np.eye(2)], [np.zeros((2, 2)), np.eye(2)]])
    B = np.vstack([DT ** 2 / 2 * np.eye(2), DT * np.eye(2)])
    H = np.hstack([np.eye(2), np.zeros((2, 2))])
    Q = np.diag([0.01, 0.01, 0.04, 0.04])
    R = np.diag([0.5, 0.3])
    x0, P0 = np.array([1.0, -2.0, 0.5, 0.2]), np.diag([4.0, 4.0, 1.0, 1.0])
    U = rng.normal(scale=0.3, size=(STEPS, 2)) if with_input else np.zeros((STEPS, 2))
    truth, Z = x0.copy(), []
    for k in range(STEPS):
        truth = F @ truth + B @ U[k] + rng.multivariate_normal(np.zeros(4), Q)
        Z.append(H @ truth + rng.multivariate_normal(np.zeros(2), R))
    flt = cls(model, x0, P0, Q, R, **SMOOTHING)
    for k in range(STEPS):
        flt.predict_to((k + 1) * DT, U[k])
        flt.update("measurement", Z[k], (k + 1) * DT)
    return flt, (F, B, H, Q, R, x0, P0, U, np.array(Z))


def exact_rts(F, B, H, Q, R, x0, P0, U, Z):
    """The Kalman filter and the RTS smoother (Rauch, Tung and Striebel 1965) on x+ = F x + B u + w, z = H x + v."""
    xs, Ps, preds = [x0], [P0], []
    x, P = x0, P0
    for u, z in zip(U, Z):
        x_pred, P_pred = F @ x + B @ u, F @ P @ F.T + Q
        preds.append((x_pred, P_pred))
        S = H @ P_pred @ H.T + R
        K = P_pred @ H.T @ np.linalg.inv(S)
        x, P = x_pred + K @ (z - H @ x_pred), (np.eye(4) - K @ H) @ P_pred
        xs.append(x)
        Ps.append(P)
    x_s, P_s = [xs[-1]], [Ps[-1]]
    for k in range(len(U) - 1, -1, -1):
        x_pred, P_pred = preds[k]
        G = Ps[k] @ F.T @ np.linalg.inv(P_pred)
        x_s.insert(0, xs[k] + G @ (x_s[0] - x_pred))
        P_s.insert(0, Ps[k] + G @ (P_s[0] - P_pred) @ G.T)
    return np.array(xs), np.array(Ps), np.array(x_s), np.array(P_s)


@pytest.mark.parametrize("cls", [EKF, UKF, CKF])
def test_smoothing_linear_cv_equals_the_exact_rts_smoother(cls):
    flt, args = linear_cv_run(cls, np.random.default_rng(7))
    t, x, P = flt.smooth()
    x, P = per_step(t, x, P)
    _, _, x_ref, P_ref = exact_rts(*args)
    assert x.shape == x_ref.shape == (STEPS + 1, 4)
    assert np.abs(x - x_ref).max() <= 1e-12 * np.abs(x_ref).max()
    assert np.abs(P - P_ref).max() <= 1e-12 * np.abs(P_ref).max()
    assert np.all(np.diagonal(P, axis1=1, axis2=2)[:-1] < np.diagonal(exact_rts(*args)[1], axis1=1, axis2=2)[:-1])


def test_smoothing_linear_cv_equals_filterpy_rts_smoother():
    kalman = pytest.importorskip("filterpy.kalman", reason="filterpy (the test extra) is not installed")
    flt, (F, B, H, Q, R, x0, P0, U, Z) = linear_cv_run(EKF, np.random.default_rng(8), with_input=False)
    kf = kalman.KalmanFilter(dim_x=4, dim_z=2)
    kf.F, kf.H, kf.Q, kf.R, kf.x, kf.P = F, H, Q, R, x0.copy(), P0.copy()
    Xs, Ps = [x0.copy()], [P0.copy()]
    for z in Z:
        kf.predict()
        kf.update(z)
        Xs.append(kf.x.copy())
        Ps.append(kf.P.copy())
    x_ref, P_ref, _, _ = kf.rts_smoother(np.array(Xs), np.array(Ps))
    t, x, P = flt.smooth()
    x, P = per_step(t, x, P)
    assert np.abs(x - x_ref).max() <= 1e-12 * np.abs(x_ref).max()
    assert np.abs(P - P_ref).max() <= 1e-12 * np.abs(P_ref).max()


# ------------------------------------------------------------------------------------------ a nonlinear model

def pendulum() -> Model:
    """A damped pendulum driven by a torque; measured: the bob's horizontal position and the rate."""
    states = (Quantity("angle", "rad"), Quantity("rate", "rad/s"))
    x, u = symbols("x", states), symbols("u", (Quantity("torque", "rad/s^2"),))
    sensor = Sensor(name="bob", outputs=(Quantity("horizontal", "m"), Quantity("rate", "rad/s")),
                    y=ca.vertcat(2.0 * ca.sin(x[0]), x[1]))
    return Model(name="pendulum", states=states, inputs=(Quantity("torque", "rad/s^2"),), x=x, u=u,
                 xdot=ca.vertcat(x[1], -9.81 / 2.0 * ca.sin(x[0]) - 0.3 * x[1] + u[0]), sensors=(sensor,),
                 discretisation="rk4", substeps=2)


@pytest.fixture(scope="module")
def swing(tmp_path_factory):
    return abyssal.load(abyssal.generate(pendulum(), tmp_path_factory.mktemp("pendulum") / "gen"))


def sigma_rule(kind: str, n: int, alpha=1.0, beta=2.0, kappa=0.0):
    """(spread c, mean weights, covariance weights) of the point set x, x +- sqrt(c) L e_i (UKF: Julier's scaled
    points with the centre; CKF: the 2n cubature points, equal weights)."""
    if kind == "ckf":
        w = np.full(2 * n, 1 / (2 * n))
        return float(n), w, w, False
    c = alpha ** 2 * (n + kappa)
    wm = np.r_[(c - n) / c, np.full(2 * n, 1 / (2 * c))]
    wc = wm.copy()
    wc[0] += 1 - alpha ** 2 + beta
    return c, wm, wc, True


def points(x, P, c, centre):
    L = np.linalg.cholesky(P)
    offsets = np.sqrt(c) * L.T  # rows: sqrt(c) L e_i
    X = np.vstack([x + offsets, x - offsets])
    return np.vstack([x, X]) if centre else X


def unscented_smoother(model, kind, x0, P0, Q, R, U, Z, dt):
    """A forward unscented/cubature Kalman filter and Saerkkae's unscented RTS smoother (module docstring)."""
    n = len(x0)
    c, wm, wc, centre = sigma_rule(kind, n)

    def f(X, u):
        return np.array([model.f(xi, u, None, dt) for xi in X])

    def h(X):
        return np.array([model.h(xi) for xi in X])

    m, P = x0.copy(), P0.copy()
    filtered = [(m, P)]
    for u, z in zip(U, Z):
        Y = f(points(m, P, c, centre), u)
        m_pred = wm @ Y
        P_pred = (Y - m_pred).T @ np.diag(wc) @ (Y - m_pred) + Q
        X = points(m_pred, P_pred, c, centre)
        Zs = h(X)
        mu = wm @ Zs
        S = (Zs - mu).T @ np.diag(wc) @ (Zs - mu) + R
        C = (X - m_pred).T @ np.diag(wc) @ (Zs - mu)
        K = C @ np.linalg.inv(S)
        m, P = m_pred + K @ (z - mu), P_pred - K @ S @ K.T
        filtered.append((m, P))
    smoothed = [filtered[-1]]
    for k in range(len(U) - 1, -1, -1):  # Saerkkae (2008): the backward recursion
        m_k, P_k = filtered[k]
        X = points(m_k, P_k, c, centre)
        Y = f(X, U[k])
        m_pred = wm @ Y
        P_pred = (Y - m_pred).T @ np.diag(wc) @ (Y - m_pred) + Q
        C = (X - m_k).T @ np.diag(wc) @ (Y - m_pred)
        D = C @ np.linalg.inv(P_pred)
        m_next, P_next = smoothed[0]
        smoothed.insert(0, (m_k + D @ (m_next - m_pred), P_k + D @ (P_next - P_pred) @ D.T))
    return (np.array([m for m, _ in filtered]), np.array([P for _, P in filtered]),
            np.array([m for m, _ in smoothed]), np.array([P for _, P in smoothed]))


@pytest.mark.parametrize("cls", [UKF, CKF])
def test_sigma_point_smoothing_equals_the_unscented_rts_smoother(swing, cls):
    rng = np.random.default_rng(9)
    dt = 0.2
    Q, R = np.diag([1e-4, 4e-3]), np.diag([0.02, 0.05])
    x0, P0 = np.array([1.2, 0.0]), np.diag([0.2, 0.3])
    U = 0.5 * np.sin(0.3 * np.arange(STEPS))[:, None]
    truth, Z = np.array([1.0, 0.3]), []
    for k in range(STEPS):
        truth = swing.f(truth, U[k], None, dt) + rng.multivariate_normal(np.zeros(2), Q)
        Z.append(swing.h(truth) + rng.multivariate_normal(np.zeros(2), R))
    flt = cls(swing, x0, P0, Q, R, **SMOOTHING)
    filtered = [flt.x]
    for k in range(STEPS):
        flt.predict_to((k + 1) * dt, U[k])
        flt.update("bob", Z[k], (k + 1) * dt)
        filtered.append(flt.x)
    m_ref, _, ms_ref, Ps_ref = unscented_smoother(swing, cls.kind, x0, P0, Q, R, U, Z, dt)
    assert np.abs(np.array(filtered) - m_ref).max() <= 1e-12   # the forward pass first
    t, x, P = flt.smooth()
    x, P = per_step(t, x, P)
    assert np.abs(x - ms_ref).max() <= 1e-12 * np.abs(ms_ref).max()
    assert np.abs(P - Ps_ref).max() <= 1e-12 * np.abs(Ps_ref).max()
    # and the smoother moved something: the unscented gain is not the filter's estimate
    assert np.abs(x - m_ref).max() > 1e-3
