"""Unscented particle filters of seed 002: UPF, HRUPF and MCUPF (with KLD-resampling).

    upf = UnscentedParticleFilter(cn, x0, P0, Q, R, 5000, rng)                       # UPF, eqs. 7-24
    hrupf = UnscentedParticleFilter(cn, x0, P0, Q, R, 5000, rng, update="huber")     # HRUPF
    mcupf = UnscentedParticleFilter(cn, x0, P0, Q, R, 5000, rng, update="mcc",
                                    resampling=KLDResampling(n_max=2000))           # MCUPF, Table 3

Every particle j carries its own Gaussian (x^j, P^j) (van der Merwe's UPF, the paper's eqs. 5-6
and 7-19). One step, all per-particle work in generated C over all particles in one call each:

1. ``<m>_ukf_predict_batch`` on (x^j_{k-1}, P^j_{k-1}) with Q (eqs. 7-10);
2. ``<m>_ukf_update_batch`` (UPF), ``<m>_huber_ukf_update_batch`` (HRUPF: Huber gamma, 3 IRLS
   iterations fixed at generation) or ``<m>_mcukf_update_batch`` (MCUPF: R~ = R / C_k with the
   correntropy kernel of bandwidth sigma, eqs. 36-39) with the range and the leader position p;
3. a draw x^j_k ~ N(x^j_{k|k}, P^j_{k|k}) (eq. 19), weights by eq. 20 -- the Gaussian
   likelihood p(z | x) with the filter's R, the transition density N(x; f(x^j_{k-1}), Q) and the
   proposal density -- normalised in the log domain (eq. 21);
4. resampling every step: multinomial ("simple random", the paper's PF/UPF), or KLD-resampling
   (runtime/resampling/kld.py) which also sets the next particle number; P^j follows its particle.

Decisions:

* Sigma points: the scaled unscented rule with alpha = 1, beta = 0, kappa = 3 - n, i.e. the
  paper's lambda = 3 - n. For n = 2 that is lambda = 1: 2n + 1 = 5 points at +-sqrt(3) standard
  deviations, weights 1/3 (centre) and 1/6 -- all positive, so P stays positive definite, and the
  points match the Gaussian's fourth moment along each axis. (cn2d's f is linear in x, so the
  predict is exact for any lambda; lambda only matters in the range update.)
* The MCC kernel weight C_k underflows for large whitened innovations (sigma = 15, R = 0.1: a 30 m
  innovation gives ~2e-9, 60 m gives 1e-35). It is floored in the generated update
  (symbolic/filters/robust.py: the kernel exponent is capped at MCC_MAX_EXPONENT = 50, so
  C_k >= e^-50 ~ 2e-22 and R/C_k stays finite); the capped update then ignores the range.
* Estimates: x and P are the weighted mean and covariance before resampling (eqs. 23-24 after
  resampling have the same expectation and more noise).
* A likelihood that underflows at every particle (log p < log(tiny), e.g. R = 0.1 and a 40 m
  multipath outlier far from every particle) carries no usable information: the weights are left
  as they were (as in the SIR engine, engine.py), and the step is counted in ``uninformative``.
* ``update(z)`` alone (the contract's) reweights the particles where they are by p(z | x) and
  resamples: the unscented proposal needs the step's input, so ``step`` is where it acts.
* Particle number: ``n_particles`` is the number before the step's resampling; with
  KLD-resampling it starts at ``n_particles`` (N_start = 5000) and is set by every resampling
  after that (at most ``resampling.n_max``: 2000 in Table 6).
"""
from __future__ import annotations

import math

import numpy as np

from abyssal.symbolic.filters.families import FUNCTIONS

from ...compiled.batches import MeasureBatch, ModelBatch, ParallelBatch
from ...contract import FilterBase, as_generator, check_count, check_covariance, check_state, register
from ...noise.mixtures import LOG_2PI, weighted_moments
from ...numerics import factorable_covariance, gaussian_draws, stacked_cholesky
from ...resampling import KLDResampling, kld_resample, multinomial_resample, normalise_log_weights
from .engine import LOG_UNDERFLOW

__all__ = ["UnscentedParticleFilter"]

UPDATES = {"ukf": (FUNCTIONS["ukf"]["update"], None), "huber": (FUNCTIONS["robust"]["huber_update"], "gamma"),
           "mcc": (FUNCTIONS["robust"]["mcc_update"], "sigma")}


def _f_zeros(*shape) -> np.ndarray:
    return np.zeros(shape, order="F")


@register("particle")
class UnscentedParticleFilter(FilterBase):
    """UPF / HRUPF / MCUPF on batched generated UKF steps (see the module docstring)."""

    _state = ("N", "particles", "carried", "log_weights", "ess", "_x", "_P", "uninformative", "failed_slices", "rng",
              "n_particles")
    #: the particles and their covariances are written by _finish's last line only (after every check)
    _touched = ("N", "log_weights", "ess", "_x", "_P", "uninformative", "failed_slices", "rng", "n_particles")

    @classmethod
    def contract_example(cls, model, *, x0=None, P0=None, n_particles=None, rng=0):
        """For the contract test: an MCUPF (MCC update + KLD-resampling, the most moving parts)."""
        n, m = model.n_x, model.n_y
        return cls(model, np.zeros(n) if x0 is None else x0, np.eye(n) if P0 is None else P0, 0.05 * np.eye(n),
                   0.5 * np.eye(m), 40 if n_particles is None else n_particles, rng, update="mcc",
                   resampling=KLDResampling(bin_size=(0.5, 0.5), n_min=10, n_max=60))

    def __init__(self, model, x0, P0, Q, R, n_particles, rng, *, update: str = "ukf", sigma: float = 15.0,
                 gamma: float = 1.345, resampling: KLDResampling | None = None, name: str | None = None):
        if update not in UPDATES:
            raise ValueError(f"update must be one of {sorted(UPDATES)}, got {update!r}")
        n, m = model.n_x, model.n_y
        if resampling is not None and not all(0 <= c < n for c in resampling.coordinates):
            raise ValueError(f"resampling.coordinates must name rows of the {n}-state, got {resampling.coordinates}")
        N = check_count(n_particles, "n_particles")
        self._init_contract(model)
        self.rng = as_generator(rng)
        x0, P0 = check_state(x0, n, "x0"), check_covariance(P0, n, "P0")
        self.Q = np.asfortranarray(check_covariance(Q, n, "Q", definite=True))
        self.R = np.asfortranarray(check_covariance(R, m, "R", definite=True))
        self.update_kind, self.kld = update, resampling
        self.name = name or {"ukf": "UPF", "huber": "HRUPF", "mcc": "MCUPF"}[update]
        cap = max(N, resampling.n_max if resampling else N)
        self.capacity, self.N = cap, N
        self.n_particles = float(N)
        # particle means and carried covariances, Fortran (column j = particle j)
        self._means, self._covs = _f_zeros(n, cap), _f_zeros(n, n, cap)
        self._means[:, :N] = gaussian_draws(x0, P0, self.rng, N)
        # the carried covariances start at P0, or its nearest factorable when P0 is singular (a UKF step needs a factor)
        self._covs[:, :, :N] = (P0 if np.linalg.eigvalsh(P0)[0] > 0 else factorable_covariance(P0, self.Q))[:, :, None]
        self._u, self._dt = np.zeros(model.n_u), np.zeros(1)
        lam = 3.0 - n
        self.abk = np.array([1.0, 0.0, lam], dtype=np.float64)
        self.mean_pred, self.cov_pred, self._ok_p = _f_zeros(n, cap), _f_zeros(n, n, cap), _f_zeros(1, cap)
        self._predict_batch = ParallelBatch(model.function("ukf_predict"),
                                      [self._means, self._covs, self._u, self._p, self._dt, self.Q.reshape(-1, order="F"), self.abk],
                                      [True, True, False, False, False, False, False],
                                      [self.mean_pred, self.cov_pred, self._ok_p], cap)
        fn, extra_name = UPDATES[update]
        self._z, self._mask = np.zeros(m), np.ones(m)
        extra = [np.array([sigma if update == "mcc" else gamma], dtype=np.float64)] if extra_name else []
        self.mean_post, self.cov_post = _f_zeros(n, cap), _f_zeros(n, n, cap)
        self._innov, self._ok_u = _f_zeros(m, cap), _f_zeros(1, cap)
        self._S = _f_zeros(m, cap) if m == 1 else _f_zeros(m, m, cap)  # a (1, 1) output batches as a vector
        self._update_batch = ParallelBatch(model.function(fn),
                                     [self.mean_pred, self.cov_pred, self._z, self._p, self.R.reshape(-1, order="F"), self._mask, self.abk, *extra],
                                     [True, True, False, False, False, False, False] + [False] * len(extra),
                                     [self.mean_post, self.cov_post, self._innov, self._S, self._ok_u], cap)
        self._f = ModelBatch(model, cap, self._p)  # transition means f(x^j_{k-1}) (SIMD kernel)
        self.proposed = np.zeros((n, cap))
        self._h = MeasureBatch(model, self.proposed, self._p)
        self._R_inv = np.linalg.inv(self.R)
        self._R_log_norm = -0.5 * (float(np.linalg.slogdet(self.R)[1]) + m * LOG_2PI)
        self._Q_inv = np.linalg.inv(self.Q)
        self._Q_logdet = float(np.linalg.slogdet(self.Q)[1])
        self.log_weights = np.full(N, -math.log(N))
        self.ess, self.nis, self.nis_dof = float(N), math.nan, 0
        self._x, self._P = x0.copy(), np.array(P0)
        self.uninformative = 0
        self.failed_slices = 0  # particles whose generated step reported ok = 0 (kept at their prediction)

    # ---------------------------------------------------------------- contract: state
    @property
    def mean(self) -> np.ndarray:
        """The N particles (their UKF means), (n, N); a copy (the buffer beyond N is scratch)."""
        return self.particles.copy()

    @property
    def cov(self) -> np.ndarray:
        """The covariances the particles carry, (n, n, N); a copy."""
        return self.carried.copy()

    @property
    def particles(self) -> np.ndarray:
        """The N particles' means (n, N): a view of the buffer (copy before keeping it)."""
        return self._means[:, :self.N]

    @property
    def carried(self) -> np.ndarray:
        """The covariances the N particles carry (n, n, N): a view of the buffer."""
        return self._covs[:, :, :self.N]

    # ---------------------------------------------------------------- the contract's move (FilterBase)
    def _advance(self, u, dt, measurement) -> bool:
        return self._reweight(*measurement) if u is None else self._move(u, dt, measurement)

    def _reweight(self, z, present) -> bool:
        """An update alone: reweight the particles where they are by p(z | x) and resample (no unscented move:
        the proposal needs the step's input; ``step`` is the filter)."""
        N = self.N
        log_lik = self._log_likelihood(self._means[:, :N], z, present)
        log_w = self.log_weights + (log_lik if log_lik is not None else 0.0)
        self._finish(self._means[:, :N].copy(), self._covs[:, :, :N], log_w)
        return True

    def _log_likelihood(self, x: np.ndarray, z: np.ndarray, present: np.ndarray):
        """log p(z | x) per particle (Gaussian, the filter's R, present rows); None when it underflows
        at every particle (counted in ``uninformative``)."""
        N = x.shape[1]
        self.proposed[:, :N] = x
        y = self._h(N)[:, :N]
        if present.all():
            r, R_inv, log_norm = z[:, None] - y, self._R_inv, self._R_log_norm
        else:
            rows = np.flatnonzero(present)
            r = z[rows, None] - y[rows]
            R = self.R[np.ix_(rows, rows)]
            R_inv, log_norm = np.linalg.inv(R), -0.5 * (np.linalg.slogdet(R)[1] + rows.size * LOG_2PI)
        log_lik = -0.5 * np.einsum("iN,ij,jN->N", r, R_inv, r) + log_norm
        if log_lik.max() < LOG_UNDERFLOW:
            self.uninformative += 1
            return None
        return log_lik

    def _move(self, u, dt, measurement) -> bool:
        N, n = self.N, self.model.n_x
        self._u[:], self._dt[0] = u, dt
        self._predict_batch(N)
        self._f.x[:, :N] = self._means[:, :N]
        f = self._f.propagate(u, dt, N)
        if measurement is None:  # no range: x ~ p(x | x_prev), weights unchanged, P^j <- P^j_pred
            w = np.linalg.cholesky(self.Q) @ self.rng.standard_normal((n, N))
            new_mean, new_cov = f + w, self.cov_pred[:, :, :N]
            log_w = self.log_weights
            updated = False
        else:
            z, present = measurement
            self._z[:], self._mask[:] = np.where(present, z, 0.0), present
            self._update_batch(N)
            ok = self._ok_u[0, :N] > 0
            mu, C = self.mean_post[:, :N], self.cov_post[:, :, :N]
            if not ok.all():  # a particle whose update failed its guards proposes from its prediction
                self.failed_slices += int((~ok).sum())
                mu = np.where(ok, mu, self.mean_pred[:, :N])
                C = np.where(ok, C, self.cov_pred[:, :, :N])
            xi = self.rng.standard_normal((n, N))
            L, log_det = stacked_cholesky(np.moveaxis(C, -1, 0), repair=True)
            new_mean = mu + np.einsum("Nij,jN->iN", L, xi)
            new_cov = C
            log_q = -0.5 * np.einsum("iN,iN->N", xi, xi) - log_det - 0.5 * n * LOG_2PI
            d = new_mean - f
            log_prior = -0.5 * np.einsum("iN,ij,jN->N", d, self._Q_inv, d) - 0.5 * (self._Q_logdet + n * LOG_2PI)
            log_lik = self._log_likelihood(new_mean, z, present)
            if log_lik is None:
                log_w = self.log_weights + log_prior - log_q
            else:
                log_w = self.log_weights + log_lik + log_prior - log_q
            updated = True
        self._finish(new_mean, new_cov, log_w)
        return updated

    def _finish(self, new_mean, new_cov, log_w) -> None:
        """Weights, estimate, resampling (multinomial or KLD); carried covariances follow their particles."""
        N = self.N
        if not np.all(np.isfinite(new_mean)):
            raise ValueError(f"{self.name}: a particle left the finite range (u or dt too large for the model); state left unchanged")
        weights, _ = normalise_log_weights(log_w)
        self.ess = 1.0 / float(weights @ weights)
        self._x, self._P = weighted_moments(new_mean, weights)
        # resample every step (multinomial or KLD); carried covariances follow their particles
        if self.kld is None:
            ancestors = multinomial_resample(weights, self.rng, None)
        else:
            ancestors = kld_resample(weights, new_mean, self.rng, self.kld)
        new_cov = np.array(new_cov[:, :, ancestors], order="F")
        new_mean = new_mean[:, ancestors]
        self.n_particles = float(N)  # the number this step ran with
        N = ancestors.size
        self.N = N
        self._means[:, :N], self._covs[:, :, :N] = new_mean, new_cov
        self.log_weights = np.full(N, -math.log(N))

