"""Sigma-point rules as data: where the points go and how they are weighted.

A rule for an n-dimensional Gaussian N(x, P = L L^T) gives points X = x + L xi_k and weights
wm_k (mean) and wc_k (covariance):

* ``cubature_rule(n)``: third-degree spherical-radial cubature (Arasaratnam & Haykin; seed 000
  eq. 22): 2n points xi = +-sqrt(n) e_i, all weights 1/(2n).
* ``scaled_unscented_rule(n, alpha, beta, kappa)``: Julier's scaled unscented transform as
  parameterised by van der Merwe (seed 002 eqs. 7-9): 2n+1 points, xi_0 = 0,
  xi = +-sqrt(c) e_i with c = alpha^2 (n + kappa); wm_0 = (c - n)/c,
  wc_0 = wm_0 + 1 - alpha^2 + beta, wm_i = wc_i = 1/(2c). alpha, beta, kappa may be SX
  symbols, so one generated function serves every choice:
  Merwe's choice alpha = 1e-3, beta = 2, kappa = 0 (Gaussian prior) and Julier's
  alpha = 1, beta = 0, kappa = 3 - n are presets of the runtime (abyssal.runtime.filters.kalman).
  alpha = 1, beta = 0, kappa = 0 is the cubature rule plus a centre point of weight zero.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca


@dataclass(frozen=True)
class SigmaPointRule:
    """Unit points xi (n x m, multiplied by the Cholesky factor) and weights of a rule."""

    name: str
    xi: ca.SX
    wm: tuple
    wc: tuple

    @property
    def n_points(self) -> int:
        return self.xi.size2()

    def offsets(self, L: ca.SX) -> ca.SX:
        """L xi_k: the points' deviations from the mean, as the columns of an (n, m) matrix."""
        return ca.mtimes(L, self.xi)

    def points(self, x: ca.SX, L: ca.SX) -> ca.SX:
        """Sigma points x + L xi_k as the columns of an (n, m) matrix."""
        return ca.repmat(x, 1, self.n_points) + self.offsets(L)


def cubature_rule(n: int) -> SigmaPointRule:
    """Third-degree spherical-radial cubature: 2n points (seed 000 eq. 22)."""
    scale = ca.sqrt(ca.SX(n))
    eye = ca.SX.eye(n)
    w = ca.SX(1) / (2 * n)
    return SigmaPointRule("cubature", ca.horzcat(scale * eye, -scale * eye), (w,) * (2 * n), (w,) * (2 * n))


def scaled_unscented_rule(n: int, alpha, beta, kappa) -> SigmaPointRule:
    """Scaled unscented transform with 2n+1 points (seed 002 eqs. 7-9)."""
    c = alpha**2 * (n + kappa)
    scale = ca.sqrt(c)
    eye = ca.SX.eye(n)
    wm0 = (c - n) / c
    wc0 = wm0 + 1 - alpha**2 + beta
    wi = 1 / (2 * c)
    xi = ca.horzcat(ca.SX.zeros(n, 1), scale * eye, -scale * eye)
    return SigmaPointRule("scaled_unscented", xi, (wm0,) + (wi,) * (2 * n), (wc0,) + (wi,) * (2 * n))
