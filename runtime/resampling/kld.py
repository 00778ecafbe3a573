"""KLD-resampling: an adaptive particle number (Fox 2003; Li, Sun & Sattar 2013; seed 002 eq. 40-41).

    n = kld_sample_size(k, epsilon, delta)                     # Fox's bound, no clamping
    ancestors = kld_resample(weights, states, rng, KLDResampling(...))

``kld_sample_size(k, epsilon, delta)`` is the number of draws that keeps the Kullback-Leibler
distance between the histogram of the draws over k occupied bins and the true (binned)
distribution below epsilon with probability 1 - delta (Wilson-Hilferty approximation of the
chi-square quantile):

    N(k) = ceil( (k - 1) / (2 epsilon) * (1 - 2 / (9 (k - 1)) + sqrt(2 / (9 (k - 1))) * z_{1-delta})^3 )

with z_{1-delta} the upper 1 - delta quantile of the standard normal (z = 2.326 for delta = 0.01).
Seed 002 prints z inside the square root and calls it the "upper quartile": both are misprints
(Fox 2003 eq. 13 and ROS amcl's ``pf_resample_limit`` put it outside; a quartile would be
delta = 0.25). With epsilon = 0.15, delta = 0.01: N = 22, 73, 449, 1919 for k = 2, 10, 100, 500.

k = 1 (every draw so far in one bin): the bound is undefined (it has k - 1 in a denominator) and a
one-bin histogram is represented exactly by any number of draws, so N(1) = 1; the resampler's
floor N_min then decides. (ROS amcl returns its maximum for k <= 1 -- ros-planning/navigation
#1159 -- which spends N_max particles exactly when the posterior is tightest.)

``kld_resample`` draws ancestors from the categorical distribution of the weights (multinomial,
as Li et al.'s KLD-resampling does) and after each draw counts the occupied bins k of a regular
grid over chosen state coordinates (seed 002: x, y with 10 m x 10 m bins); it stops at the first
draw count n with n >= clamp(N(k), N_min, N_max). Draws come in chunks (the first of N_min
draws, then ``chunk``; the kept draws do not depend on the chunk size, but the generator advances
by whole chunks, so the draws after a resampling do): a chunk's bin keys are
compared with the bins already seen, k after each draw is a cumulative sum, and the stopping
draw is found with one vectorised comparison, so there is no Python iteration per particle. The
result never has more than N_max entries (PCL overran its maximum: pcl #1391/#1392) and never
fewer than N_min. Each draw is an independent categorical draw from the weights; only the stopping
time depends on them (through the bins they occupy). tests/runtime/test_kld.py checks that the
resampled frequencies copies_i / n match w_i within their standard errors and that the weighted
mean is preserved.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.special import ndtri

from .schemes import check_weights

__all__ = ["KLDResampling", "kld_resample", "kld_sample_size"]


def _z_upper(delta: float) -> float:
    """The upper 1 - delta quantile of the standard normal."""
    if not 0.0 < delta < 1.0:
        raise ValueError(f"delta must be in (0, 1), got {delta!r}")
    return float(ndtri(1.0 - delta))


def kld_sample_size(k, epsilon: float, delta: float):
    """Fox's KLD bound N(k) (module docstring); k an int >= 1 or an integer array. No clamping.

    Returns an int for a scalar k, an int64 array for an array k. N(1) = 1 (see module docstring).
    """
    if not (isinstance(epsilon, (int, float, np.floating)) and epsilon > 0 and math.isfinite(epsilon)):
        raise ValueError(f"epsilon must be a positive finite number, got {epsilon!r}")
    z = _z_upper(delta)
    k_arr = np.asarray(k)
    if k_arr.dtype.kind not in "iu" and not (k_arr.dtype.kind == "f" and np.all(k_arr == np.floor(k_arr))):
        raise TypeError(f"k must be an integer number of occupied bins, got {k!r}")
    if np.any(k_arr < 1):
        raise ValueError(f"k must be >= 1 (occupied bins), got {k!r}")
    km1 = np.maximum(k_arr.astype(np.float64) - 1.0, 1.0)  # k = 1 handled below
    a = 2.0 / (9.0 * km1)
    n = np.ceil(km1 / (2.0 * epsilon) * (1.0 - a + np.sqrt(a) * z) ** 3)
    n = np.where(k_arr <= 1, 1.0, n).astype(np.int64)
    return int(n) if n.ndim == 0 else n


@dataclass(frozen=True)
class KLDResampling:
    """Parameters of KLD-resampling (defaults: seed 002 Table 6 and section 4.1).

    epsilon, delta: the KLD error bound and its confidence (0.15, 0.01); bin_size: bin widths
    along ``coordinates`` (the state rows binned: x, y with 10 m bins); n_min, n_max: the clamp of
    the particle number (n_max = 2000; n_min = 50, ours: the paper states none); chunk: draws per
    vectorised chunk.
    """

    epsilon: float = 0.15
    delta: float = 0.01
    bin_size: tuple = (10.0, 10.0)
    coordinates: tuple = (0, 1)
    n_min: int = 50
    n_max: int = 2000
    chunk: int = 512

    def __post_init__(self):
        if not (self.epsilon > 0 and 0 < self.delta < 1):
            raise ValueError("KLDResampling needs epsilon > 0 and 0 < delta < 1")
        if len(self.bin_size) != len(self.coordinates) or not all(b > 0 for b in self.bin_size):
            raise ValueError("bin_size needs one positive width per binned coordinate")
        if not (1 <= int(self.n_min) <= int(self.n_max)) or int(self.chunk) < 1:
            raise ValueError(f"KLDResampling needs 1 <= n_min <= n_max and chunk >= 1, got {self.n_min}, {self.n_max}")

    def limit(self, k) -> np.ndarray:
        """clamp(N(k), n_min, n_max)."""
        return np.clip(kld_sample_size(k, self.epsilon, self.delta), self.n_min, self.n_max)

    def limit_table(self) -> np.ndarray:
        """limit(k) for k = 0..n_max (entry 0 unused), computed once per parameter set."""
        return _limit_table(self.epsilon, self.delta, int(self.n_min), int(self.n_max))


@lru_cache(maxsize=32)
def _limit_table(epsilon, delta, n_min, n_max) -> np.ndarray:
    table = np.clip(kld_sample_size(np.arange(1, n_max + 1), epsilon, delta), n_min, n_max)
    return np.concatenate([[n_min], table])


def _bin_keys(states: np.ndarray, params: KLDResampling) -> np.ndarray:
    """One int64 key per column of states (n, N): the bin index along each binned coordinate, packed."""
    key = np.zeros(states.shape[1], dtype=np.int64)
    for row, width in zip(params.coordinates, params.bin_size):
        index = np.floor(states[row] / width)
        if not np.all(np.abs(index) < 2**20):
            raise ValueError("kld_resample: a particle lies more than 2^20 bins from the origin (or is not finite)")
        key = key * (2**21) + (index.astype(np.int64) + 2**20)
    return key


def kld_resample(weights, states: np.ndarray, rng: np.random.Generator,
                 params: KLDResampling = KLDResampling()) -> np.ndarray:
    """Ancestor indices (int64, n_min <= len <= n_max) drawn until n >= clamp(N(k)) (module docstring).

    weights (N,) normalised; states (n, N) the particles (their binned rows set the bins).
    """
    w = check_weights(weights)
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    states = np.asarray(states, dtype=np.float64)
    if states.ndim != 2 or states.shape[1] != w.shape[0]:
        raise ValueError(f"states must have shape (n, {w.shape[0]}), got {states.shape}")
    _, bin_of = np.unique(_bin_keys(states, params), return_inverse=True)  # dense bin index per particle
    occupied = np.zeros(int(bin_of.max()) + 1, dtype=bool)
    limit = params.limit_table()
    cumulative = np.cumsum(w)
    cumulative /= cumulative[-1]
    drawn: list[np.ndarray] = []
    n_done, k = 0, 0
    while n_done < params.n_max:
        # the first chunk is n_min draws (never fewer are kept), later ones params.chunk
        size = min(int(params.chunk) if n_done else max(int(params.n_min), 1), params.n_max - n_done)
        idx = np.searchsorted(cumulative, rng.random(size), side="right")
        np.minimum(idx, w.shape[0] - 1, out=idx)
        bins = bin_of[idx]
        _, first = np.unique(bins, return_index=True)  # first draw of each bin inside the chunk ...
        new = np.zeros(size, dtype=bool)
        new[first] = ~occupied[bins[first]]  # ... counts if the bin was empty before the chunk
        occupied[bins] = True
        k_after = k + np.cumsum(new)
        count = n_done + np.arange(1, size + 1)
        stop = np.flatnonzero(count >= limit[k_after])
        if stop.size:
            drawn.append(idx[:int(stop[0]) + 1])
            return np.concatenate(drawn).astype(np.int64)
        drawn.append(idx)
        k = int(k_after[-1])
        n_done += size
    return np.concatenate(drawn).astype(np.int64)  # exactly n_max draws
