"""Robust sigma-point updates of seed 002: maximum correntropy and Huber M-estimation.

    <m>_mcukf_update(x, P, z, p, R, mask, abk, sigma)       -> (x_post, P_post, innovation, S, ok)
    <m>_huber_ukf_update(x, P, z, p, R, mask, abk, gamma)   -> (x_post, P_post, innovation, S, ok)

Both are the UKF update (unscented.py; points redrawn from x, P with the scaled unscented rule,
abk = [alpha, beta, kappa]; abk = [1, 0, 0] is the cubature rule, so these are also the MCCKF and
Huber CKF updates) with the measurement covariance R replaced by an inflated R~, computed from
the innovation nu whitened by R = a a^T (eqs. 31-35; a is the guarded Cholesky factor):

* Maximum correntropy (eqs. 36-39, one fixed-point iteration as in MCKF/MCUKF): zeta = a^-1 nu,
  C = diag(G_sigma(zeta_i)) with the Gaussian kernel G_sigma(e) = exp(-e^2 / (2 sigma^2))
  (eq. 37), R~ = a C^-1 a^T (eq. 38), used in Pzz + R~ (eq. 39). The kernel exponent is capped
  at MCC_MAX_EXPONENT so an extreme outlier inflates R by at most e^50 instead of overflowing.
  sigma -> inf gives C = I: the plain UKF update (sigma = inf is allowed and exact).
* Huber (HRUKF, gamma = 1.345, HUBER_ITERATIONS iterations): iteratively reweighted least
  squares on the whitened measurement residuals, prior residuals unweighted. With weights
  psi(e)/e = min(1, gamma/|e|), R~ = a diag(max(1, |zeta_i|/gamma)) a^T. Iteration 0 uses the
  innovation; iteration j+1 the post-fit residual of the statistically linearised regression,
  z - z_pred - H (x_j - x_pred) = R~_j S_j^-1 nu (S_j = Pzz + R~_j), which needs no second
  pass through h. gamma -> inf gives R~ = R: the plain UKF update.

The returned S is the one used, Pzz + R~ (masked as in measurement.py).
"""
from __future__ import annotations

import casadi as ca

from ..model import Model
from .families import FUNCTIONS
from .linalg import cholesky_solve, forward_substitute, guarded_cholesky
from .unscented import SigmaPointFamily, noise_leaf, unscented_family

MCC_MAX_EXPONENT = 50.0
HUBER_ITERATIONS = 3


def _inflated(a: ca.SX, inflation: list) -> ca.SX:
    """a diag(inflation) a^T."""
    return ca.mtimes(ca.mtimes(a, ca.diag(ca.vertcat(*inflation))), a.T)


def correntropy_noise(sigma):
    """R~ = a C^-1 a^T with C = diag(G_sigma(a^-1 nu)) (eqs. 37-38)."""
    def inflated(a, Pzz, innovation):
        zeta = forward_substitute(a, innovation)
        exponent = [ca.fmin(zeta[i] ** 2 / (2 * sigma**2), MCC_MAX_EXPONENT) for i in range(zeta.size1())]
        return _inflated(a, [ca.exp(e) for e in exponent])
    return inflated


def huber_noise(gamma, iterations: int = HUBER_ITERATIONS):
    """R~ after `iterations` Huber reweightings (see module docstring)."""
    def inflated(a, Pzz, innovation):
        residual = innovation
        for _ in range(iterations):
            zeta = forward_substitute(a, residual)
            R_tilde = _inflated(a, [ca.fmax(1, ca.fabs(zeta[i]) / gamma) for i in range(zeta.size1())])
            L, _ = guarded_cholesky(Pzz + R_tilde)
            residual = ca.mtimes(R_tilde, cholesky_solve(L, innovation))
        return R_tilde
    return inflated


def robust_functions(model: Model, family: SigmaPointFamily | None = None,
                     huber_iterations: int = HUBER_ITERATIONS) -> tuple[ca.Function, ...]:
    """<m>_mcukf_update and <m>_huber_ukf_update: the UKF's points and h (`family`, shared with the UKF's
    functions when they go into the same file, with its moments and Kalman gain), each with its own noise leaf."""
    family = family or unscented_family(model)
    sigma, gamma = ca.SX.sym("sigma"), ca.SX.sym("gamma")
    m = model.name
    mcc = noise_leaf(model, f"{m}_mcc_noise", correntropy_noise(sigma), [sigma], ["sigma"])
    huber = noise_leaf(model, f"{m}_huber_noise", huber_noise(gamma, huber_iterations), [gamma], ["gamma"])
    names = FUNCTIONS["robust"]
    return (family.update_function(f"{m}_{names['mcc_update']}", mcc, [sigma], ["sigma"]),
            family.update_function(f"{m}_{names['huber_update']}", huber, [gamma], ["gamma"]))
