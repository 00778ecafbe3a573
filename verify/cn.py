"""`abyssal verify` section for seed 002 (cooperative navigation), on the cn2d bundle (IVBCKF on linear_cv).

* Per-particle proposal steps: the C runtime's ``ukf_predict``, ``ukf_update``, ``mcukf_update`` and
  ``huber_ukf_update`` (compiled.kalman.BatchStep) evaluated over 257 particles in one batched call
  (through ``ParallelBatch``, as the UPF/HRUPF/MCUPF use them) vs the same steps called particle by
  particle: <= 1e-12 (relative to the largest entry).
* Limits: the MCC update with sigma = 1e12 (C = 1 exactly in double), and the Huber update with gamma = 1e12, vs the plain
  UKF update: <= 1e-12.
* The MCC update vs a NumPy transcription of eqs. 36-39 (one fixed point: R~ = R / C with
  C = exp(-(z - z_pred)^2 / (2 R sigma^2)), capped at exponent 50) at innovations of 0.5, 5 and 40 m:
  <= 1e-9 relative.
* IVBCKF (runtime/filters/kalman/ivbckf.py: the runtime's cubature update inside the VB iteration) vs
  a NumPy transcription of the iteration of the paper's ref. 21 in linear Kalman form on the
  linear_cv model (where the cubature update is exact), with an outlier in the measurement:
  <= 1e-9 relative.
* kld_sample_size vs Fox's formula with scipy.stats.norm.ppf for k = 2..1000: exact.
"""
from __future__ import annotations

import math

import numpy as np

from .report import Check

MODEL = "cn2d"


def _rel(a, b) -> float:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return float(np.max(np.abs(a - b)) / max(1.0, float(np.max(np.abs(b)))))


def _particle_cloud(rng, N):
    x = np.asfortranarray(rng.normal([100.0, -50.0], 20.0, (N, 2)).T)
    A = rng.normal(0, 3.0, (N, 2, 2))
    P = np.asfortranarray(np.moveaxis(A @ np.swapaxes(A, 1, 2) + np.eye(2), 0, -1))
    return x, P


def batch_checks(bundle) -> list[Check]:
    from abyssal.runtime.compiled.batches import ParallelBatch
    from abyssal.runtime.compiled.kalman import BatchStep

    rng = np.random.default_rng(0)
    N = 257
    x, P = _particle_cloud(rng, N)
    # a ping of sensor leader0 (leader1 silent: its entry missing, mask 0)
    u, p, dt = np.array([1.5, 0.1, 0.3]), np.array([400.0, 300.0, -200.0, 100.0]), np.array([5.0])
    Q, R = np.diag([100.0, 100.0]), np.eye(2) * 0.1
    abk, z, mask = np.array([1.0, 0.0, 1.0]), np.array([480.0, 0.0]), np.array([1.0, 0.0])
    out = []
    xp, Pp, ok = np.zeros((2, N), order="F"), np.zeros((2, 2, N), order="F"), np.zeros((1, N), order="F")
    ParallelBatch(BatchStep(bundle, "ukf_predict"), [x, P, u, p, dt, Q.reshape(-1, order="F"), abk],
                  [True, True, False, False, False, False, False], [xp, Pp, ok], N)(N)
    single = BatchStep(bundle, "ukf_predict")
    err = max(max(_rel(np.ravel(r[0]), xp[:, j]), _rel(r[1], Pp[:, :, j]))
              for j in range(N) for r in [single(x[:, j], P[:, :, j], u, p, dt, Q, abk)])
    out.append(Check(MODEL, "ukf_predict_batch over 257 particles", "ukf_predict per particle", err, 1e-12))
    for name, extra in (("ukf_update", []), ("mcukf_update", [np.array([15.0])]), ("huber_ukf_update", [np.array([1.345])])):
        xo, Po = np.zeros((2, N), order="F"), np.zeros((2, 2, N), order="F")
        nu, S, ok = np.zeros((2, N), order="F"), np.zeros((2, 2, N), order="F"), np.zeros((1, N), order="F")
        ParallelBatch(BatchStep(bundle, name), [xp, Pp, z, p, R.reshape(-1, order="F"), mask, abk, *extra],
                      [True, True] + [False] * (5 + len(extra)), [xo, Po, nu, S, ok], N)(N)
        single = BatchStep(bundle, name)
        err = max(max(_rel(np.ravel(r[0]), xo[:, j]), _rel(r[1], Po[:, :, j]))
                  for j in range(N) for r in [single(xp[:, j], Pp[:, :, j], z, p, R, mask, abk, *extra)])
        out.append(Check(MODEL, f"{name}_batch over 257 particles", f"{name} per particle", err, 1e-12))
    return out


def limit_checks(bundle) -> list[Check]:
    x, P = np.array([100.0, -50.0]), np.array([[30.0, 5.0], [5.0, 20.0]])
    # a ping of sensor leader0 (leader1 silent: its entry missing, mask 0)
    p, R, mask, abk = np.array([400.0, 300.0, -200.0, 100.0]), np.eye(2) * 0.1, np.array([1.0, 0.0]), np.array([1.0, 0.0, 1.0])
    from abyssal.runtime.compiled.kalman import BatchStep

    ukf = BatchStep(bundle, "ukf_update")
    mcc, huber = BatchStep(bundle, "mcukf_update"), BatchStep(bundle, "huber_ukf_update")
    out = []
    z_pred = float(np.ravel(ukf(x, P, np.zeros(2), p, R, mask, abk)[2])[0]) * -1.0  # innovation of z = 0 is -z_pred
    for dz in (0.5, 5.0, 40.0):
        z = np.array([z_pred + dz, 0.0])
        plain = ukf(x, P, z, p, R, mask, abk)
        lim_m = mcc(x, P, z, p, R, mask, abk, np.array([1e12]))  # the call API refuses inf; C = 1 in double
        lim_h = huber(x, P, z, p, R, mask, abk, np.array([1e12]))
        out.append(Check(MODEL, f"mcukf_update, sigma = 1e12, innovation {dz:g} m", "ukf_update",
                         max(_rel(lim_m[0], plain[0]), _rel(lim_m[1], plain[1])), 1e-12))
        out.append(Check(MODEL, f"huber_ukf_update, gamma = 1e12, innovation {dz:g} m", "ukf_update",
                         max(_rel(lim_h[0], plain[0]), _rel(lim_h[1], plain[1])), 1e-12))
        # NumPy transcription of eqs. 36-39 (one fixed point) with the generated code's exponent cap
        sigma = 15.0
        plain_S = float(np.ravel(plain[3])[0])
        Pzz = plain_S - R[0, 0]
        nu = float(np.ravel(plain[2])[0])
        C = math.exp(-min(nu**2 / (R[0, 0] * 2 * sigma**2), 50.0))
        S = Pzz + R[0, 0] / C
        K_plain = (np.ravel(plain[0]) - x) / nu  # Pxz / S_plain
        Pxz = K_plain * plain_S
        x_ref = x + Pxz / S * nu
        P_ref = P - np.outer(Pxz, Pxz) / S
        got = mcc(x, P, z, p, R, mask, abk, np.array([sigma]))
        out.append(Check(MODEL, f"mcukf_update sigma = 15, innovation {dz:g} m", "NumPy eqs. 36-39 (R/C, capped)",
                         max(_rel(np.ravel(got[0]), x_ref), _rel(got[1], P_ref)), 1e-9))
    return out


def ivbckf_reference(x_prior, P_prior, z, H, R, iterations, chi=5.0, phi=1.0, kappa=5.0, zeta=1.0, u=8.0, t=5.0):
    """Ref. 21's iteration in linear Kalman form (independent NumPy transcription)."""
    from scipy.special import digamma

    n, m = x_prior.size, z.size
    U0, T0 = (u - n - 1) * P_prior, (t - m - 1) * R
    EPi, ERi = np.linalg.inv(P_prior), np.linalg.inv(R)
    Exi = Elam = 1.0
    Eom, Enu = chi / phi, kappa / zeta
    for _ in range(iterations):
        Pt, Rt = np.linalg.inv(EPi) / Exi, np.linalg.inv(ERi) / Elam
        S = H @ Pt @ H.T + Rt
        K = Pt @ H.T @ np.linalg.inv(S)
        x = x_prior + K @ (z - H @ x_prior)
        P = Pt - K @ S @ K.T
        A = np.outer(x - x_prior, x - x_prior) + P
        r = z - H @ x
        B = np.outer(r, r) + H @ P @ H.T
        eta, theta = (Eom + n) / 2, (Eom + np.trace(A @ EPi)) / 2
        Exi = eta / theta
        Eom = (chi + 0.5) / (phi + Exi / 2 - 0.5 - (digamma(eta) - math.log(theta)) / 2)
        eta_l, theta_l = (Enu + m) / 2, (Enu + np.trace(B @ ERi)) / 2
        Elam = eta_l / theta_l
        Enu = (kappa + 0.5) / (zeta + Elam / 2 - 0.5 - (digamma(eta_l) - math.log(theta_l)) / 2)
        EPi = (u - n) * np.linalg.inv(U0 + Exi * A)
        ERi = (t - m) * np.linalg.inv(T0 + Elam * B)
    return x, P


def ivbckf_checks() -> list[Check]:
    from abyssal.generated import load

    from abyssal.runtime.filters.kalman.ivbckf import IVBCKF

    lin = load("linear_cv")
    x0 = np.array([1.0, 2.0, 0.5, -0.3])
    P0 = np.diag([4.0, 4.0, 1.0, 1.0])
    Q, R = np.eye(4) * 0.1, np.eye(2) * 0.5
    u, dt = np.zeros(lin.n_u), 0.1
    out = []
    for label, z in (("inlier", np.array([1.2, 1.9])), ("outlier", np.array([15.0, 1.9]))):
        f = IVBCKF(lin, x0, P0, Q, R, u=8.0, t=5.0, iterations=10)  # the reference's u, t
        f.predict(u, dt)
        x_prior, P_prior = f.x, f.P
        f.update(z)
        H = lin.H(x_prior)
        x_ref, P_ref = ivbckf_reference(x_prior, P_prior, z, H, R, 10)
        out.append(Check("linear_cv", f"IVBCKF update, 10 iterations, {label}", "NumPy ref. 21 iteration (KF form)",
                         max(_rel(f.x, x_ref), _rel(f.P, P_ref)), 1e-9))
    return out


def kld_checks() -> list[Check]:
    from scipy.stats import norm

    from abyssal.runtime.resampling import kld_sample_size

    ks = np.arange(2, 1001)
    a = 2 / (9 * (ks - 1))
    ref = np.ceil((ks - 1) / (2 * 0.15) * (1 - a + np.sqrt(a) * norm.ppf(0.99)) ** 3)
    err = float(np.max(np.abs(kld_sample_size(ks, 0.15, 0.01) - ref)))
    return [Check(MODEL, "kld_sample_size, k = 2..1000", "Fox 2003 with scipy norm.ppf", err, 0.0)]


def checks(bundle, target=None) -> list[Check]:
    if bundle.name != MODEL or (target is not None and not getattr(target, "builtin", True)):
        return []
    return batch_checks(bundle) + limit_checks(bundle) + ivbckf_checks() + kld_checks()
