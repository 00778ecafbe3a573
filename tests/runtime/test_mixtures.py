import numpy as np
import pytest
from scipy.stats import multivariate_normal

from abyssal.runtime.noise.mixtures import GaussianMixture, logsumexp, weighted_em, weighted_moments

TRUTH = GaussianMixture(np.array([0.3, 0.7]), np.array([[-2.0, 0.0], [2.0, 1.0]]),
                        np.array([[[0.5, 0.2], [0.2, 0.4]], [[0.8, -0.3], [-0.3, 0.6]]]))


def test_log_density_matches_scipy():
    x = np.random.default_rng(0).normal(size=(2, 40))
    expected = np.log(sum(w * multivariate_normal(m, c).pdf(x.T)
                          for w, m, c in zip(TRUTH.weights, TRUTH.means, TRUTH.covariances)))
    assert np.allclose(TRUTH.log_density(x), expected, rtol=1e-12, atol=1e-12)


def test_logsumexp_handles_infinities():
    assert logsumexp(np.array([-np.inf, -np.inf])) == -np.inf
    assert np.isclose(logsumexp(np.array([1000.0, 1000.0])), 1000.0 + np.log(2))


def test_sample_moments_and_mixture_covariance():
    x, labels = TRUTH.sample(np.random.default_rng(1), 200_000)
    mean, cov = weighted_moments(x, np.full(x.shape[1], 1.0 / x.shape[1]))
    assert np.allclose(mean, TRUTH.mean(), atol=0.02)
    assert np.allclose(cov, TRUTH.covariance(), atol=0.05)
    assert abs(np.mean(labels == 1) - 0.7) < 0.01


def _sorted(mixture):
    order = np.argsort(mixture.means[:, 0])
    return mixture.weights[order], mixture.means[order], mixture.covariances[order]


def test_weighted_em_recovers_two_components_from_importance_weights():
    rng = np.random.default_rng(7)
    proposal = GaussianMixture.gaussian(np.array([0.0, 0.5]), np.diag([9.0, 4.0]))
    x, _ = proposal.sample(rng, 20_000)
    log_w = TRUTH.log_density(x) - proposal.log_density(x)
    w = np.exp(log_w - logsumexp(log_w))
    init = GaussianMixture(np.array([0.5, 0.5]), np.array([[-1.0, 0.0], [1.0, 0.0]]), np.array([np.eye(2)] * 2))
    fit = weighted_em(x, w, init, tol=1e-6, max_iter=500)
    assert fit.converged
    weights, means, covs = _sorted(fit.mixture)
    assert np.allclose(weights, TRUTH.weights, atol=0.03)
    assert np.allclose(means, TRUTH.means, atol=0.1)
    assert np.allclose(covs, TRUTH.covariances, atol=0.12)


def test_weighted_em_with_uniform_weights_matches_sklearn():
    sklearn_mixture = pytest.importorskip("sklearn.mixture")
    x, _ = TRUTH.sample(np.random.default_rng(3), 5000)
    init = GaussianMixture(np.array([0.5, 0.5]), np.array([[-1.0, 0.0], [1.0, 0.0]]), np.array([np.eye(2)] * 2))
    ours = weighted_em(x, np.ones(x.shape[1]), init, tol=1e-8, max_iter=1000).mixture
    ref = sklearn_mixture.GaussianMixture(2, tol=1e-10, max_iter=1000, reg_covar=1e-6, weights_init=init.weights,
                                          means_init=init.means, precisions_init=np.array([np.eye(2)] * 2)).fit(x.T)
    ref_mixture = GaussianMixture(ref.weights_, ref.means_, ref.covariances_)
    for a, b in zip(_sorted(ours), _sorted(ref_mixture)):
        assert np.allclose(a, b, atol=1e-4)


def test_weighted_em_never_returns_singular_covariances():
    # all the weight on three identical points and a starved second component
    x = np.zeros((3, 50))
    x[:, 10:] = np.random.default_rng(0).normal(size=(3, 40))
    w = np.zeros(50)
    w[:3] = 1.0
    init = GaussianMixture(np.array([0.5, 0.5]), np.zeros((2, 3)) + [[0.0], [5.0]], np.array([np.eye(3)] * 2))
    fit = weighted_em(x, w, init, reg_covar=1e-6, max_iter=30)
    eigenvalues = np.linalg.eigvalsh(fit.mixture.covariances)
    assert np.all(eigenvalues >= 1e-6 * 0.999)
    assert np.all(np.isfinite(fit.mixture.means)) and np.all(fit.mixture.weights > 0)
