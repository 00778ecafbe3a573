import numpy as np
import pytest

from abyssal.runtime.resampling import (
    RESAMPLERS, ResamplingPolicy, effective_sample_size, normalise_log_weights, systematic_resample,
)

WEIGHTS = np.array([0.0, 0.05, 0.4, 0.01, 0.24, 0.3])


@pytest.mark.parametrize("scheme", sorted(RESAMPLERS))
def test_resampler_is_unbiased(scheme):
    rng = np.random.default_rng(11)
    n, repeats = WEIGHTS.shape[0], 4000
    counts = np.zeros(n)
    for _ in range(repeats):
        counts += np.bincount(RESAMPLERS[scheme](WEIGHTS, rng), minlength=n)
    mean_copies = counts / repeats
    expected = n * WEIGHTS
    # the multinomial count variance n w (1 - w) bounds every scheme's; 5 sigma of the mean of `repeats` draws
    bound = 5 * np.sqrt(np.maximum(expected * (1 - WEIGHTS), 0.25) / repeats)
    assert np.all(np.abs(mean_copies - expected) < bound), (mean_copies, expected)
    assert counts[0] == 0  # a zero-weight particle is never an ancestor


@pytest.mark.parametrize("scheme", sorted(RESAMPLERS))
def test_resampler_shape_range_and_draw_count(scheme):
    rng = np.random.default_rng(3)
    w = rng.random(50)
    w /= w.sum()
    idx = RESAMPLERS[scheme](w, rng, 80)
    assert idx.shape == (80,) and idx.dtype.kind == "i"
    assert idx.min() >= 0 and idx.max() < 50


@pytest.mark.parametrize("scheme", sorted(RESAMPLERS))
def test_resampler_reproducible_from_seed(scheme):
    w = np.random.default_rng(0).dirichlet(np.ones(30))
    a = RESAMPLERS[scheme](w, np.random.default_rng(42))
    b = RESAMPLERS[scheme](w, np.random.default_rng(42))
    assert np.array_equal(a, b)


def test_systematic_keeps_deterministic_part():
    # weights k/N give exactly k copies under systematic resampling
    w = np.array([0.5, 0.25, 0.25])
    counts = np.bincount(systematic_resample(w, np.random.default_rng(1), 4), minlength=3)
    assert counts.tolist() == [2, 1, 1]


def test_log_weights_normalise_without_nan():
    w, log_mean = normalise_log_weights(np.array([-1e12, -2e12, -1e12 - 3.0]))
    assert np.all(np.isfinite(w)) and np.isclose(w.sum(), 1.0) and w[0] > 0.9
    w, log_mean = normalise_log_weights(np.full(4, -np.inf))
    assert np.allclose(w, 0.25) and log_mean == -np.inf


def test_policy_thresholds():
    uniform = np.full(10, 0.1)
    peaked = np.array([0.91] + [0.01] * 9)
    assert effective_sample_size(uniform) == pytest.approx(10)
    assert not ResamplingPolicy(threshold=0.5).should_resample(uniform)
    assert ResamplingPolicy(threshold=0.5).should_resample(peaked)
    assert ResamplingPolicy(threshold=1.0).should_resample(uniform)  # every step
    with pytest.raises(ValueError):
        ResamplingPolicy(scheme="bogus")
