"""Property-based tests of the resamplers, the log-weight normalisation and GaussianMixture:
every input is either refused with an error naming the argument, or gives
finite, well-formed output."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, strategies as st
from hypothesis.extra import numpy as hnp

from abyssal.runtime.noise.mixtures import GaussianMixture
from abyssal.runtime.resampling import (RESAMPLERS, ResamplingPolicy, effective_sample_size, normalise_log_weights)
from abyssal.runtime.resampling.schemes import WEIGHT_SUM_TOLERANCE

ANY_FLOAT = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(0, 1), st.just(0.0))


def acceptable_weights(w: np.ndarray) -> bool:
    with np.errstate(over="ignore", invalid="ignore"):
        return (w.ndim == 1 and w.size > 0 and bool(np.all(np.isfinite(w))) and w.min() >= 0
                and abs(float(w.sum()) - 1.0) <= WEIGHT_SUM_TOLERANCE)


@st.composite
def weight_arrays(draw):
    """Raw arrays of any floats (mostly refused), or normalised positive ones (always acceptable)."""
    n = draw(st.integers(0, 12))
    raw = draw(hnp.arrays(np.float64, n, elements=ANY_FLOAT))
    if n and draw(st.booleans()):
        positive = np.abs(np.nan_to_num(raw, nan=1.0, posinf=1.0, neginf=1.0)) + draw(st.sampled_from([0.0, 1e-300, 1.0]))
        if positive.sum() > 0 and np.isfinite(positive.sum()):
            return positive / positive.sum()
    return raw


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
@pytest.mark.parametrize("scheme", sorted(RESAMPLERS))
@given(weights=weight_arrays(), n_draws=st.one_of(st.none(), st.integers(0, 20)), seed=st.integers(0, 2**32 - 1))
def test_resampler_refuses_or_draws_valid_ancestors(scheme, weights, n_draws, seed):
    rng = np.random.default_rng(seed)
    if not acceptable_weights(weights):
        state = repr(rng.bit_generator.state)
        with pytest.raises(ValueError, match="weights"):
            RESAMPLERS[scheme](weights, rng, n_draws)
        assert repr(rng.bit_generator.state) == state  # a refusal draws nothing
        return
    idx = RESAMPLERS[scheme](weights, rng, n_draws)
    m = weights.size if n_draws is None else n_draws
    assert idx.shape == (m,) and idx.dtype.kind == "i"
    assert np.all((idx >= 0) & (idx < weights.size))
    assert np.all(weights[idx] > 0), "a zero-weight particle was drawn"


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
@given(weights=weight_arrays())
def test_effective_sample_size_and_policy(weights):
    if not acceptable_weights(weights):
        with pytest.raises(ValueError, match="weights"):
            effective_sample_size(weights)
        with pytest.raises(ValueError, match="weights"):
            ResamplingPolicy().should_resample(weights)
        return
    ess = effective_sample_size(weights)
    assert 1.0 - 1e-9 <= ess <= weights.size * (1 + 1e-9)
    assert isinstance(ResamplingPolicy().should_resample(weights), bool)


@given(log_weights=hnp.arrays(np.float64, st.integers(0, 10), elements=st.one_of(
    st.floats(allow_nan=True, allow_infinity=True), st.floats(-800, 5), st.just(-np.inf))))
def test_normalise_log_weights(log_weights):
    if log_weights.size == 0 or np.isnan(log_weights).any() or (log_weights == np.inf).any():
        with pytest.raises(ValueError, match="log_weights"):
            normalise_log_weights(log_weights)
        return
    weights, log_mean = normalise_log_weights(log_weights)
    assert np.all(np.isfinite(weights)) and np.all(weights >= 0) and math.isclose(weights.sum(), 1.0, rel_tol=1e-12)
    if np.all(log_weights == -np.inf):
        assert log_mean == -np.inf and np.all(weights == 1.0 / log_weights.size)  # documented fallback
    else:
        assert math.isfinite(log_mean)
        assert np.all(weights[log_weights == -np.inf] == 0)
        assert acceptable_weights(weights)  # what a resampler takes


# ---------------------------------------------------------------- GaussianMixture

SCALES = st.sampled_from([1e-100, 1e-6, 1.0, 1e6, 1e100])


@st.composite
def mixtures(draw):
    """(weights, means, covariances, faulty argument or None): valid mixtures with one fault injected
    into a copy sometimes."""
    K, d = draw(st.integers(1, 3)), draw(st.integers(1, 3))
    weights = np.array(draw(st.lists(st.floats(0, 10), min_size=K, max_size=K)))
    if not weights.sum() > 0:
        weights[0] = 1.0
    means = np.array(draw(st.lists(st.floats(-1e3, 1e3), min_size=K * d, max_size=K * d))).reshape(K, d)
    A = np.array(draw(st.lists(st.floats(-1, 1), min_size=K * d * d, max_size=K * d * d))).reshape(K, d, d)
    covariances = (A @ A.transpose(0, 2, 1) + 0.1 * np.eye(d)) * draw(SCALES)
    fault = draw(st.sampled_from([None] * 4 + ["weights", "means", "covariances"]))
    if fault == "weights":
        weights[draw(st.integers(0, K - 1))] = draw(st.sampled_from([np.nan, np.inf, -1.0]))
    elif fault == "means":
        means[draw(st.integers(0, K - 1)), 0] = draw(st.sampled_from([np.nan, np.inf, -np.inf]))
    elif fault == "covariances":
        k = draw(st.integers(0, K - 1))
        how = draw(st.sampled_from(["nan", "indefinite", "asymmetric", "zero"]))
        if how == "nan":
            covariances[k, 0, 0] = np.nan
        elif how == "indefinite":
            covariances[k] = -covariances[k]
        elif how == "asymmetric" and d > 1:
            covariances[k, 0, 1] += covariances[k].max()
        elif how == "zero":
            covariances[k] = 0.0
        else:
            fault = None
    return weights, means, covariances, fault


@given(mixture=mixtures(), seed=st.integers(0, 2**32 - 1))
def test_gaussian_mixture_refuses_or_is_usable(mixture, seed):
    weights, means, covariances, fault = mixture
    if fault is not None:
        with pytest.raises(ValueError, match=fault):
            GaussianMixture(weights, means, covariances)
        return
    g = GaussianMixture(weights, means, covariances)
    assert math.isclose(g.weights.sum(), 1.0, rel_tol=1e-12) and np.all(g.weights >= 0)
    points, labels = g.sample(np.random.default_rng(seed), 5)
    assert np.all(np.isfinite(points)) and points.shape == (g.dim, 5)
    log_density = g.log_density(np.hstack([points, np.zeros((g.dim, 1))]))
    assert not np.isnan(log_density).any() and not (log_density == np.inf).any()
    assert np.all(np.isfinite(g.mean())) and np.all(np.isfinite(g.covariance()))


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
@given(weights=weight_arrays(), data=st.data(), seed=st.integers(0, 2**32 - 1))
def test_kld_resample_refuses_or_draws_valid_ancestors(weights, data, seed):
    from abyssal.runtime.resampling import KLDResampling, kld_resample

    n = max(weights.size, 1) if weights.ndim == 1 else 1
    states = data.draw(hnp.arrays(np.float64, (2, n), elements=st.floats(-1e3, 1e3)), "states")
    fault = data.draw(st.sampled_from([None] * 3 + ["nan", "huge", "shape"]), "states fault")
    if fault == "nan":
        states[0, 0] = np.nan
    elif fault == "huge":
        states[1, 0] = 1e300
    elif fault == "shape":
        states = states[:, :-1] if n > 1 else np.zeros((2, 2))
    params = KLDResampling(n_min=5, n_max=60, chunk=16)
    rng = np.random.default_rng(seed)
    if not acceptable_weights(weights):
        with pytest.raises(ValueError, match="weights"):
            kld_resample(weights, states, rng, params)
        return
    if fault in ("nan", "shape"):
        with pytest.raises(ValueError, match="states|particle"):
            kld_resample(weights, states, rng, params)
        return
    idx = kld_resample(weights, states, rng, params)  # a huge (finite) state is binned relative to the cloud
    assert 5 <= idx.size <= 60 and idx.dtype.kind == "i"
    assert np.all((idx >= 0) & (idx < weights.size)) and np.all(weights[idx] > 0)
