"""Gaussian-sum filters on batched generated cubature steps: MOGCPF and EM-MOGCPF (seed 000) and the
GS-CKF baseline. See filters/particle/sir.py for the decisions where seed 000 is ambiguous.

All three keep the one filter contract (runtime/contract.py). ``predict`` turns the G-component
posterior into the G' = G K predicted mixture (reported reduced to G components); ``update``
turns the last predicted mixture (or the posterior, after another update) into the posterior;
``step`` is both as one transaction. NaN entries of z are left out of the cubature updates (the
generated mask) and of the particle likelihoods (the mixture's marginal on the present
entries). The process noise is a GaussianMixture or a covariance matrix (singular allowed: the
predicted covariances F P F^T + Q stay positive definite).

EM-MOGCPF, a property worth knowing: with a linear measurement the G'' cubature mixture is the
exact posterior of the predicted mixture, so its importance weights are uniform and the
particles only add Monte-Carlo noise to the EM refit.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from ...compiled.batches import CubaturePredictBatch, CubatureUpdateBatch, MeasureBatch
from ...contract import FilterBase, as_generator, check_count, check_covariance, check_state, register
from ...noise.mixtures import (LOG_2PI, GaussianMixture, initial_mixture, logsumexp, merge_components, reduce_mixture,
                               weighted_em, weighted_moments)
from ...numerics import factorable_covariance, grew_beyond, stacked_cholesky, stacked_times
from ...resampling import normalise_log_weights, systematic_resample
from ..particle.engine import MeasurementNoise, check_model, informative, measurement_residuals


def _process_components(noise, n: int):
    """The process-noise components (weights, means, covariances, n_components) of a mixture or a matrix."""
    if isinstance(noise, GaussianMixture):
        if noise.dim != n:
            raise ValueError(f"process_noise must be {n}-dimensional (additive on the discrete state), got {noise.dim}")
        return noise
    Q = check_covariance(noise, n, "process_noise")
    return SimpleNamespace(weights=np.ones(1), means=np.zeros((1, n)), covariances=np.array(Q)[None], n_components=1)

class _GaussianSumCubature:
    """Predict (G -> G' = G K) and update (G' -> G'' = G' M) of a Gaussian sum by batched cubature steps."""

    def __init__(self, bundle, n_components: int, process_noise: GaussianMixture, measurement_noise: GaussianMixture,
                 p: np.ndarray):
        self.bundle = bundle
        self.G, self.K, self.M = n_components, process_noise.n_components, measurement_noise.n_components
        self.process_noise, self.measurement_noise = process_noise, measurement_noise
        g1, g2 = self.G * self.K, self.G * self.K * self.M
        self.predict_batch = CubaturePredictBatch(bundle, g1, p)
        self.update_batch = CubatureUpdateBatch(bundle, g2, self.predict_batch.p, gate_jointly=True)
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

    def update(self, predicted: GaussianMixture, z: np.ndarray, present: np.ndarray) -> GaussianMixture:
        ub, M, G1 = self.update_batch, self.M, predicted.n_components
        g2 = G1 * M
        ub.present[:] = present
        ub.mean[:, :g2] = np.repeat(predicted.means, M, axis=0).T
        ub.cov[:, :, :g2] = np.moveaxis(np.repeat(predicted.covariances, M, axis=0), 0, -1)
        ub.z[:, :g2] = np.where(present[None, :], z[None, :] - np.tile(self.measurement_noise.means, (G1, 1)), 0.0).T
        ub(g2)
        log_w = (np.log(np.repeat(predicted.weights, M)) + np.log(np.tile(self.measurement_noise.weights, G1))
                 + ub.log_evidence(g2))  # eq. 40: w_i' gamma_m N(z - mu_m; z_hat, S)
        weights = np.exp(log_w - logsumexp(log_w))
        return GaussianMixture(np.maximum(weights, 1e-300), ub.mean_post[:, :g2].T.copy(),
                               np.moveaxis(ub.cov_post[:, :, :g2], -1, 0).copy())


class _MixtureFilterBase(FilterBase):
    """Common set-up of the Gaussian-sum filters: G-component posterior, cubature bank, estimate (eq. 45),
    and the contract's hooks (FilterBase holds the transaction)."""

    _state = ("posterior", "_pending", "_x", "_P", "ess", "rng")

    def __init__(self, model, x0, P0, process_noise, measurement_noise, n_components, rng):
        check_model(model, type(self).__name__)
        self.G = check_count(n_components, "n_components")
        rng = None if rng is None else as_generator(rng)
        x0 = check_state(x0, model.n_x, "x0")
        P0 = check_covariance(P0, model.n_x, "P0")
        self.noise = MeasurementNoise(measurement_noise, model.n_y)
        process = _process_components(process_noise, model.n_x)
        self._init_contract(model)
        self.rng = rng
        self.process_noise, self.measurement_noise = process, measurement_noise
        self.angle_outputs = tuple(model.angle_outputs)
        self.cubature = _GaussianSumCubature(model, self.G, process, measurement_noise, self._p)
        if np.linalg.eigvalsh(P0)[0] <= 0:  # singular P0: a cubature point set needs a factor
            P0 = factorable_covariance(P0, process.covariances)
        self.posterior = initial_mixture(x0, P0, self.G, rng)
        self._pending = None  # the predicted mixture of a predict() not yet followed by update()
        self._x, self._P = x0, np.array(P0)

    def _publish(self, mixture: GaussianMixture) -> None:
        self._x, self._P = mixture.mean(), mixture.covariance()  # eq. 45

    def _advance(self, u, dt, measurement) -> bool:
        """The contract's move (FilterBase): predict when u is given, then update when z is."""
        try:
            if u is not None:
                predicted = self.cubature.predict(self.posterior, u, dt)
                self._check_growth(self.posterior, predicted, dt)
            else:
                predicted = self._pending if self._pending is not None else self.posterior
            if measurement is None:
                self._pending = predicted
                self.posterior = reduce_mixture(predicted, self.G)
                self._publish(predicted)
                return False
            self._pending = None
            self._correct(predicted, *measurement)
            return True
        except ValueError as error:
            if str(error).startswith("mixture "):  # GaussianMixture refused a component: the numbers left their range
                raise FloatingPointError(str(error)) from error
            raise

    def _correct(self, predicted: GaussianMixture, z: np.ndarray, present: np.ndarray) -> None:
        raise NotImplementedError

    #: a predict whose largest component variance grows more than this many times the prior's largest
    #: variance plus the process noise's is refused (the same test as the Kalman engine's ``growth_limit``):
    #: a dt beyond the model's stable range would otherwise be accepted with finite but absurd
    #: covariances and poison every later step. These filters do not subdivide dt.
    growth_limit = 1e3

    def _check_growth(self, prior: GaussianMixture, predicted: GaussianMixture, dt: float) -> None:
        if grew_beyond(self.growth_limit, prior.covariances, predicted.covariances, self.process_noise.covariances):
            raise ValueError(f"{type(self).__name__}: dt = {dt:g} s is beyond the model's stable range (a component "
                             f"covariance grew more than {self.growth_limit:g}x in one predict); use a shorter dt. "
                             "State left unchanged")


@register("gaussian-sum")
class GaussianSumCKF(_MixtureFilterBase):
    """Gaussian-sum CKF with the exact mixture measurement noise (extra baseline, no particles)."""

    name = "GS-CKF"

    def __init__(self, model, x0, P0, process_noise, measurement_noise, n_components: int = 2, rng=None):
        if rng is None and n_components > 1:
            raise ValueError("GaussianSumCKF with n_components > 1 needs rng (it spreads the initial components)")
        super().__init__(model, x0, P0, process_noise, measurement_noise, n_components, rng)

    def _correct(self, predicted, z, present) -> None:
        updated = self.cubature.update(predicted, z, present)
        self._publish(updated)
        self.posterior = reduce_mixture(updated, self.G)


class _SampledMixtureFilter(_MixtureFilterBase):
    """Particles drawn from the G'' cubature posterior and weighted with the exact likelihood."""

    _state = _MixtureFilterBase._state + ("particles",)

    def __init__(self, model, x0, P0, process_noise, measurement_noise, n_particles, n_components, rng):
        self.N = check_count(n_particles, "n_particles")
        if rng is None:
            raise TypeError("rng is required (an int seed or a numpy.random.Generator)")
        super().__init__(model, x0, P0, process_noise, measurement_noise, n_components, rng)
        self.n = self.N
        self.n_particles = float(self.N)
        self.particles = np.zeros((model.n_x, self.N))
        self._h = MeasureBatch(model, self.particles, self._p)
        self.ess = float(self.N)

    def _draw(self, proposal: GaussianMixture, labels: np.ndarray) -> np.ndarray:
        """Fill self.particles with draws from the proposal components named by labels; returns xi."""
        L, _ = stacked_cholesky(proposal.covariances, repair=False)
        xi = self.rng.standard_normal((self.model.n_x, self.N))
        self.particles[...] = proposal.means[labels].T + stacked_times(L[labels], xi)
        return xi

    def _log_likelihoods_by_component(self, z: np.ndarray, present: np.ndarray) -> np.ndarray | None:
        """log gamma_m p_m(z_present | x) of every particle, (M, N); None when all underflow."""
        y = self._h(self.N)
        rows = np.flatnonzero(present)
        angle_rows = [i for i, r in enumerate(rows) if r in self.angle_outputs]
        residuals = measurement_residuals(z[rows], y[rows], angle_rows)
        out = self.noise.marginal(present).weighted_component_log_densities(residuals)
        return out if informative(out) is not None else None


@register("mixture")
class MixtureCubatureParticleFilter(_SampledMixtureFilter):
    """MOGCPF (eqs. 34-40) as a Gaussian-sum particle filter over cubature-updated components."""

    name = "MOGCPF"

    def __init__(self, model, x0, P0, process_noise, measurement_noise, n_particles, rng, *, n_components: int = 2):
        super().__init__(model, x0, P0, process_noise, measurement_noise, n_particles, n_components, rng)
        g2 = self.G * self.cubature.K * self.cubature.M
        # equal allocation: particle j belongs to component j mod G'' (N/G'' each, remainder spread);
        # with fewer particles than components some components get none and keep their cubature moments
        self._labels = np.arange(self.N) % g2

    def _correct(self, predicted, z, present) -> None:
        updated = self.cubature.update(predicted, z, present)
        M, n = self.cubature.M, self.model.n_x
        labels = self._labels % updated.n_components
        xi = self._draw(updated, labels)
        parent, noise = labels // M, labels % M
        _, L_diag = stacked_cholesky(updated.covariances, repair=False)
        log_q = -0.5 * (np.einsum("ij,ij->j", xi, xi) + n * LOG_2PI) - L_diag[labels]
        log_prior = predicted.component_log_densities(self.particles)[parent, np.arange(self.N)]
        by_component = self._log_likelihoods_by_component(z, present)
        log_lik = 0.0 if by_component is None else by_component[noise, np.arange(self.N)]
        log_w = log_lik + log_prior - log_q
        # per-component evidence, weights and moments
        g2 = updated.n_components
        weights = np.full(g2, -np.inf)
        means, covs = updated.means.copy(), updated.covariances.copy()
        for j in range(g2):  # loop over the few components, each a vectorised batch of particles
            members = labels == j
            if not members.any():
                weights[j] = np.log(updated.weights[j])
                continue
            lw = log_w[members]
            log_mean_w = logsumexp(lw) - np.log(lw.shape[0])
            weights[j] = np.log(predicted.weights[j // M]) + np.log(self.measurement_noise.weights[j % M]) + log_mean_w
            w, _ = normalise_log_weights(lw)
            if 1.0 / (w @ w) >= 2 * n:
                means[j], covs[j] = weighted_moments(self.particles[:, members], w)
                covs[j] += 1e-9 * np.eye(n)
        total = logsumexp(weights)
        weights = np.exp(weights - total) if np.isfinite(total) else updated.weights
        refit = GaussianMixture(np.maximum(weights, 1e-300), means, covs)
        self.ess = 1.0 / float(np.sum(normalise_log_weights(log_w)[0] ** 2))
        self._publish(refit)
        self.posterior = reduce_mixture(refit, self.G)


@register("mixture")
class EMMixtureCubatureParticleFilter(_SampledMixtureFilter):
    """EM-MOGCPF (eqs. 41-45): cubature Gaussian-sum proposal, exact weights, weighted-EM refit to G.

    Uniform weights: when h is linear in x (seed 000: z = H x, H = [I 0]) the cubature update of
    each predicted component with each measurement component is exact, so the G'' proposal q is
    the exact posterior p(z|x) p_G'(x) / p(z) and every importance weight p(z|x) p_G'(x) / q(x)
    equals p(z): the ESS is N at every step (the rov experiment reports it) and the particles only
    add Monte-Carlo noise to the EM refit. Weights differ from uniform only where the cubature
    update is not exact: a nonlinear h, an angle residual that wraps, an entry left out by the
    outlier gate, or a likelihood that underflows. ``covariances="analytic"`` (an ablation, not in
    the paper) keeps EM's weights and means but replaces each component's sample covariance --
    noisy and overconfident with 12-D components and a few hundred particles -- by its
    Rao-Blackwellised form (``_analytic_covariances``).
    """

    name = "EM-MOGCPF"
    _state = _SampledMixtureFilter._state + ("em_iterations",)

    def __init__(self, model, x0, P0, process_noise, measurement_noise, n_particles, rng, *,
                 n_components: int = 2, em_tol: float = 1e-3, em_max_iter: int = 20, reg_covar: float = 1e-6,
                 covariances: str = "sample"):
        if covariances not in ("sample", "analytic"):
            raise ValueError(f"covariances must be 'sample' or 'analytic', got {covariances!r}")
        super().__init__(model, x0, P0, process_noise, measurement_noise, n_particles, n_components, rng)
        self.em_tol, self.em_max_iter, self.reg_covar = em_tol, em_max_iter, reg_covar
        self.covariances = covariances
        self.em_iterations = 0

    def _warm_start(self, updated: GaussianMixture) -> GaussianMixture:
        """G components: the moment-matched children of each posterior component of the last step."""
        G = min(self.G, updated.n_components)
        per_parent = updated.n_components // G
        weights, means, covs = [], [], []
        for i in range(G):
            block = slice(i * per_parent, (i + 1) * per_parent)
            w, m, c = merge_components(updated.weights[block], updated.means[block], updated.covariances[block])
            weights.append(w), means.append(m), covs.append(c)
        return GaussianMixture(np.maximum(weights, 1e-12), np.array(means), np.array(covs))

    def _correct(self, predicted, z, present) -> None:
        updated = self.cubature.update(predicted, z, present)  # G' -> G''
        labels = systematic_resample(updated.weights, self.rng, self.N)
        self._draw(updated, labels)
        by_component = self._log_likelihoods_by_component(z, present)
        log_lik = 0.0 if by_component is None else logsumexp(by_component, axis=0)
        log_w = log_lik + predicted.log_density(self.particles) - updated.log_density(self.particles)
        weights, _ = normalise_log_weights(log_w)
        self.ess = 1.0 / float(weights @ weights)
        fit = weighted_em(self.particles, weights, self._warm_start(updated), tol=self.em_tol,
                          max_iter=self.em_max_iter, reg_covar=self.reg_covar)  # eqs. 41-44
        self.em_iterations = fit.iterations
        mixture = fit.mixture if self.covariances == "sample" else _analytic_covariances(
            fit.mixture, updated, labels, self.particles, weights, self.reg_covar)
        self.posterior = mixture
        self._publish(mixture)  # eq. 45


def _analytic_covariances(fit: GaussianMixture, proposal: GaussianMixture, labels: np.ndarray, particles: np.ndarray,
                          weights: np.ndarray, reg_covar: float) -> GaussianMixture:
    """The EM fit with each component's covariance replaced by its Rao-Blackwellised form (ablation).

    The sample covariance of component j is sum_i a_ij (x_i - mu_j)(x_i - mu_j)^T / sum_i a_ij with
    a_ij = w_i r_ij (importance weight times responsibility). Particle i was drawn from proposal
    component l_i = labels[i], so its outer product is replaced by its expectation under that
    component: P''_l + (m''_l - mu_j)(m''_l - mu_j)^T. EM's weights and means are kept. With 12-D
    components and a few hundred particles this removes the sampling noise of the covariance
    (which makes the sample version overconfident) while keeping what EM learned about the split.
    Symmetrised, with EM's ridge ``reg_covar`` (a component fed by one nearly degenerate proposal
    component was otherwise refused as not positive definite, seen once in 60 runs of sea state 3).
    """
    resp = np.exp(fit.component_log_densities(particles) + np.log(fit.weights)[:, None])
    resp /= np.maximum(resp.sum(axis=0, keepdims=True), np.finfo(float).tiny)
    a = resp * weights  # (G, N)
    by_label = np.zeros((fit.n_components, proposal.n_components))
    for j in range(fit.n_components):
        by_label[j] = np.bincount(labels, weights=a[j], minlength=proposal.n_components)
    covs = np.empty_like(fit.covariances)
    for j in range(fit.n_components):
        share = by_label[j] / max(by_label[j].sum(), np.finfo(float).tiny)
        d = proposal.means - fit.means[j]
        covs[j] = np.einsum("l,lab->ab", share, proposal.covariances) + (d * share[:, None]).T @ d
    covs = 0.5 * (covs + np.swapaxes(covs, 1, 2)) + reg_covar * np.eye(covs.shape[-1])
    return GaussianMixture(fit.weights, fit.means, covs)
