"""KLD-resampling: an adaptive particle number (Fox 2003; Li, Sun & Sattar 2013; seed 002 eq. 40-41).

    n = kld_sample_size(k, epsilon, delta)                     # Fox's bound, no clamping
    ancestors = kld_resample(weights, states, rng, KLDResampling(...))
    SIRFilter(..., policy=KLDResampling(n_max=2000))          # a resampling policy: every step, N adapts

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
draw count n with n >= clamp(N(k), N_min, N_max). The uniforms come in chunks (the first of N_min
draws, then ``chunk``; the kept draws do not depend on the chunk size, but the generator advances
by whole chunks, so the draws after a resampling do), one C call per chunk. The
result never has more than N_max entries (PCL overran its maximum: pcl #1391/#1392) and never
fewer than N_min. Each draw is an independent categorical draw from the weights; only the stopping
time depends on them (through the bins they occupy). tests/runtime/test_kld.py checks that the
resampled frequencies copies_i / n match w_i within their standard errors and that the weighted
mean is preserved.

Bins: the regular grid floor(x / width) along each binned coordinate, indexed relative to the cloud's
lowest occupied bin (never from the origin, so a cloud far from the origin with small bins is binned like
one near it); two particles share a bin when every index is equal. Beyond 2^53 bin widths from the origin
doubles no longer resolve neighbouring bins: such particles share bins.

The draws are C (runtime/c/abyssal_resample.h, ``compiled.resample.KLDSampler``): the uniforms are the
Generator's, chunk by chunk as above, and each draw is binned when it is drawn, into a hash set of the
occupied bins; nothing renumbers the bins of all N particles (the cloud's lowest bin is one minimum per
binned row). tests/runtime/test_kld.py checks the ancestors against the former NumPy form (every particle's
bin numbered by ``numpy.unique``, the chunk's new bins by a second ``numpy.unique``) on random clouds.

As a resampling policy of the SIR engine (``ResamplingPolicy``'s interface): KLD-resampling resamples
every step (``due``), its ``ancestors`` are ``kld_resample``'s (their number is the next step's
particle number), and ``capacity(n)`` = max(n, n_max) sizes the engine's buffers.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import ClassVar

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
    """Parameters of KLD-resampling (defaults: seed 002 Table 6 and section 4.1), and the resampling policy
    that applies it (module docstring).

    epsilon, delta: the KLD error bound and its confidence (0.15, 0.01); bin_size: bin widths
    along ``coordinates`` (the state rows binned: x, y with 10 m bins); n_min, n_max: the clamp of
    the particle number (n_max = 2000; n_min = 50, ours: the paper states none); chunk: draws per
    vectorised chunk.
    """

    #: resample every step (a policy's threshold; not a field)
    threshold: ClassVar[float] = 1.0

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

    # ---------------------------------------------------------------- the resampling policy
    def capacity(self, n_particles: int) -> int:
        """The most particles a filter starting with n_particles holds: max(n_particles, n_max)."""
        return max(int(n_particles), int(self.n_max))

    def check(self, n_states: int) -> None:
        """The binned coordinates must be rows of the state."""
        if not all(0 <= c < n_states for c in self.coordinates):
            raise ValueError(f"resampling.coordinates must name rows of the {n_states}-state, got {self.coordinates}")

    def due(self, ess: float, n: int) -> bool:
        """Every step."""
        return True

    def ancestors(self, weights: np.ndarray, rng: np.random.Generator, states: np.ndarray | None = None) -> np.ndarray:
        """``kld_resample`` of the weighted states: n_min..n_max indices, the next particle number."""
        return kld_resample(weights, states, rng, self)


@lru_cache(maxsize=32)
def _limit_table(epsilon, delta, n_min, n_max) -> np.ndarray:
    table = np.clip(kld_sample_size(np.arange(1, n_max + 1), epsilon, delta), n_min, n_max)
    return np.concatenate([[n_min], table])


def kld_resample(weights, states: np.ndarray, rng: np.random.Generator,
                 params: KLDResampling = KLDResampling()) -> np.ndarray:
    """Ancestor indices (int64, n_min <= len <= n_max) drawn until n >= clamp(N(k)) (module docstring).

    weights (N,) normalised; states (n, N) the particles (their binned rows set the bins).
    """
    from ..compiled.resample import KLDSampler

    w = check_weights(weights)
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    states = np.asarray(states, dtype=np.float64)
    if states.ndim != 2 or states.shape[1] != w.shape[0]:
        raise ValueError(f"states must have shape (n, {w.shape[0]}), got {states.shape}")
    return KLDSampler(w.shape[0], int(params.n_max), len(params.coordinates)).ancestors(w, states, rng, params)
