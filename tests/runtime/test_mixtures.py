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


# ---------------------------------------------------------------- input checks

GOOD_W, GOOD_MEANS, GOOD_COVS = np.array([0.3, 0.7]), np.zeros((2, 2)), np.array([np.eye(2)] * 2)


def _replace(index, value):
    args = [GOOD_W.copy(), GOOD_MEANS.copy(), GOOD_COVS.copy()]
    args[index] = value
    return args


BAD_MIXTURES = {
    # argument named in the error: (weights, means, covariances)
    "weights inf": ("weights", _replace(0, np.array([np.inf, 1.0]))),  # was accepted (NaN weights after /sum)
    "weights NaN": ("weights", _replace(0, np.array([np.nan, 1.0]))),
    "weights negative": ("weights", _replace(0, np.array([-0.5, 1.5]))),
    "weights all zero": ("weights", _replace(0, np.zeros(2))),
    "weights wrong shape": ("weights", _replace(0, np.ones(3))),
    "means NaN": ("means", _replace(1, np.array([[0.0, np.nan], [0.0, 0.0]]))),  # was accepted
    "means inf": ("means", _replace(1, np.array([[0.0, np.inf], [0.0, 0.0]]))),  # was accepted
    "means 1-D": ("means", _replace(1, np.zeros(2))),
    "covariances NaN": ("covariances", _replace(2, np.array([np.eye(2), [[1.0, np.nan], [np.nan, 1.0]]]))),
    "covariances inf": ("covariances", _replace(2, np.array([np.eye(2), np.diag([np.inf, 1.0])]))),
    "covariances asymmetric": ("covariances", _replace(2, np.array([np.eye(2), [[1.0, 0.5], [0.0, 1.0]]]))),
    "covariances indefinite": ("covariances", _replace(2, np.array([np.eye(2), np.diag([1.0, -1.0])]))),
    "covariances singular": ("covariances", _replace(2, np.array([np.eye(2), np.zeros((2, 2))]))),
    "covariances wrong shape": ("covariances", _replace(2, np.eye(2))),
}


@pytest.mark.parametrize("case", sorted(BAD_MIXTURES))
def test_mixture_refuses_bad_arguments_naming_them(case):
    name, args = BAD_MIXTURES[case]
    with pytest.raises(ValueError, match=name) as info:
        GaussianMixture(*args)
    if name == "covariances" and "shape" not in case:
        assert "covariances[1" in str(info.value)  # the component at fault


@pytest.mark.parametrize("index, name", [(0, "weights"), (1, "means"), (2, "covariances")])
def test_mixture_refuses_complex_arrays(index, name):
    args = _replace(index, [GOOD_W, GOOD_MEANS, GOOD_COVS][index] + 0j)
    with pytest.raises(TypeError, match=name):
        GaussianMixture(*args)


def test_mixture_weights_renormalised_even_when_their_sum_overflows():
    assert GaussianMixture(np.array([1.875, 0.04]), GOOD_MEANS, GOOD_COVS).weights.sum() == pytest.approx(1.0)
    given = np.array([1e308, 1e308])
    huge = GaussianMixture(given, GOOD_MEANS, GOOD_COVS)
    assert np.allclose(huge.weights, 0.5) and given.tolist() == [1e308, 1e308]  # the caller's array untouched
    one_zero = GaussianMixture(np.array([0.0, 2.0]), GOOD_MEANS, GOOD_COVS)
    assert one_zero.weights.tolist() == [0.0, 1.0] and np.all(np.isfinite(one_zero.log_density(np.zeros((2, 3)))))


def test_mixture_accepts_round_off_asymmetry_and_extreme_scales():
    cov = np.array([[2.0, 0.3], [0.3 * (1 + 1e-14), 1.0]])
    GaussianMixture.gaussian(np.zeros(2), cov)
    for scale in (1e-300, 1e300):
        m = GaussianMixture.gaussian(np.zeros(2), scale * np.eye(2))
        assert np.all(np.isfinite(m.log_density(np.zeros((2, 1)))))


def test_weighted_em_and_reduce_check_their_arguments():
    from abyssal.runtime.noise.mixtures import reduce_mixture

    init = GaussianMixture(np.array([0.5, 0.5]), np.array([[-1.0, 0.0], [1.0, 0.0]]), np.array([np.eye(2)] * 2))
    x = np.random.default_rng(0).normal(size=(2, 10))
    for bad_w in (np.zeros(10), np.full(10, np.nan), -np.ones(10), np.full(10, np.inf)):
        with pytest.raises(ValueError, match="weights"):
            weighted_em(x, bad_w, init)
    with pytest.raises(ValueError, match="weights"):
        weighted_em(x, np.ones(9), init)
    bad_x = x.copy()
    bad_x[0, 3] = np.nan
    with pytest.raises(ValueError, match="points"):
        weighted_em(bad_x, np.ones(10), init)
    with pytest.raises(ValueError, match="points"):
        weighted_em(x[:1], np.ones(10), init)
    with pytest.raises(ValueError, match="n_components"):
        reduce_mixture(init, 0)
