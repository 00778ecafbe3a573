"""Gaussian-sum filters on batched generated cubature steps: MOGCPF and EM-MOGCPF (seed 000) and the
GS-CKF baseline. See filters/particle/sir.py for the decisions where seed 000 is ambiguous.
"""
from __future__ import annotations

import numpy as np

from ...compiled.batches import CubaturePredictBatch, CubatureUpdateBatch, ModelBatch
from ...noise.mixtures import (LOG_2PI, GaussianMixture, initial_mixture, logsumexp, merge_components, reduce_mixture,
                               weighted_em, weighted_moments)
from ...resampling import normalise_log_weights, systematic_resample
from ..particle.sir import _check_problem, informative, measurement_residuals

class _GaussianSumCubature:
    """Predict (G -> G' = G K) and update (G' -> G'' = G' M) of a Gaussian sum by batched cubature steps."""

    def __init__(self, bundle, n_components: int, process_noise: GaussianMixture, measurement_noise: GaussianMixture,
                 p: np.ndarray):
        self.bundle = bundle
        self.G, self.K, self.M = n_components, process_noise.n_components, measurement_noise.n_components
        self.process_noise, self.measurement_noise = process_noise, measurement_noise
        g1, g2 = self.G * self.K, self.G * self.K * self.M
        self.predict_batch = CubaturePredictBatch(bundle, g1, p)
        self.update_batch = CubatureUpdateBatch(bundle, g2, p, gate_jointly=True)
        # process component r of posterior component i sits at slice i K + r (eq. 35)
        self.predict_batch.Q[...] = np.moveaxis(np.tile(process_noise.covariances, (self.G, 1, 1)), 0, -1)
        # measurement component m of predicted component i' sits at slice i' M + m (eq. 40)
        self.update_batch.R[...] = np.moveaxis(np.tile(measurement_noise.covariances, (g1, 1, 1)), 0, -1)

    def predict(self, posterior: GaussianMixture, u: np.ndarray, dt: float) -> GaussianMixture:
        pb, K, G = self.predict_batch, self.K, posterior.n_components
        if G > self.G:
            raise ValueError(f"posterior has {G} components; the cubature bank holds {self.G}")
        count = G * K
        pb.mean[:, :count] = np.repeat(posterior.means, K, axis=0).T
        pb.cov[:, :, :count] = np.moveaxis(np.repeat(posterior.covariances, K, axis=0), 0, -1)
        pb.u[...] = u
        pb.dt[0] = dt
        pb(count)
        means = pb.mean_pred[:, :count].T + np.tile(self.process_noise.means, (G, 1))  # f(X) + u_v (eq. 38)
        weights = np.outer(posterior.weights, self.process_noise.weights).reshape(-1)  # eq. 36
        return GaussianMixture(weights, means, np.moveaxis(pb.cov_pred[:, :, :count], -1, 0).copy())

    def update(self, predicted: GaussianMixture, z: np.ndarray) -> GaussianMixture:
        ub, M, G1 = self.update_batch, self.M, predicted.n_components
        g2 = G1 * M
        ub.mean[:, :g2] = np.repeat(predicted.means, M, axis=0).T
        ub.cov[:, :, :g2] = np.moveaxis(np.repeat(predicted.covariances, M, axis=0), 0, -1)
        ub.z[:, :g2] = (z[None, :] - np.tile(self.measurement_noise.means, (G1, 1))).T
        ub(g2)
        log_w = (np.log(np.repeat(predicted.weights, M)) + np.log(np.tile(self.measurement_noise.weights, G1))
                 + ub.log_evidence(g2))  # eq. 40: w_i' gamma_m N(z - mu_m; z_hat, S)
        weights = np.exp(log_w - logsumexp(log_w))
        return GaussianMixture(np.maximum(weights, 1e-300), ub.mean_post[:, :g2].T.copy(),
                               np.moveaxis(ub.cov_post[:, :, :g2], -1, 0).copy())


class _MixtureFilterBase:
    """Common set-up of the Gaussian-sum filters: G-component posterior, cubature bank, estimate (eq. 45)."""

    def __init__(self, bundle, x0, P0, process_noise, measurement_noise, n_components, rng, p):
        x0, P0 = _check_problem(bundle, x0, P0, process_noise, measurement_noise)
        self.bundle, self.rng, self.G = bundle, rng, n_components
        self.process_noise, self.measurement_noise = process_noise, measurement_noise
        self.angle_outputs = bundle.angle_outputs
        self.cubature = _GaussianSumCubature(bundle, n_components, process_noise, measurement_noise, bundle.params(p))
        self.posterior = initial_mixture(x0, P0, n_components, rng)
        self.estimate, self.covariance = x0.copy(), P0.copy()

    def _publish(self, mixture: GaussianMixture) -> None:
        self.estimate, self.covariance = mixture.mean(), mixture.covariance()  # eq. 45


class GaussianSumCKF(_MixtureFilterBase):
    """Gaussian-sum CKF with the exact mixture measurement noise (extra baseline, no particles)."""

    name = "GS-CKF"

    def __init__(self, bundle, x0, P0, process_noise, measurement_noise, n_components: int = 2,
                 rng: np.random.Generator | None = None, p=None):
        if rng is None and n_components > 1:
            raise ValueError("GaussianSumCKF with n_components > 1 needs rng (it spreads the initial components)")
        super().__init__(bundle, x0, P0, process_noise, measurement_noise, n_components, rng, p)

    def step(self, u, z, dt) -> None:
        predicted = self.cubature.predict(self.posterior, np.asarray(u, dtype=np.float64), dt)
        updated = self.cubature.update(predicted, np.asarray(z, dtype=np.float64))
        self._publish(updated)
        self.posterior = reduce_mixture(updated, self.G)


class _SampledMixtureFilter(_MixtureFilterBase):
    """Particles drawn from the G'' cubature posterior and weighted with the exact likelihood."""

    def __init__(self, bundle, x0, P0, process_noise, measurement_noise, n_particles, n_components, rng, p):
        super().__init__(bundle, x0, P0, process_noise, measurement_noise, n_components, rng, p)
        self.n = n_particles
        self.model = ModelBatch(bundle, n_particles, bundle.params(p))
        self.particles = self.model.x
        self.ess = float(n_particles)

    def _draw(self, proposal: GaussianMixture, labels: np.ndarray) -> np.ndarray:
        """Fill self.particles with draws from the proposal components named by labels; returns xi."""
        L = np.linalg.cholesky(proposal.covariances)
        xi = self.rng.standard_normal((self.bundle.n_x, self.n))
        self.particles[...] = proposal.means[labels].T + (L[labels] @ xi.T[:, :, None])[:, :, 0].T
        return xi

    def _log_likelihoods_by_component(self, z: np.ndarray) -> np.ndarray:
        """log gamma_m p_m(z | x) of every particle, (M, N)."""
        residuals = measurement_residuals(z, self.model.measure(), self.angle_outputs)
        return informative(self.measurement_noise.weighted_component_log_densities(residuals))


class MixtureCubatureParticleFilter(_SampledMixtureFilter):
    """MOGCPF (eqs. 34-40) as a Gaussian-sum particle filter over cubature-updated components."""

    name = "MOGCPF"

    def __init__(self, bundle, x0, P0, process_noise, measurement_noise, n_particles: int, rng,
                 n_components: int = 2, p=None):
        super().__init__(bundle, x0, P0, process_noise, measurement_noise, n_particles, n_components, rng, p)
        g2 = n_components * process_noise.n_components * measurement_noise.n_components
        if n_particles < g2:
            raise ValueError(f"MOGCPF needs at least G'' = {g2} particles")
        # equal allocation: particle j belongs to component j mod G'' (N/G'' each, remainder spread)
        self._labels = np.arange(n_particles) % g2

    def step(self, u, z, dt) -> None:
        z = np.asarray(z, dtype=np.float64)
        predicted = self.cubature.predict(self.posterior, np.asarray(u, dtype=np.float64), dt)
        updated = self.cubature.update(predicted, z)
        M, n = self.cubature.M, self.bundle.n_x
        labels = self._labels
        xi = self._draw(updated, labels)
        parent, noise = labels // M, labels % M
        L_diag = np.log(np.diagonal(np.linalg.cholesky(updated.covariances), axis1=1, axis2=2)).sum(1)
        log_q = -0.5 * (np.einsum("ij,ij->j", xi, xi) + n * LOG_2PI) - L_diag[labels]
        log_prior = predicted.component_log_densities(self.particles)[parent, np.arange(self.n)]
        log_lik = self._log_likelihoods_by_component(z)[noise, np.arange(self.n)]
        log_w = log_lik + log_prior - log_q
        # per-component evidence, weights and moments
        g2 = updated.n_components
        weights = np.empty(g2)
        means, covs = updated.means.copy(), updated.covariances.copy()
        for j in range(g2):  # loop over the few components, each a vectorised batch of particles
            members = labels == j
            lw = log_w[members]
            log_mean_w = logsumexp(lw) - np.log(lw.shape[0])
            weights[j] = np.log(predicted.weights[j // M]) + np.log(self.measurement_noise.weights[j % M]) + log_mean_w
            w, _ = normalise_log_weights(lw)
            if 1.0 / (w @ w) >= 2 * n:
                means[j], covs[j] = weighted_moments(self.particles[:, members], w)
                covs[j] += 1e-9 * np.eye(n)
        weights = np.exp(weights - logsumexp(weights)) if np.isfinite(logsumexp(weights)) else updated.weights
        refit = GaussianMixture(np.maximum(weights, 1e-300), means, covs)
        self.ess = 1.0 / float(np.sum(normalise_log_weights(log_w)[0] ** 2))
        self._publish(refit)
        self.posterior = reduce_mixture(refit, self.G)


class EMMixtureCubatureParticleFilter(_SampledMixtureFilter):
    """EM-MOGCPF (eqs. 41-45): cubature Gaussian-sum proposal, exact weights, weighted-EM refit to G."""

    name = "EM-MOGCPF"

    def __init__(self, bundle, x0, P0, process_noise, measurement_noise, n_particles: int, rng,
                 n_components: int = 2, em_tol: float = 1e-3, em_max_iter: int = 20, reg_covar: float = 1e-6, p=None):
        super().__init__(bundle, x0, P0, process_noise, measurement_noise, n_particles, n_components, rng, p)
        self.em_tol, self.em_max_iter, self.reg_covar = em_tol, em_max_iter, reg_covar
        self.em_iterations = 0

    def _warm_start(self, updated: GaussianMixture) -> GaussianMixture:
        """G components: the moment-matched children of each posterior component of the last step."""
        per_parent = updated.n_components // self.G
        weights, means, covs = [], [], []
        for i in range(self.G):
            block = slice(i * per_parent, (i + 1) * per_parent)
            w, m, c = merge_components(updated.weights[block], updated.means[block], updated.covariances[block])
            weights.append(w), means.append(m), covs.append(c)
        return GaussianMixture(np.maximum(weights, 1e-12), np.array(means), np.array(covs))

    def step(self, u, z, dt) -> None:
        z = np.asarray(z, dtype=np.float64)
        predicted = self.cubature.predict(self.posterior, np.asarray(u, dtype=np.float64), dt)  # G -> G'
        updated = self.cubature.update(predicted, z)  # G' -> G''
        labels = systematic_resample(updated.weights, self.rng, self.n)
        self._draw(updated, labels)
        log_lik = logsumexp(self._log_likelihoods_by_component(z), axis=0)
        log_w = log_lik + predicted.log_density(self.particles) - updated.log_density(self.particles)
        weights, _ = normalise_log_weights(log_w)
        self.ess = 1.0 / float(weights @ weights)
        fit = weighted_em(self.particles, weights, self._warm_start(updated), tol=self.em_tol,
                          max_iter=self.em_max_iter, reg_covar=self.reg_covar)  # eqs. 41-44
        self.em_iterations = fit.iterations
        self.posterior = fit.mixture
        self._publish(fit.mixture)  # eq. 45
