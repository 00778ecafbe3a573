"""Particle filters on the generated C of any model: PF and CPF (seed 000), plus the batch cubature
Kalman filter baseline. The Gaussian-sum filters (MOGCPF, EM-MOGCPF, GS-CKF) are in filters/mixture.

Every filter is built from a ``ModelBundle`` (``abyssal.generated.load``), an initial mean and
covariance, a process noise and a measurement noise given as ``GaussianMixture`` objects (one
component for Gaussian noise), and a ``numpy.random.Generator``. ``step(u, z, dt)`` runs one
predict + update; ``estimate`` (n,) and ``covariance`` (n, n) hold the result. Particles are
(n, N) arrays; all per-particle model and filter evaluations are calls of generated C over the
whole batch (``bind_soa`` for f and h, ``bind_batch`` for ``ckf_predict`` / ``ckf_update``),
never Python loops over particles. Loops over mixture components (a handful) are allowed.

Noise conventions: the process noise is additive on the discrete state, x_{k+1} = f(x_k, u_k)
+ w_k with w_k ~ process_noise (already scaled to one step by the caller); measurement residuals
z - h(x) of angle outputs are wrapped to (-pi, pi]. Likelihoods are Gaussian or Gaussian
mixtures, evaluated in the log domain and normalised by log-sum-exp.

Decisions where seed 000 is ambiguous:

* PF: bootstrap SIR, proposal p(x_k | x_{k-1}), weights the exact (mixture) likelihood.
* Cubature steps inside CPF / MOGCPF / EM-MOGCPF / CKF use the moment-matched (single
  Gaussian) covariance of a mixture noise; the particle weights then use the exact mixture.
* CPF (eqs. 30-33): each particle carries its own covariance P^i, as in van der Merwe's
  unscented PF; the CKF predict+update of (x^i_{k-1}, P^i_{k-1}) gives the proposal
  N(x^i_{k|k}, P^i_{k|k}) (eq. 30), the particle is drawn from it (eq. 31) and weighted by
  p(z|x) p(x|x_{k-1}) / q (eq. 32); P^i_{k|k} is kept (and copied on resampling). The estimate
  is the weighted mean before resampling (eq. 33 after resampling is the same in expectation
  with more Monte-Carlo noise).
* MOGCPF (eqs. 34-40) is implemented as a Gaussian-sum particle filter (Kotecha & Djuric, the
  paper's ref. 22): G posterior components x K process-noise components give G' predicted
  components (eqs. 35-39, the process-noise mean is added to the cubature mean), each updated
  with every one of the M measurement-noise components gives G'' = G' M components (eq. 40)
  weighted by w_i' gamma_m N(z - mu_m; z_hat, S). N/G'' particles are drawn from each, weighted
  by gamma_m p_m(z|x) N(x; predicted_i') / N(x; updated_j); a component's weight is multiplied
  by its mean particle weight and its moments become the weighted particle moments (the
  cubature moments when its effective sample size is below 2n). The reduction G'' -> G keeps
  the G - 1 heaviest components and merges the rest by moment matching (``reduce_mixture``).
* EM-MOGCPF (eqs. 41-45): the same G'' cubature posterior is the importance density q for N
  particles (allocated to components by systematic resampling of the weights), weighted by
  p(z|x) p_G'(x) / q(x) with the exact mixture likelihood and the predicted G'-mixture; weighted
  EM (``mixtures.weighted_em``) refits G components, warm-started from the moment-matched
  children of each predicted component. Estimate and covariance are eq. 45. No resampling is
  needed: the EM refit replaces it, as the paper says.
* Initial mixtures (G > 1): component means drawn from N(x0, P0/2) with covariances P0/2, so
  the mixture's covariance is about P0 and the components are not identical (identical
  components would never separate under EM or Gaussian-sum updates).
* Extra baseline ``GaussianSumCKF``: the Gaussian-sum CKF with the exact mixture measurement
  noise (MOGCPF without particles), reduced to G components by ``reduce_mixture``.
* Outlier gate (not in the paper): a measurement entry more than 100 standard deviations of S
  from its prediction is left out of the cubature update (see ``CubatureUpdateBatch``); the
  particle weights still use the exact likelihood, normalised in the log domain. When the
  likelihood underflows at every particle (below the smallest normal double) the measurement is
  treated as carrying no information for the weights (``informative``): the log domain would
  otherwise hand all the weight to whichever particle lies nearest the outlier.
* A cubature step whose Cholesky guard fails (ok = 0) is rerun after repairing the offending
  input covariances by symmetrising and clipping eigenvalues at 1e-9 (relative).
"""
from __future__ import annotations

import numpy as np

from ...compiled.batches import CubaturePredictBatch, CubatureStepBatch, CubatureUpdateBatch, ModelBatch
from ...noise.mixtures import LOG_2PI, GaussianMixture, weighted_moments
from ...resampling import ResamplingPolicy, normalise_log_weights


def measurement_residuals(z: np.ndarray, y: np.ndarray, angle_outputs) -> np.ndarray:
    """z - y for each column of y (n_y, N), angle rows wrapped to (-pi, pi]."""
    r = z[:, None] - y
    for i in angle_outputs:
        if np.abs(r[i]).max() > np.pi:
            r[i] = -np.remainder(-r[i] + np.pi, 2 * np.pi) + np.pi
    return r


#: log of the smallest normal double: a likelihood below it at every particle underflows to zero
LOG_UNDERFLOW = float(np.log(np.finfo(np.float64).tiny))


def informative(log_likelihoods: np.ndarray) -> np.ndarray:
    """The log-likelihoods, or zeros when every one underflows (the measurement carries no usable
    information: all-zero likelihoods would give 0/0 weights, so the weights are left as they were)."""
    if log_likelihoods.max() < LOG_UNDERFLOW:
        return np.zeros_like(log_likelihoods)
    return log_likelihoods


def _check_problem(bundle, x0, P0, process_noise: GaussianMixture, measurement_noise: GaussianMixture):
    x0 = np.asarray(x0, dtype=np.float64)
    P0 = np.asarray(P0, dtype=np.float64)
    if x0.shape != (bundle.n_x,) or P0.shape != (bundle.n_x, bundle.n_x):
        raise ValueError(f"x0 must be ({bundle.n_x},) and P0 ({bundle.n_x}, {bundle.n_x}); got {x0.shape}, {P0.shape}")
    if process_noise.dim != bundle.n_x:
        raise ValueError(f"process noise must be {bundle.n_x}-dimensional (additive on the discrete state)")
    if measurement_noise.dim != bundle.n_y:
        raise ValueError(f"measurement noise must be {bundle.n_y}-dimensional")
    return x0, P0


# ---------------------------------------------------------------------------------------------
# filters


class CubatureKalmanFilter:
    """CKF (eqs. 22-29) on the generated steps; mixture noises enter by their moment-matched Gaussian."""

    name = "CKF"

    def __init__(self, bundle, x0, P0, process_noise: GaussianMixture, measurement_noise: GaussianMixture, p=None):
        x0, P0 = _check_problem(bundle, x0, P0, process_noise, measurement_noise)
        p = bundle.params(p)
        self._predict = CubaturePredictBatch(bundle, 1, p)
        self._update = CubatureUpdateBatch(bundle, 1, p, self._predict.mean_pred, self._predict.cov_pred)
        self._predict.Q[:, :, 0] = process_noise.covariance()
        self._q_mean = process_noise.mean()
        self._update.R[:, :, 0] = measurement_noise.covariance()
        self._r_mean = measurement_noise.mean()
        self.estimate, self.covariance = x0.copy(), P0.copy()

    def step(self, u, z, dt) -> None:
        pb, ub = self._predict, self._update
        pb.mean[:, 0], pb.cov[:, :, 0] = self.estimate, self.covariance
        pb.u[...] = u
        pb.dt[0] = dt
        pb(1)
        pb.mean_pred[:, 0] += self._q_mean
        ub.z[:, 0] = np.asarray(z) - self._r_mean
        ub(1)
        self.estimate, self.covariance = ub.mean_post[:, 0].copy(), ub.cov_post[:, :, 0].copy()


class ParticleFilter:
    """Bootstrap SIR particle filter (PF): proposal p(x_k|x_{k-1}), weights p(z|x) in the log domain."""

    name = "PF"

    def __init__(self, bundle, x0, P0, process_noise: GaussianMixture, measurement_noise: GaussianMixture,
                 n_particles: int, rng: np.random.Generator, policy: ResamplingPolicy = ResamplingPolicy(), p=None):
        x0, P0 = _check_problem(bundle, x0, P0, process_noise, measurement_noise)
        self.bundle, self.rng, self.policy = bundle, rng, policy
        self.n = n_particles
        self.process_noise, self.measurement_noise = process_noise, measurement_noise
        self.angle_outputs = bundle.angle_outputs
        self.model = ModelBatch(bundle, n_particles, bundle.params(p))
        self.particles = self.model.x  # (n, N) C-ordered, the input buffer of f and h
        self.particles[...] = GaussianMixture.gaussian(x0, P0).sample(rng, n_particles)[0]
        self.log_weights = np.full(n_particles, -np.log(n_particles))
        self.weights = np.full(n_particles, 1.0 / n_particles)
        gaussian_q = process_noise.n_components == 1
        q_cov = process_noise.covariances[0]
        self._q_diagonal_std = np.sqrt(np.diag(q_cov)) if gaussian_q and np.count_nonzero(q_cov - np.diag(np.diag(q_cov))) == 0 else None
        self._q_diagonal_std_col = None if self._q_diagonal_std is None else self._q_diagonal_std[:, None].copy()
        self._q_mean_col = process_noise.means[0][:, None].copy() if process_noise.means[0].any() else None
        self._noise = np.empty((bundle.n_x, n_particles))
        self._uniform_log_weight = -np.log(n_particles)
        self._log_n = float(np.log(n_particles))
        self._resample_always = policy.threshold >= 1.0
        self._resample_below = policy.threshold * n_particles
        self.estimate, self.covariance = x0.copy(), P0.copy()
        self.ess = float(n_particles)

    def _process_noise_sample(self) -> np.ndarray:
        if self._q_diagonal_std is not None:
            noise = self.rng.standard_normal(out=self._noise)
            noise *= self._q_diagonal_std_col
            if self._q_mean_col is not None:
                noise += self._q_mean_col
            return noise
        return self.process_noise.sample(self.rng, self.n)[0]

    def _log_likelihoods(self, z: np.ndarray) -> np.ndarray:
        """informative(log p(z | x)) of every particle (h evaluated on self.particles)."""
        residuals = measurement_residuals(z, self.model.measure(), self.angle_outputs)
        return informative(self.measurement_noise.log_density(residuals))

    def step(self, u, z, dt) -> None:
        x_next = self.model.propagate(np.asarray(u, dtype=np.float64), dt)
        np.add(x_next, self._process_noise_sample(), out=self.particles)
        log_w = self._log_likelihoods(np.asarray(z, dtype=np.float64))
        log_w += self.log_weights
        self._reweight(log_w)

    def _reweight(self, log_weights: np.ndarray) -> None:
        """Normalise, publish the moments, resample when the ESS is low. log_weights may be modified."""
        self.weights, log_mean = normalise_log_weights(log_weights)
        self.ess = 1.0 / float(self.weights @ self.weights)
        self.estimate, self.covariance = weighted_moments(self.particles, self.weights)  # before resampling
        if self._resample_always or self.ess < self._resample_below:
            ancestors = self.policy.ancestors(self.weights, self.rng)
            self.particles[...] = self.particles[:, ancestors]
            self._resampled(ancestors)
            self.log_weights = np.full(self.n, self._uniform_log_weight)
        else:
            self._kept()
            if np.isfinite(log_mean):
                log_weights -= log_mean + self._log_n  # normalised, in the log domain
                self.log_weights = log_weights
            else:
                self.log_weights = np.full(self.n, self._uniform_log_weight)

    def _resampled(self, ancestors: np.ndarray) -> None:
        """Hook for per-particle state carried beside the particles."""

    def _kept(self) -> None:
        """Hook: the step ended without resampling."""


class CubatureParticleFilter(ParticleFilter):
    """CPF (eqs. 30-33): per-particle cubature proposal, weights p(z|x) p(x|x_prev) / q."""

    name = "CPF"

    def __init__(self, bundle, x0, P0, process_noise, measurement_noise, n_particles, rng,
                 policy: ResamplingPolicy = ResamplingPolicy(), p=None):
        super().__init__(bundle, x0, P0, process_noise, measurement_noise, n_particles, rng, policy, p)
        p = bundle.params(p)
        n = bundle.n_x
        self._predict = CubaturePredictBatch(bundle, n_particles, p)
        self._update = CubatureUpdateBatch(bundle, n_particles, p, self._predict.mean_pred, self._predict.cov_pred)
        self._predict.Q[...] = process_noise.covariance()[:, :, None]
        self._update.R[...] = measurement_noise.covariance()[:, :, None]
        self._q_mean, self._r_mean = process_noise.mean(), measurement_noise.mean()
        self._q_mean_col = self._q_mean[:, None].copy()
        # zero-mean process noise: nothing happens between predict and update, so they run fused
        self._step = None if self._q_mean.any() else CubatureStepBatch(bundle, self._predict, self._update)
        self._predict.cov[...] = P0[:, :, None]  # P^i_0
        self._gaussian_process = process_noise.n_components == 1
        self._n_log_2pi = n * LOG_2PI
        # views and scratch reused every step
        self._cov_post_stack = np.moveaxis(self._update.cov_post, -1, 0)  # (N, n, n) view, each matrix contiguous
        self._xi = np.empty((n, n_particles))
        self._xi_columns = self._xi.T[:, :, None]  # (N, n, 1) view
        self._offsets = np.empty((n_particles, n, 1))  # L^i xi^i
        self._log_det = np.empty(n_particles)  # log det L^i
        self._factor_failed = False

    def _factor(self, lo: int, hi: int) -> None:
        """Slices lo..hi-1: L^i = chol(P^i_{k|k}), the draw offsets L^i xi^i and log det L^i."""
        L = np.linalg.cholesky(self._cov_post_stack[lo:hi])
        np.matmul(L, self._xi_columns[lo:hi], out=self._offsets[lo:hi])
        self._log_det[lo:hi] = _log_det_triangular(L)

    def _factor_chunk(self, lo: int, hi: int) -> None:
        """``_factor`` run beside the generated step on each core; a failure is redone (and raised) later."""
        try:
            self._factor(lo, hi)
        except np.linalg.LinAlgError:
            self._factor_failed = True

    def step(self, u, z, dt) -> None:
        u = np.asarray(u, dtype=np.float64)
        z = np.asarray(z, dtype=np.float64)
        pb, ub, N = self._predict, self._update, self.n
        # transition means f(x_{k-1}) for p(x_k | x_{k-1}) in eq. 32
        f_prev = self.model.propagate(u, dt)  # x_next buffer: untouched until the next step
        # the standard normal draws of eq. 31 (no other draw happens before them in this step)
        xi = self.rng.standard_normal(out=self._xi)
        # eq. 30: the cubature importance density of every particle, one batched C call
        pb.mean[...] = self.particles
        pb.u[...] = u
        pb.dt[0] = dt
        ub.z[...] = (z - self._r_mean)[:, None]
        self._factor_failed = False
        if self._step is not None:
            # predict + update fused; each core factors its own chunk's P^i_{k|k} right after
            factored = self._step(N, then=self._factor_chunk)
        else:
            pb(N)
            pb.mean_pred += self._q_mean_col
            ub(N)
            factored = False
        if not factored or self._factor_failed:
            self._factor(0, N)
        # eq. 31: x^i ~ N(x^i_{k|k}, P^i_{k|k}) = x^i_{k|k} + L^i xi^i
        np.add(ub.mean_post, self._offsets[:, :, 0].T, out=self.particles)
        # -log q = 0.5 |xi|^2 + log det L + n/2 log 2 pi
        log_w = np.einsum("ij,ij->j", xi, xi)
        log_w *= 0.5
        log_w += self._log_det
        # eq. 32: p(z|x) p(x|x_prev) / q
        log_w += self.process_noise.log_density(self.particles - f_prev)
        log_w += self._log_likelihoods(z)
        log_w += self.log_weights
        log_w += 0.5 * self._n_log_2pi
        self._reweight(log_w)

    def _resampled(self, ancestors: np.ndarray) -> None:
        self._predict.cov[...] = self._update.cov_post[:, :, ancestors]  # P^i_{k|k} travels with its particle

    def _kept(self) -> None:
        self._predict.cov[...] = self._update.cov_post


def _log_det_triangular(L: np.ndarray) -> np.ndarray:
    """sum_i log L_ii of stacked triangular factors (K, n, n): (K,). Computed matrix by matrix, so the
    result does not depend on how a batch is split over the cores."""
    n = L.shape[-1]
    diag = L.reshape(L.shape[0], n * n)[:, :: n + 1] if L.flags.c_contiguous else np.diagonal(L, axis1=1, axis2=2)
    return np.log(diag).sum(axis=1)


