"""IVBCKF: the iterated variational-Bayes Student-t cubature Kalman filter (seed 002 ref. 21).

Huang, Zhang, Xu, Wu & Chambers 2017 (IEEE/ASME TMech): the prior covariance and the measurement
covariance are scaled by Gamma-distributed factors xi and lambda whose degrees of freedom omega and
nu are themselves Gamma-distributed, with inverse-Wishart conjugate priors on the two scale
matrices. Seed 002's prior parameters: chi = kappa = 5 (Gamma shapes of omega, nu), phi = zeta = 1
(their rates), u = 8 and t = 5 (inverse-Wishart degrees of freedom of the prior and likelihood
scale matrices: u = n + 1 + tau_P, t = m + 1 + tau_R, so tau_P = 5, tau_R = 3 for n = 2, m = 1).

One step: the generated cubature predict ``<m>_ckf_predict`` gives (x^-, P^-); then with
U0 = tau_P P^-, T0 = tau_R R, E[P^-1] = P^-^-1, E[R^-1] = R^-1, E[xi] = E[lambda] = 1,
E[omega] = chi / phi, E[nu] = kappa / zeta, ``iterations`` (default 10, ours) fixed-point passes:

    P~ = E[P^-1]^-1 / E[xi],  R~ = E[R^-1]^-1 / E[lambda]
    (x, P) = <m>_ckf_update(x^-, P~, z, p, R~)                          (generated C)
    A = (x - x^-)(x - x^-)^T + P;  B = E[(z - h(x))(z - h(x))^T]          (cubature points of N(x, P))
    eta = (E[omega] + n) / 2, theta = (E[omega] + tr(A E[P^-1])) / 2;  E[xi] = eta / theta
    E[lambda] = (E[nu] + m) / (E[nu] + tr(B E[R^-1]))
    E[omega] = (chi + 1/2) / (phi + E[xi] / 2 - 1/2 - (psi(eta) - ln theta) / 2)   (same for nu)
    E[P^-1] = (u - n) (U0 + E[xi] A)^-1,  E[R^-1] = (t - m) (T0 + E[lambda] B)^-1

The "- 1/2" in the rate of omega comes from Stirling's approximation of log Gamma(omega / 2) (a
copy of the authors' code has "+ 1/2"; the derivation gives "- 1/2", which keeps the rate >= phi
because E[xi] - E[ln xi] >= 1). The update and h run in generated C; the iteration's small
matrix algebra is NumPy (n = 2, m = 1 here).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.special import digamma

from ...contract import (ConcurrencyGuard, FilterBase, check_covariance, check_dt, check_p, check_state, check_u,
                         check_z, register)
from ...numerics import REPAIR_FLOOR, repair_covariance

__all__ = ["IVBCKF"]


@register("kalman")
class IVBCKF(FilterBase):
    """Iterated VB Student-t CKF (module docstring); Kalman constructor (model, x0, P0, Q, R, **options)."""

    name = "IVBCKF"

    def __init__(self, model, x0, P0, Q, R, *, chi: float = 5.0, phi: float = 1.0, kappa: float = 5.0,
                 zeta: float = 1.0, u: float = 8.0, t: float = 5.0, iterations: int = 10):
        n, m = model.n_x, model.n_y
        self.model = model
        self._x, self._P = check_state(x0, n, "x0"), check_covariance(P0, n, "P0")
        self.Q = check_covariance(Q, n, "Q")
        self.R = check_covariance(R, m, "R", definite=True)
        if not (u > n + 1 and t > m + 1 and iterations >= 1):
            raise ValueError(f"IVBCKF needs u > n + 1 = {n + 1}, t > m + 1 = {m + 1} and iterations >= 1")
        self.chi, self.phi, self.kappa, self.zeta, self.u, self.t = chi, phi, kappa, zeta, u, t
        self.iterations = int(iterations)
        self._predict_fn = model.function("ckf_predict")
        self._update_fn = model.function("ckf_update")
        self._h = model.function("h")
        self.nis, self.nis_dof = math.nan, 0
        self.xi, self.lam = 1.0, 1.0  # the last step's E[xi], E[lambda] (for inspection)
        self._guard = ConcurrencyGuard(type(self).__name__)

    @property
    def x(self) -> np.ndarray:
        return self._x.copy()

    @property
    def P(self) -> np.ndarray:
        return self._P.copy()

    def checkpoint(self):
        return self._x.copy(), self._P.copy(), self.nis, self.nis_dof, self.xi, self.lam

    def restore(self, state) -> None:
        x, P, self.nis, self.nis_dof, self.xi, self.lam = state
        self._x, self._P = x.copy(), P.copy()

    def _p(self, p):
        return np.array(self.model.p_default) if p is None else p

    def predict(self, u, dt, p=None) -> None:
        u, dt, p = check_u(u, self.model.n_u), check_dt(dt), check_p(p, self.model)
        with self._guard:
            self._predict(u, dt, p)

    def _predict(self, u, dt, p) -> None:
        P0 = self._P
        x, P, ok = self._predict_fn(self._x, P0, u, self._p(p), dt, self.Q)
        if not ok:  # a singular P (e.g. P0 = 0) has no cubature factor: its nearest positive definite matrix
            floor = max(float(np.max(np.abs(P0))), float(np.max(np.abs(self.Q))), 1e-300)
            P0 = repair_covariance(P0) if np.any(P0) else np.eye(P0.shape[0]) * REPAIR_FLOOR * floor
            x, P, ok = self._predict_fn(self._x, P0, u, self._p(p), dt, self.Q)
        if not ok or not np.all(np.isfinite(P)):
            raise ValueError("IVBCKF predict failed (P not positive definite)")
        self._x, self._P = np.asarray(x).reshape(-1), np.asarray(P)

    def update(self, z, p=None) -> bool:
        measurement, p = check_z(z, self.model.n_y), check_p(p, self.model)
        if measurement is None:
            return False
        with self._guard:
            saved = self.checkpoint()
            try:
                return self._update(measurement, self._p(p))
            except BaseException:
                self.restore(saved)
                raise

    def step(self, u, dt, z=None, p=None) -> bool:
        u, dt = check_u(u, self.model.n_u), check_dt(dt)
        measurement, p = check_z(z, self.model.n_y), check_p(p, self.model)
        with self._guard:
            saved = self.checkpoint()
            try:
                self._predict(u, dt, p)
                return False if measurement is None else self._update(measurement, self._p(p))
            except BaseException:
                self.restore(saved)
                raise

    def _cubature_B(self, x, P, z, p, present) -> np.ndarray:
        """E[(z - h(x))(z - h(x))^T] over the 2n cubature points of N(x, P) (present rows)."""
        n = x.size
        L = np.linalg.cholesky(0.5 * (P + P.T))
        points = x[:, None] + math.sqrt(n) * np.hstack([L, -L])
        Y = np.stack([np.asarray(self._h(points[:, i], p)).reshape(-1) for i in range(2 * n)], axis=1)
        r = (z[present, None] - Y[present])
        return r @ r.T / (2 * n)

    def _update(self, measurement, p) -> bool:
        z, present = measurement
        n, m_all = self.model.n_x, self.model.n_y
        m = int(present.sum())
        mask = present.astype(float)
        x_prior, P_prior = self._x, self._P
        tau_P, tau_R = self.u - n - 1, self.t - m - 1
        U0 = tau_P * P_prior
        R_used = self.R[np.ix_(present, present)]
        T0 = tau_R * R_used
        E_Pinv, E_Rinv = np.linalg.inv(P_prior), np.linalg.inv(R_used)
        E_xi = E_lam = 1.0
        E_omega, E_nu = self.chi / self.phi, self.kappa / self.zeta
        R_full = np.array(self.R)
        for _ in range(self.iterations):
            P_t = np.linalg.inv(E_Pinv) / E_xi
            R_t = np.linalg.inv(E_Rinv) / E_lam
            R_full[np.ix_(present, present)] = R_t
            x, P, innovation, S, ok = self._update_fn(x_prior, 0.5 * (P_t + P_t.T), np.where(present, z, 0.0), p,
                                                      R_full, mask)
            x, P = np.asarray(x).reshape(-1), np.asarray(P)
            if not ok:
                raise ValueError("IVBCKF update failed (covariance not positive definite)")
            d = x - x_prior
            A = np.outer(d, d) + P
            B = self._cubature_B(x, P, z, p, present)
            eta, theta = 0.5 * (E_omega + n), 0.5 * (E_omega + np.trace(A @ E_Pinv))
            E_xi = eta / theta
            E_omega = (self.chi + 0.5) / (self.phi + 0.5 * E_xi - 0.5 - 0.5 * (digamma(eta) - math.log(theta)))
            eta_l, theta_l = 0.5 * (E_nu + m), 0.5 * (E_nu + np.trace(B @ E_Rinv))
            E_lam = eta_l / theta_l
            E_nu = (self.kappa + 0.5) / (self.zeta + 0.5 * E_lam - 0.5 - 0.5 * (digamma(eta_l) - math.log(theta_l)))
            E_Pinv = (self.u - n) * np.linalg.inv(U0 + E_xi * A)
            E_Rinv = (self.t - m) * np.linalg.inv(T0 + E_lam * B)
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P))):
            raise ValueError("IVBCKF update diverged")
        self._x, self._P = x, 0.5 * (P + P.T)
        nu = np.asarray(innovation).reshape(-1)[present]
        S = np.atleast_2d(np.asarray(S))
        S = S[np.ix_(present, present)] if S.shape == (m_all, m_all) else S
        self.nis, self.nis_dof = float(nu @ np.linalg.solve(S, nu)), m
        self.xi, self.lam = E_xi, E_lam
        return True
