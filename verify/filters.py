"""`abyssal verify` section: the filters (the C runtime's algebra on the model's generated f, F, h, H,
through the runtime classes) against reference numerics they were not produced by.

Checks per model (errors are max |difference| / max(1, max |reference|) over a short
simulated run of STEPS predict+update steps):

* CKF   == filterpy UnscentedKalmanFilter with MerweScaledSigmaPoints(alpha=1, beta=0, kappa=0)
           (the cubature rule plus a centre point of weight zero);
* UKF   == filterpy UnscentedKalmanFilter with MerweScaledSigmaPoints(alpha, beta, kappa), for
           two parameter sets;
* EKF   == filterpy ExtendedKalmanFilter (its predict_x replaced by the model's f, F from the
           bundle; filterpy's update is the Joseph form too);
* masked update == the filterpy CKF update on the measurement with the masked entries removed;
* a linear model (F and H constant, found numerically, e.g. linear_cv): EKF, UKF and CKF == the
  exact Kalman filter (NumPy, written here); any other model: EKF == the exact Kalman filter of
  the model linearised at each estimate (F, H from the bundle, already checked against central
  differences), an oracle that needs no filterpy;
* CKF, UKF and the masked update == a sigma-point Kalman filter written here in NumPy over the compiled f and h
  (``numpy_sigma_point_run``, Merwe's scaled points from the lower Cholesky factor, as filterpy's): the oracle of
  every model that needs no filterpy and reuses the model's loaded build (it once generated and compiled a
  linearised copy of a user's model for the exact Kalman filter: 1.3-1.7 MB of C compiled a second time);
* MCUKF with sigma = inf and HuberUKF with gamma = inf == UKF (the robust updates' limits);
* step() (one transaction of the runtime) == predict then update.

Our sigma-point updates redraw the points from the predicted mean and covariance, while
filterpy reuses the propagated points; the oracles are configured the same way (filterpy's by setting
``sigmas_f`` from the predicted (x, P) before each update). Angle outputs use the
same residual (wrapped to (-pi, pi]) on both sides. filterpy is a test-only dependency,
imported here lazily; if it is missing, the checks that need it are reported as skipped.
"""
from __future__ import annotations

import importlib.util
import math
from dataclasses import dataclass

import numpy as np

from abyssal.runtime.filters.kalman import CKF, EKF, MCUKF, UKF, HuberUKF
from abyssal.runtime.numerics import relative_error, wrap_to_pi as wrap

from .report import Check

STEPS = 15
TOLERANCE = 1e-12
UKF_PARAMETERS = ((1.0, 2.0, 0.0), (0.5, 2.0, 1.0))


def measurement_residual(angle_outputs):
    def residual(a, b):
        d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
        for i in angle_outputs:
            d[..., i] = wrap(d[..., i])
        return d
    return residual


@dataclass
class Scenario:
    """A short simulated run: inputs, parameters, measurements and noise matrices."""

    x0: np.ndarray
    P0: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    p: np.ndarray
    dt: float
    U: np.ndarray
    Z: np.ndarray


def scenario(bundle, steps: int = STEPS, seed: int = 7) -> Scenario:
    rng = np.random.default_rng(seed)
    n, m = bundle.n_x, bundle.n_y
    p = bundle.params()
    if bundle.name == "cn2d":
        p = np.array([40.0, -25.0, -30.0, 35.0])  # leaders away from the follower: the ranges are smooth
    x0 = rng.uniform(0.5, 2.0, n)
    A = rng.normal(size=(n, n)) * 0.05
    P0 = 0.2 * np.eye(n) + A @ A.T
    Q = 1e-3 * np.eye(n)
    R = 0.02 * np.eye(m)
    dt = 0.1
    U = rng.normal(size=(steps, bundle.n_u))
    if not _builtin(bundle):
        # a user's model, inside its sampling box (its declared envelope, or the box verify derives about its rest
        # state, with a dt its discretisation is stable at): start in the middle half of each state's range, inputs
        # in the middle half of theirs, dt inside [min_dt, max_dt]
        from .models import SamplingBox

        box = SamplingBox(bundle)
        mid, half = (box.x_low + box.x_high) / 2, (box.x_high - box.x_low) / 2
        x0 = mid + half * rng.uniform(-0.5, 0.5, n)
        P0 = np.diag((0.05 * half) ** 2) + (0.05 * half[:, None]) * (A @ A.T) * (0.05 * half[None, :])
        u_mid, u_half = (box.u_low + box.u_high) / 2, (box.u_high - box.u_low) / 2
        U = u_mid + u_half * rng.uniform(-0.5, 0.5, (steps, bundle.n_u))
        dt = box.clip_dt(dt)
    if bundle.name == "remus100":  # Euler angles: keep the points far from theta = +-90 deg; cruise at ~1500 rpm
        x0 = np.array([1.4, 0.05, 0.02, 0.01, 0.01, 0.05, 60.0, 3.0, 5.0, 0.02, 0.05, 2.0]) + 0.01 * rng.normal(size=n)
        P0 = 0.01 * np.eye(n) + 0.01 * A @ A.T
        U = np.column_stack([1500 + 100 * rng.normal(size=steps), rng.normal(size=steps), rng.normal(size=steps)])
    x = x0 + np.linalg.cholesky(P0) @ rng.normal(size=n)
    Z = np.empty((steps, m))
    for k in range(steps):
        x = bundle.f(x, U[k], p, dt) + np.linalg.cholesky(Q) @ rng.normal(size=n)
        Z[k] = bundle.h(x, p) + np.sqrt(0.02) * rng.normal(size=m)
    return Scenario(x0, P0, Q, R, p, dt, U, Z)


def _builtin(bundle) -> bool:
    from .models import _builtin_bundle

    return _builtin_bundle(bundle)


def run_ours(flt, sc: Scenario, mask_entries=None):
    """(x, P) after every step of a runtime filter."""
    out = []
    for k in range(len(sc.U)):
        flt.predict(sc.U[k], sc.dt, sc.p)
        z = sc.Z[k].copy()
        if mask_entries is not None:
            z[mask_entries] = np.nan
        flt.update(z, sc.p)
        out.append((flt.x, flt.P))
    return out


def run_ours_fused(flt, sc: Scenario):
    """(x, P) after every step() (predict and update in one call of the runtime)."""
    out = []
    for k in range(len(sc.U)):
        flt.step(sc.U[k], sc.dt, sc.Z[k], sc.p)
        out.append((flt.x, flt.P))
    return out


def filterpy_sigma_point_run(bundle, sc: Scenario, alpha, beta, kappa, kept=None):
    """(x, P) after every step of filterpy's UKF, points redrawn before each update."""
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    kept = list(range(bundle.n_y)) if kept is None else list(kept)
    angles = [kept.index(i) for i in bundle.angle_outputs if i in kept]
    points = MerweScaledSigmaPoints(bundle.n_x, alpha=alpha, beta=beta, kappa=kappa)
    ukf = UnscentedKalmanFilter(bundle.n_x, len(kept), sc.dt, hx=lambda s: bundle.h(s, sc.p)[kept],
                                fx=None, points=points, residual_z=measurement_residual(angles))
    ukf.x, ukf.P, ukf.Q, ukf.R = sc.x0.copy(), sc.P0.copy(), sc.Q.copy(), sc.R[np.ix_(kept, kept)].copy()
    out = []
    for k in range(len(sc.U)):
        ukf.predict(dt=sc.dt, fx=lambda s, dt, u=sc.U[k]: bundle.f(s, u, sc.p, dt))
        ukf.sigmas_f = points.sigma_points(ukf.x, ukf.P)  # redraw from the prediction, as our update does
        ukf.update(sc.Z[k][kept])
        out.append((ukf.x.copy(), ukf.P.copy()))
    return out


def numpy_sigma_point_run(bundle, sc: Scenario, alpha, beta, kappa, kept=None):
    """(x, P) after every step of a sigma-point Kalman filter written here in NumPy on the compiled f and h: Merwe's
    scaled points x +- sqrt(n + lambda) L e_i (L the lower Cholesky factor, as filterpy's), lambda = alpha^2 (n +
    kappa) - n, mean weights lambda / (n + lambda) and 1 / (2 (n + lambda)), the centre's covariance weight plus
    1 - alpha^2 + beta; the points redrawn from the prediction before the update; angle outputs' residuals wrapped;
    only the `kept` entries of z used."""
    n = bundle.n_x
    kept = list(range(bundle.n_y)) if kept is None else list(kept)
    angles = [kept.index(i) for i in bundle.angle_outputs if i in kept]
    residual = measurement_residual(angles)
    lam = alpha**2 * (n + kappa) - n
    wm = np.full(2 * n + 1, 1.0 / (2 * (n + lam)))
    wm[0] = lam / (n + lam)
    wc = wm.copy()
    wc[0] += 1.0 - alpha**2 + beta

    def points(x, P):
        L = np.linalg.cholesky((n + lam) * P)
        return np.column_stack([x, x[:, None] + L, x[:, None] - L])  # (n, 2n + 1)

    x, P = sc.x0.copy(), sc.P0.copy()
    R = sc.R[np.ix_(kept, kept)]
    out = []
    for k in range(len(sc.U)):
        X = np.column_stack([bundle.f(c, sc.U[k], sc.p, sc.dt) for c in points(x, P).T])
        x = X @ wm
        D = X - x[:, None]
        P = (D * wc) @ D.T + sc.Q
        X = points(x, P)
        Z = np.column_stack([bundle.h(c, sc.p)[kept] for c in X.T])
        z_mean = Z @ wm
        E = residual(Z.T, z_mean).T
        D = X - x[:, None]
        S = (E * wc) @ E.T + R
        K = np.linalg.solve(S, ((D * wc) @ E.T).T).T
        x = x + K @ residual(sc.Z[k][kept], z_mean)
        P = P - K @ S @ K.T
        out.append((x.copy(), P.copy()))
    return out


def filterpy_ekf_run(bundle, sc: Scenario):
    from filterpy.kalman import ExtendedKalmanFilter

    class ModelEKF(ExtendedKalmanFilter):
        def predict_x(self, u=0):
            self.x = bundle.f(self.x, u, sc.p, sc.dt)

    ekf = ModelEKF(bundle.n_x, bundle.n_y)
    ekf.x, ekf.P, ekf.Q, ekf.R = sc.x0.copy(), sc.P0.copy(), sc.Q.copy(), sc.R.copy()
    residual = measurement_residual(bundle.angle_outputs)
    out = []
    for k in range(len(sc.U)):
        ekf.F = bundle.F(ekf.x, sc.U[k], sc.p, sc.dt)
        ekf.predict(sc.U[k])
        ekf.update(sc.Z[k], HJacobian=lambda s: bundle.H(s, sc.p), Hx=lambda s: bundle.h(s, sc.p), residual=residual)
        out.append((ekf.x.copy(), ekf.P.copy()))
    return out


def exact_kalman_run(bundle, sc: Scenario):
    """The Kalman filter of a linear model x' = A x + B u, z = C x + d (A, C from the bundle's Jacobians)."""
    n = bundle.n_x
    x, P = sc.x0.copy(), sc.P0.copy()
    out = []
    for k in range(len(sc.U)):
        A = bundle.F(x, sc.U[k], sc.p, sc.dt)
        x = bundle.f(x, sc.U[k], sc.p, sc.dt)  # = A x + B u exactly for a linear model
        P = A @ P @ A.T + sc.Q
        C = bundle.H(x, sc.p)
        S = C @ P @ C.T + sc.R
        K = np.linalg.solve(S, C @ P).T
        x = x + K @ (sc.Z[k] - bundle.h(x, sc.p))
        IKC = np.eye(n) - K @ C
        P = IKC @ P @ IKC.T + K @ sc.R @ K.T
        out.append((x, P))
    return out


def compare(model: str, name: str, reference: str, ours, theirs, tolerance: float = TOLERANCE) -> Check:
    error = max(max(relative_error(a[0], b[0]), relative_error(a[1], b[1])) for a, b in zip(ours, theirs))
    return Check(model, name, reference, error, tolerance, detail=f"max relative error of x and P over {len(ours)} steps")


def _is_linear(bundle, sc: Scenario) -> bool:
    """F and H the same at two distant points: the model is linear (affine), so the Kalman filter is exact."""
    rng = np.random.default_rng(11)
    a, b = rng.normal(size=bundle.n_x), 3 * rng.normal(size=bundle.n_x)
    same = lambda s, t: np.allclose(s, t, rtol=1e-12, atol=1e-12)  # noqa: E731
    return same(bundle.F(a, sc.U[0], sc.p, sc.dt), bundle.F(b, sc.U[1], sc.p, sc.dt)) and same(
        bundle.H(a, sc.p), bundle.H(b, sc.p))


def checks(bundle, target=None) -> list[Check]:
    """The filter checks (every filter runs on every model: the algebra is the C runtime's)."""
    model = bundle.name
    result = []
    sc = scenario(bundle)
    args = (bundle, sc.x0, sc.P0, sc.Q, sc.R)
    ekf, ukf, ckf = run_ours(EKF(*args), sc), run_ours(UKF(*args), sc), run_ours(CKF(*args), sc)
    oracles = [("a NumPy sigma-point filter", "NumPy sigma-point filter", numpy_sigma_point_run)]
    if importlib.util.find_spec("filterpy") is None:
        result.append(Check.skip(model, "filters vs filterpy", "filterpy",
                                 "filterpy is not installed: pip install 'abyssal[test]' (a test-only dependency; the "
                                 "NumPy sigma-point oracle still runs)"))
    else:
        oracles.append(("filterpy", "filterpy UKF", filterpy_sigma_point_run))
    for label, reference, oracle in oracles:
        suffix = "" if label == "filterpy" else f" vs {label}"
        result.append(compare(model, f"ckf step{suffix}", f"{reference}, Merwe(1, 0, 0)", ckf,
                              oracle(bundle, sc, 1.0, 0.0, 0.0)))
        for a, b, k in UKF_PARAMETERS:
            result.append(compare(model, f"ukf step ({a:g}, {b:g}, {k:g}){suffix}",
                                  f"{reference}, Merwe({a:g}, {b:g}, {k:g})",
                                  run_ours(UKF(*args, alpha=a, beta=b, kappa=k), sc), oracle(bundle, sc, a, b, k)))
        if bundle.n_y > 1:
            masked = [bundle.n_y - 1]
            kept = [i for i in range(bundle.n_y) if i not in masked]
            result.append(compare(model, f"ckf masked update{suffix}", f"{reference} on the kept entries",
                                  run_ours(CKF(*args), sc, mask_entries=masked),
                                  oracle(bundle, sc, 1.0, 0.0, 0.0, kept=kept)))
    if importlib.util.find_spec("filterpy") is not None:
        result.append(compare(model, "ekf step (Joseph)", "filterpy ExtendedKalmanFilter", ekf, filterpy_ekf_run(bundle, sc)))
    exact = exact_kalman_run(bundle, sc)
    if _is_linear(bundle, sc):
        for family, ours in (("ekf", ekf), ("ukf", ukf), ("ckf", ckf)):
            result.append(compare(model, f"{family} on a linear model", "exact Kalman filter", ours, exact))
    else:
        result.append(compare(model, "ekf step vs Kalman filter of the linearised model", "exact Kalman filter "
                              "(NumPy) on F, H at each estimate", ekf, exact))
    result.append(compare(model, "ckf step()", "ckf predict then update", run_ours_fused(CKF(*args), sc), ckf))
    result.append(compare(model, "ekf step()", "ekf predict then update", run_ours_fused(EKF(*args), sc), ekf))
    result.append(compare(model, "mcukf, sigma = inf", "ukf step", run_ours(MCUKF(*args, sigma=math.inf), sc), ukf))
    result.append(compare(model, "huber ukf, gamma = inf", "ukf step", run_ours(HuberUKF(*args, gamma=math.inf), sc), ukf))
    return result
