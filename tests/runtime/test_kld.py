"""KLD-resampling (runtime/resampling/kld.py): Fox's bound, the adaptive draw, unbiasedness."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import norm

import abyssal.runtime
from abyssal.runtime.resampling import KLDResampling, kld_resample, kld_sample_size


def fox_reference(k: int, epsilon: float, delta: float) -> int:
    """Fox 2003 eq. 13 written out independently, z from scipy.stats.norm.ppf."""
    z = norm.ppf(1 - delta)
    a = 2 / (9 * (k - 1))
    return int(np.ceil((k - 1) / (2 * epsilon) * (1 - a + np.sqrt(a) * z) ** 3))


@pytest.mark.parametrize("epsilon,delta", [(0.15, 0.01), (0.05, 0.01), (0.3, 0.05)])
def test_formula_matches_scipy_quantile_for_k_2_to_1000(epsilon, delta):
    ks = np.arange(2, 1001)
    got = kld_sample_size(ks, epsilon, delta)
    want = np.array([fox_reference(int(k), epsilon, delta) for k in ks])
    np.testing.assert_array_equal(got, want)
    assert all(kld_sample_size(int(k), epsilon, delta) == want[k - 2] for k in ks[::97])  # scalar path


def test_seed_002_values_and_public_export():
    assert abyssal.runtime.kld_sample_size is kld_sample_size
    assert [kld_sample_size(k, 0.15, 0.01) for k in (2, 10, 100, 500)] == [22, 73, 449, 1919]
    # not clamped: beyond N_max = 2000 from k = 523 on
    assert kld_sample_size(523, 0.15, 0.01) > 2000
    # the misprinted form (z inside the square root) would give a different, smaller number
    a = 2 / 9
    assert kld_sample_size(2, 0.15, 0.01) != int(np.ceil(1 / 0.3 * (1 - a + np.sqrt(a * norm.ppf(0.99))) ** 3))


def test_k_one_and_bad_arguments():
    assert kld_sample_size(1, 0.15, 0.01) == 1
    for bad in (0, -3):
        with pytest.raises(ValueError, match="k"):
            kld_sample_size(bad, 0.15, 0.01)
    with pytest.raises(ValueError, match="epsilon"):
        kld_sample_size(5, 0.0, 0.01)
    with pytest.raises(ValueError, match="delta"):
        kld_sample_size(5, 0.15, 1.0)


def _cloud(rng, spread, N=5000):
    return rng.normal(0.0, spread, (2, N)) + np.array([[1234.0], [-567.0]])


def test_particle_number_tracks_posterior_spread():
    rng = np.random.default_rng(1)
    w = np.full(5000, 1 / 5000)
    params = KLDResampling()
    sizes = {s: np.mean([len(kld_resample(w, _cloud(rng, s), rng, params)) for _ in range(5)]) for s in (0.5, 5, 20, 60, 500)}
    assert sizes[0.5] == params.n_min  # one or a few bins: the floor
    assert sizes[0.5] < sizes[5] < sizes[20] < sizes[60]
    assert sizes[500] == params.n_max  # spread over far more than 523 bins: the cap, never above
    # the stopping rule: n >= clamp(N(k)) at the end, and not reached one draw earlier
    X = _cloud(rng, 20)
    idx = kld_resample(w, X, rng, params)
    keys = {tuple(np.floor(X[:, i] / 10)) for i in idx}
    assert len(idx) >= params.limit(len(keys))
    keys_before = {tuple(np.floor(X[:, i] / 10)) for i in idx[:-1]}
    assert len(idx) - 1 < params.limit(len(keys_before))


def test_never_above_n_max_or_below_n_min_and_chunking_invisible():
    rng = np.random.default_rng(2)
    X = _cloud(rng, 1e4)
    w = rng.random(5000)
    w /= w.sum()
    for chunk in (1, 7, 512, 5000):
        params = KLDResampling(n_min=10, n_max=300, chunk=chunk)
        out = [kld_resample(w, X, np.random.default_rng(s), params) for s in range(3)]
        assert all(10 <= len(o) <= 300 for o in out)
    # the same generator stream gives the same draws whatever the chunk size
    a = kld_resample(w, _cloud(np.random.default_rng(3), 15), np.random.default_rng(9), KLDResampling(chunk=3))
    b = kld_resample(w, _cloud(np.random.default_rng(3), 15), np.random.default_rng(9), KLDResampling(chunk=1000))
    np.testing.assert_array_equal(a, b)


def test_resampled_set_is_unbiased():
    """Mean over repetitions of (copies of particle i) / n equals w_i (chi-square-free z-test per particle)."""
    rng = np.random.default_rng(4)
    N = 40
    X = np.vstack([np.arange(N) * 10.0 + 5.0, np.zeros(N)])  # one bin per particle: k grows with each new ancestor
    w = rng.random(N) ** 3
    w /= w.sum()
    reps = 4000
    freq = np.zeros(N)
    for _ in range(reps):
        idx = kld_resample(w, X, rng, KLDResampling(n_min=5, n_max=2000))
        freq += np.bincount(idx, minlength=N) / len(idx)
    freq /= reps
    # standard error of a frequency of a draw of >= 5 is at most sqrt(w (1 - w) / (5 reps))
    se = np.sqrt(w * (1 - w) / (5 * reps))
    assert np.all(np.abs(freq - w) < 5 * se + 1e-12)
    # and the weighted mean of the states is preserved
    mean = np.mean([X[0, kld_resample(w, X, rng)].mean() for _ in range(2000)])
    assert abs(mean - w @ X[0]) < 5 * np.sqrt(w @ (X[0] - w @ X[0]) ** 2 / 2000 / 5)


def test_refusals_name_their_argument():
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="weights"):
        kld_resample(np.array([0.5, 0.6]), np.zeros((2, 2)), rng)
    with pytest.raises(ValueError, match="states"):
        kld_resample(np.array([0.5, 0.5]), np.zeros((2, 3)), rng)
    with pytest.raises(TypeError, match="rng"):
        kld_resample(np.array([0.5, 0.5]), np.zeros((2, 2)), 3)


def _former_kld_resample(w, states, rng, params):
    """kld_resample as NumPy wrote it before the draws moved to C: every particle's bin numbered by numpy.unique over
    all N, each chunk's new bins by a second numpy.unique (an independent oracle of the same rule)."""
    index = np.empty((len(params.coordinates), states.shape[1]))
    for i, (row, width) in enumerate(zip(params.coordinates, params.bin_size)):
        with np.errstate(over="ignore"):
            np.divide(states[row], width, out=index[i])
        np.clip(index[i], -1e300, 1e300, out=index[i])
        np.floor(index[i], out=index[i])
        index[i] -= index[i].min()
    if 21 * index.shape[0] <= 63 and index.max(initial=0.0) < 2**21:
        key = np.zeros(states.shape[1], dtype=np.int64)
        for row in index:
            key = key * (2**21) + row.astype(np.int64)
        bin_of = np.unique(key, return_inverse=True)[1]
    else:
        bin_of = np.unique(index, axis=1, return_inverse=True)[1].reshape(-1)
    occupied = np.zeros(int(bin_of.max()) + 1, dtype=bool)
    limit = params.limit_table()
    cumulative = np.cumsum(w)
    cumulative /= cumulative[-1]
    drawn, n_done, k = [], 0, 0
    while n_done < params.n_max:
        size = min(int(params.chunk) if n_done else max(int(params.n_min), 1), params.n_max - n_done)
        idx = np.minimum(np.searchsorted(cumulative, rng.random(size), side="right"), w.shape[0] - 1)
        bins = bin_of[idx]
        _, first = np.unique(bins, return_index=True)
        new = np.zeros(size, dtype=bool)
        new[first] = ~occupied[bins[first]]
        occupied[bins] = True
        k_after = k + np.cumsum(new)
        stop = np.flatnonzero(n_done + np.arange(1, size + 1) >= limit[k_after])
        if stop.size:
            drawn.append(idx[:int(stop[0]) + 1])
            return np.concatenate(drawn).astype(np.int64)
        drawn.append(idx)
        k, n_done = int(k_after[-1]), n_done + size
    return np.concatenate(drawn).astype(np.int64)


def test_bins_counted_on_the_drawn_keys_equal_the_former_numpy_renumbering():
    """The C draws (each drawn particle binned into a hash set of occupied bins) give the former NumPy form's
    ancestors and leave the Generator where it left it, on random clouds: 1 to 3 binned rows, clouds near and far
    from the origin (1e7, -3e9), on the grid (integer states), every particle in one bin, wider than 2^21 bins."""
    rng = np.random.default_rng(0)
    for trial in range(250):
        N, D = int(rng.integers(1, 2500)), int(rng.integers(1, 4))
        params = KLDResampling(bin_size=tuple(rng.uniform(0.1, 20.0, D)), coordinates=tuple(range(1, D + 1)),
                               n_min=int(rng.integers(1, 60)), n_max=int(rng.integers(60, 2500)),
                               chunk=int(rng.integers(1, 600)))
        states = rng.normal(size=(D + 2, N)) * 10 ** rng.uniform(-2, 4) + rng.choice([0.0, 1e7, -3e9])
        if trial % 7 == 0:
            states = np.round(states)
        if trial % 11 == 0:
            states[1:] = 0.25
        if trial % 13 == 0:
            states[1] *= 1e9
        w = rng.random(N) ** 4
        w /= w.sum()
        seed = int(rng.integers(2**40))
        a, b = np.random.default_rng(seed), np.random.default_rng(seed)
        np.testing.assert_array_equal(kld_resample(w, states, a, params), _former_kld_resample(w, states, b, params),
                                      err_msg=f"trial {trial}")
        assert a.bit_generator.state == b.bit_generator.state, trial
