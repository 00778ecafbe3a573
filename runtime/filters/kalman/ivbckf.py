"""IVBCKF: the iterated variational-Bayes Student-t cubature Kalman filter (seed 002 ref. 21).

Huang, Zhang, Xu, Wu & Chambers 2017 (IEEE/ASME TMech): the prior covariance and the measurement
covariance are scaled by Gamma-distributed factors xi and lambda whose degrees of freedom omega and
nu are themselves Gamma-distributed, with inverse-Wishart conjugate priors on the two scale
matrices. Seed 002's prior parameters: chi = kappa = 5 (Gamma shapes of omega, nu), phi = zeta = 1
(their rates), u = 8 and t = 5 (inverse-Wishart degrees of freedom of the prior and likelihood
scale matrices: u = n + 1 + tau_P, t = m + 1 + tau_R, so tau_P = 5, tau_R = 3 for n = 2, m = 1;
the defaults keep those tau for any n and m: u = n + 6, t = m + 4).

One step: the C runtime's cubature predict (``ckf_predict``, compiled.kalman.BatchStep) gives (x^-, P^-); then with
U0 = tau_P P^-, T0 = tau_R R, E[P^-1] = P^-^-1, E[R^-1] = R^-1, E[xi] = E[lambda] = 1,
E[omega] = chi / phi, E[nu] = kappa / zeta, ``iterations`` (default 10, ours) fixed-point passes:

    P~ = E[P^-1]^-1 / E[xi],  R~ = E[R^-1]^-1 / E[lambda]
    (x, P) = ckf_update(x^-, P~, z, p, R~)                              (the C runtime)
    A = (x - x^-)(x - x^-)^T + P;  B = E[(z - h(x))(z - h(x))^T]          (cubature points of N(x, P))
    eta = (E[omega] + n) / 2, theta = (E[omega] + tr(A E[P^-1])) / 2;  E[xi] = eta / theta
    E[lambda] = (E[nu] + m) / (E[nu] + tr(B E[R^-1]))
    E[omega] = (chi + 1/2) / (phi + E[xi] / 2 - 1/2 - (psi(eta) - ln theta) / 2)   (same for nu)
    E[P^-1] = (u - n) (U0 + E[xi] A)^-1,  E[R^-1] = (t - m) (T0 + E[lambda] B)^-1

The "- 1/2" in the rate of omega comes from Stirling's approximation of log Gamma(omega / 2) (a
copy of the authors' code has "+ 1/2"; the derivation gives "- 1/2", which keeps the rate >= phi
because E[xi] - E[ln xi] >= 1). The update runs in the C runtime, h in the model's generated C; the iteration's small
matrix algebra is NumPy (n = 2, m = 1 here).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.special import digamma

from ...compiled.kalman import BatchStep
from ...contract import FilterBase, check_covariance, check_state, register
from ...numerics import angle_indices, factorable_covariance, grew_beyond, wrap_angles
from .gate import InnovationGate

__all__ = ["IVBCKF"]


@register("kalman")
class IVBCKF(FilterBase):
    """Iterated VB Student-t CKF (module docstring); Kalman constructor (model, x0, P0, Q, R, **options).

    gate_probability, gate_patience, gate_inflation, gate_max_inflations: the innovation gate of every Kalman-type
    filter (gate.py), applied to the update at the prior (the first fixed-point pass); growth_limit: a predict
    whose covariance grows more than this (numerics.grew_beyond) is refused (this filter does not subdivide dt).

    A vanished measurement: the VB discounts an outlier by E[lambda] (R scaled by 1 / E[lambda]), the gate leaves
    out an entry outside its chi-square bound. When every measurement of ``gate_patience`` consecutive updates
    was discounted (E[lambda] below ``DISCOUNTED``) or gated whole, the filter, not the sensor, is taken to be
    wrong (its estimate jumped: a glitch of u accepted, or a long outage; with a huge P a nonlinear h makes B,
    and so 1 / E[lambda], huge at every later update, a fixed point that never lets a measurement in): the next
    updates skip the gate and are plain cubature updates with the measurement at face value (E[xi] = E[lambda]
    = 1, counted in ``recoveries``) until the E[lambda] the VB would give is back above ``DISCOUNTED``. A gated
    whole measurement is re-acquired this way, not by inflating P (the gate's inflation is kept for an entry
    gated while others pass): on cn2d's ranges after a 5e8 m jump of the estimate, inflating P until the range
    passed gave a cubature update over points 1e8 m apart, which left the estimate 110-280 m off for good in 3 of
    6 seeds; the face-value update at the prior's P, a Gauss-Newton step, recovers in every seed
    (tests/property/test_property_regressions.py).
    """

    name = "IVBCKF"
    _state = ("_x", "_P", "nis", "nis_dof", "xi", "lam", "gate", "_discounted_streak", "recoveries")
    #: an update whose E[lambda] ends below this counted the measurement at under a thousandth of its weight
    #: (a squared Mahalanobis residual of ~6000 with the default nu): the measurement was discounted
    DISCOUNTED = 1e-3

    def __init__(self, model, x0, P0, Q, R, *, chi: float = 5.0, phi: float = 1.0, kappa: float = 5.0,
                 zeta: float = 1.0, u: float | None = None, t: float | None = None, iterations: int = 10,
                 gate_probability: float = 1e-10, gate_patience: int = 5, gate_inflation: float = 4.0,
                 gate_max_inflations: int = 10, growth_limit: float = 1e3):
        n, m = model.n_x, model.n_y
        # the paper's tau_P = 5, tau_R = 3 (u = 8, t = 5 for its n = 2, m = 1) for any model size
        u = n + 6.0 if u is None else u
        t = m + 4.0 if t is None else t
        self._init_contract(model)
        self._x, self._P = check_state(x0, n, "x0"), check_covariance(P0, n, "P0")
        self.Q = check_covariance(Q, n, "Q")
        self.R = check_covariance(R, m, "R", definite=True)
        if not (u > n + 1 and t > m + 1 and iterations >= 1):
            raise ValueError(f"IVBCKF needs u > n + 1 = {n + 1}, t > m + 1 = {m + 1} and iterations >= 1")
        if not growth_limit > 1.0:
            raise ValueError(f"growth_limit must be > 1, got {growth_limit!r}")
        self.chi, self.phi, self.kappa, self.zeta, self.u, self.t = chi, phi, kappa, zeta, u, t
        self.iterations = int(iterations)
        self.gate = InnovationGate(self.R, probability=gate_probability, patience=gate_patience, inflation=gate_inflation,
                                   max_inflations=gate_max_inflations)
        self.growth_limit = float(growth_limit)
        self._predict_fn = BatchStep(model, "ckf_predict")
        self._update_fn = BatchStep(model, "ckf_update")
        self._h = model.function("h")
        self._angle_outputs = angle_indices(model, "outputs")
        self.nis, self.nis_dof = math.nan, 0
        self.xi, self.lam = 1.0, 1.0  # the last step's E[xi], E[lambda] (for inspection)
        self._discounted_streak = 0  # consecutive updates whose measurement the VB discounted (E[lambda] < DISCOUNTED)
        #: updates run with the measurement at face value (E[lambda] = 1) after gate_patience discounted ones
        self.recoveries = 0

    @property
    def gated(self) -> int:
        """Measurement entries left out by the innovation gate so far."""
        return self.gate.gated

    # ---------------------------------------------------------------- the contract's hooks (FilterBase)
    def _predict(self, u, dt) -> None:
        P0 = self._P
        x, P, ok = self._predict_fn(self._x, P0, u, self._p, dt, self.Q)
        if not ok:  # a singular P (e.g. P0 = 0) has no cubature factor: its nearest positive definite matrix
            P0 = factorable_covariance(P0, self.Q)
            x, P, ok = self._predict_fn(self._x, P0, u, self._p, dt, self.Q)
        if not ok or not np.all(np.isfinite(P)):
            raise ValueError("IVBCKF predict failed (P not positive definite)")
        if grew_beyond(self.growth_limit, P0, np.asarray(P), self.Q):
            raise ValueError(f"IVBCKF.predict: dt = {dt:g} s, u = {u.tolist()}: the covariance grew more than "
                             f"{self.growth_limit:g}x in one predict: dt (use a shorter one), u or p drive the model out "
                             "of its stable range at this state. State left unchanged")
        self._x, self._P = np.asarray(x).reshape(-1), np.asarray(P)

    def _update(self, z, present) -> bool:
        trust_sensor = self._discounted_streak >= self.gate.patience
        x_prior, P_prior = self._x, self._P
        accepted, gated = present, np.zeros_like(present)
        if self.gate.probability > 0.0 and not trust_sensor:  # (off: no prior update to test)
            accepted, gated = self.gate.select(lambda entries: self._prior_innovation(z, entries), present)
        if accepted is not None:
            self._vb_update(z, accepted, trust_sensor)
            self.recoveries += trust_sensor
            self._discounted_streak = self._discounted_streak + 1 if self.lam < self.DISCOUNTED else 0
        else:  # every entry gated: the measurement got no weight at all
            self._discounted_streak += 1
        self._P = self.gate.inflated(self._P, gated, present, accepted,
                                     lambda entries: P_prior - self._prior_update(x_prior, P_prior, z, entries)[1])
        return accepted is not None

    def _prior_update(self, x, P, z, present):
        """(x, P, nu, S) of the cubature update of (x, P) with R over the present entries."""
        x_post, P_post, innovation, S, ok = self._update_fn(x, P, np.where(present, z, 0.0), self._p, self.R,
                                                            present.astype(float))
        if not ok:
            raise ValueError("IVBCKF update failed (covariance not positive definite)")
        return (np.asarray(x_post).reshape(-1), np.asarray(P_post), np.asarray(innovation, dtype=float).reshape(-1),
                np.atleast_2d(np.asarray(S, dtype=float)))

    def _prior_innovation(self, z, present):
        """(nu, S) of the cubature update at the prior with R: the gate's test."""
        return self._prior_update(self._x, self._P, z, present)[2:]

    def _cubature_B(self, x, P, z, p, present) -> np.ndarray:
        """E[(z - h(x))(z - h(x))^T] over the 2n cubature points of N(x, P) (present rows; angle outputs' residuals
        wrapped to (-pi, pi], as the generated update wraps its innovation: a heading state 2 pi away from the
        compass is the same heading, not a 2 pi outlier that would scale R up and starve every update)."""
        n = x.size
        L = np.linalg.cholesky(0.5 * (P + P.T))
        points = x[:, None] + math.sqrt(n) * np.hstack([L, -L])
        Y = np.asarray(self._h.batch(2 * n, np.asfortranarray(points), p)).reshape(-1, 2 * n)  # one C call, 2n slices
        r = wrap_angles(z[:, None] - Y, self._angle_outputs, axis=0)[present]
        return r @ r.T / (2 * n)

    def _vb_update(self, z, present, trust_sensor: bool = False) -> None:
        p = self._p
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
        for _ in range(1 if trust_sensor else self.iterations):  # trusted: one plain cubature update (xi = lambda = 1)
            P_t = np.linalg.inv(E_Pinv) / E_xi
            R_t = np.linalg.inv(E_Rinv) / E_lam
            R_full[np.ix_(present, present)] = R_t
            if not (np.all(np.isfinite(P_t)) and np.all(np.isfinite(R_t))):
                raise FloatingPointError("the variational scale matrices overflowed (z far outside the prediction?)")
            x, P, innovation, S, ok = self._update_fn(x_prior, 0.5 * (P_t + P_t.T), np.where(present, z, 0.0), p,
                                                      R_full, mask)
            x, P = np.asarray(x).reshape(-1), np.asarray(P)
            if not ok:
                raise ValueError("IVBCKF update failed (covariance not positive definite)")
            if trust_sensor:
                break
            d = x - x_prior
            A = np.outer(d, d) + P
            eta, theta = 0.5 * (E_omega + n), 0.5 * (E_omega + np.trace(A @ E_Pinv))
            E_xi = eta / theta
            E_omega = (self.chi + 0.5) / (self.phi + 0.5 * E_xi - 0.5 - 0.5 * (digamma(eta) - math.log(theta)))
            B = self._cubature_B(x, P, z, p, present)
            eta_l, theta_l = 0.5 * (E_nu + m), 0.5 * (E_nu + np.trace(B @ E_Rinv))
            E_lam = eta_l / theta_l
            E_nu = (self.kappa + 0.5) / (self.zeta + 0.5 * E_lam - 0.5 - 0.5 * (digamma(eta_l) - math.log(theta_l)))
            E_Pinv = (self.u - n) * np.linalg.inv(U0 + E_xi * A)
            E_Rinv = (self.t - m) * np.linalg.inv(T0 + E_lam * B)
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P))):
            raise ValueError("IVBCKF update diverged")
        if trust_sensor:  # report the E[lambda] the VB would give at this posterior (it decides whether to go on trusting)
            E_lam = (E_nu + m) / (E_nu + np.trace(self._cubature_B(x, P, z, p, present) @ E_Rinv))
        self._x, self._P = x, 0.5 * (P + P.T)
        nu = np.asarray(innovation).reshape(-1)[present]
        S = np.atleast_2d(np.asarray(S))
        S = S[np.ix_(present, present)] if S.shape == (m_all, m_all) else S
        self.nis, self.nis_dof = float(nu @ np.linalg.solve(S, nu)), m
        self.xi, self.lam = E_xi, E_lam
