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


# ---------------------------------------------------------------- input checks

BAD_WEIGHTS = {
    "all zero": np.zeros(4),  # was: every ancestor the last particle
    "NaN": np.array([0.5, np.nan, 0.25, 0.25]),
    "negative": np.array([0.6, -0.1, 0.25, 0.25]),
    "inf": np.array([np.inf, 0.0, 0.0, 0.0]),
    "unnormalised": np.array([1.0, 2.0, 3.0, 4.0]),
    "slightly unnormalised": np.array([0.25, 0.25, 0.25, 0.25 + 1e-6]),
    "empty": np.zeros(0),
    "2-D": np.full((2, 2), 0.25),
}


@pytest.mark.parametrize("scheme", sorted(RESAMPLERS))
@pytest.mark.parametrize("case", sorted(BAD_WEIGHTS))
def test_resamplers_refuse_bad_weights_naming_them(scheme, case):
    with pytest.raises(ValueError, match="weights"):
        RESAMPLERS[scheme](BAD_WEIGHTS[case], np.random.default_rng(0))


@pytest.mark.parametrize("scheme", sorted(RESAMPLERS))
def test_resamplers_refuse_complex_weights_and_bad_rng_or_draws(scheme):
    with pytest.raises(TypeError, match="weights"):
        RESAMPLERS[scheme](np.full(4, 0.25 + 0j), np.random.default_rng(0))
    with pytest.raises(TypeError, match="rng"):
        RESAMPLERS[scheme](np.full(4, 0.25), 42)
    with pytest.raises(TypeError, match="n_draws"):
        RESAMPLERS[scheme](np.full(4, 0.25), np.random.default_rng(0), 2.5)
    with pytest.raises(ValueError, match="n_draws"):
        RESAMPLERS[scheme](np.full(4, 0.25), np.random.default_rng(0), -1)
    assert RESAMPLERS[scheme](np.full(4, 0.25), np.random.default_rng(0), 0).shape == (0,)


@pytest.mark.parametrize("scheme", sorted(RESAMPLERS))
def test_normalisation_round_off_is_absorbed_and_zero_weights_never_drawn(scheme):
    # a sum 1e-12 short of one with a zero-weight last particle: inside the tolerance, never drawn
    w = np.array([0.5, 0.5 - 1e-12, 0.0])
    counts = np.zeros(3)
    rng = np.random.default_rng(5)
    for _ in range(200):
        counts += np.bincount(RESAMPLERS[scheme](w, rng), minlength=3)
    assert counts[2] == 0 and counts.sum() == 600


def test_normalise_log_weights_refuses_nan_and_plus_inf():
    # was: [0, nan, -50] gave uniform weights
    for bad in ([0.0, np.nan, -50.0], [0.0, np.inf, -50.0], [np.nan, np.nan]):
        with pytest.raises(ValueError, match="log_weights"):
            normalise_log_weights(np.array(bad))
    with pytest.raises(ValueError, match="log_weights"):
        normalise_log_weights(np.zeros(0))
    with pytest.raises(TypeError, match="log_weights"):
        normalise_log_weights(np.zeros(3, dtype=complex))


def test_normalise_log_weights_with_some_minus_inf():
    w, log_mean = normalise_log_weights(np.array([0.0, -np.inf, 0.0, -np.inf]))
    assert w.tolist() == [0.5, 0.0, 0.5, 0.0] and np.isclose(log_mean, np.log(0.5))


def test_effective_sample_size_and_policy_check_weights():
    with pytest.raises(ValueError, match="weights"):
        effective_sample_size(np.array([0.5, np.nan, 0.5]))
    with pytest.raises(ValueError, match="weights"):
        ResamplingPolicy().should_resample(np.zeros(3))
    with pytest.raises(ValueError, match="threshold"):
        ResamplingPolicy(threshold=float("nan"))
    with pytest.raises(TypeError, match="threshold"):
        ResamplingPolicy(threshold=1j)


def test_a_uniform_rounded_up_to_one_draws_the_last_particle_with_weight():
    from abyssal.runtime.resampling.schemes import inverse_cdf

    # systematic uniforms (k + U) / m: the largest U below 1 rounds (m - 1 + U) up to m, so u = 1.0
    m, U = 3, np.nextafter(1.0, 0.0)
    assert (m - 1 + U) / m == 1.0
    weights = np.array([0.25, 0.75, 0.0])  # the last particle has no weight
    assert list(inverse_cdf(weights, np.array([0.1, 0.5, 1.0]))) == [0, 1, 1]
    assert list(inverse_cdf(np.array([0.5, 0.5]), np.array([1.0, 1.0]))) == [1, 1]


def test_ancestors_in_c_equal_the_schemes_from_the_same_uniforms():
    """compiled.resample.Ancestors (the C the carried proposals resample with) gives the systematic and multinomial
    schemes' ancestors bit for bit from the same Generator draws, with zero weights, ties and a last uniform at 1."""
    from abyssal.runtime.compiled.resample import Ancestors, gather_items, gather_rows
    from abyssal.runtime.resampling import multinomial_resample
    from abyssal.runtime.resampling.schemes import inverse_cdf

    rng = np.random.default_rng(4)
    anc = Ancestors(5000)
    for trial in range(200):
        n = int(rng.integers(1, 5000))
        w = rng.random(n) ** 6 * (rng.random(n) > 0.3)
        w[int(rng.integers(n))] += 1e-3
        w /= w.sum()
        seed = int(rng.integers(2**40))
        a, b = np.random.default_rng(seed), np.random.default_rng(seed)
        np.testing.assert_array_equal(anc.systematic(w, a.random()), systematic_resample(w, b))
        np.testing.assert_array_equal(anc.multinomial(w, a.random(n)), multinomial_resample(w, b))
        assert a.bit_generator.state == b.bit_generator.state
    w = np.array([0.2, 0.3, 0.5, 0.0])
    assert anc.systematic(w, 1.0 - 2**-53, 4)[-1] == 2  # the last particle of positive weight
    assert anc.multinomial(w, np.array([1.0, 0.0, 0.5])).tolist() == [0, 2, 2]  # sorted: 0, 0.5, 1.0
    # m != n, one particle holding nearly all the weight (its bucket range spans most particles), uniforms near 1,
    # weights with a negative entry (the sorted walk's own result)
    for n, m in ((3000, 700), (400, 4900), (1, 50), (2000, 2000)):
        w = np.full(n, 1e-300)
        w[rng.random(n) < 0.5] = 0.0
        w[int(rng.integers(n))] = 1.0
        u = np.concatenate([rng.random(m - 3), [1.0 - 2**-53, 0.0, 1.0]])
        rng.shuffle(u)
        np.testing.assert_array_equal(anc.multinomial(w, u), inverse_cdf(w, np.sort(u)))
    # cdf 0.4, 0.3, 0.8, 1.0 is not monotone: the walk over the sorted uniforms 0.1, 0.35, 0.6, 0.9 defines it
    assert anc.multinomial(np.array([0.4, -0.1, 0.5, 0.2]), np.array([0.9, 0.1, 0.35, 0.6])).tolist() == [0, 0, 2, 3]
    with pytest.raises(ValueError, match="Ancestors"):
        anc.multinomial(np.ones(5001) / 5001, np.zeros(3))
    src = rng.normal(size=(3, 40))
    dst = np.zeros((3, 40))
    idx = np.array([5, 5, 0, 39, 7], dtype=np.int64)
    gather_rows(dst, src, idx)
    np.testing.assert_array_equal(dst[:, :5], src[:, idx])
    blocks = rng.normal(size=(40, 2, 2))
    out = np.zeros_like(blocks)
    gather_items(out, blocks, idx, 4)
    np.testing.assert_array_equal(out[:5], blocks[idx])
