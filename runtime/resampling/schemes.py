"""Resampling of weighted particles.

Contract: every scheme takes normalised weights ``w`` (shape (N,), non-negative, summing to
one), a ``numpy.random.Generator`` and the number of draws ``M`` (default N), and returns
``M`` ancestor indices (int64, shape (M,)) such that the expected number of copies of
particle i is ``M * w[i]`` (unbiased). Randomness comes only from the passed generator, so a
run is reproducible from its seed.

Schemes:

* ``multinomial_resample`` -- M independent draws from the categorical distribution (highest
  variance; the textbook reference).
* ``stratified_resample``  -- one uniform draw in each of the M strata [j/M, (j+1)/M).
* ``systematic_resample``  -- one uniform offset shared by all strata (lowest variance in
  practice, cheapest; the default).
* ``residual_resample``    -- floor(M w_i) deterministic copies, the remainder drawn
  multinomially from the residual weights.

``effective_sample_size`` gives 1 / sum w_i^2, and ``ResamplingPolicy`` decides when to
resample: every step, or when the ESS falls below ``threshold * N``.

Input checks (every public function here): ``weights`` must be a non-empty 1-D array of real
numbers, finite, non-negative, with ``|sum - 1| <= WEIGHT_SUM_TOLERANCE`` (1e-9); anything else is
a ValueError (TypeError for complex or non-numeric arrays) naming ``weights``. The tolerance
absorbs the round-off of a normalisation (about N * 2e-16); inside it the weights are used as if
divided by their sum (the cumulative sum is divided by its last entry), so a zero-weight particle
is never an ancestor. Weights that are not normalised (e.g. all zero, or raw likelihoods) are
refused rather than silently renormalised: they mean a bug upstream. ``rng`` must be a
``numpy.random.Generator`` and ``n_draws`` an integer >= 0. ``normalise_log_weights`` refuses
NaN and +inf log weights and documents its all -inf case.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from abyssal.arrays import real_array

Resampler = Callable[[np.ndarray, np.random.Generator, "int | None"], np.ndarray]

#: largest accepted |sum(weights) - 1| (normalisation round-off is about N * 2e-16)
WEIGHT_SUM_TOLERANCE = 1e-9


def _real_vector(values, name: str) -> np.ndarray:
    """values as a non-empty 1-D float64 array; TypeError for complex/non-numeric, ValueError for shape."""
    arr = real_array(values, name)
    if arr.ndim != 1 or arr.shape[0] == 0:
        raise ValueError(f"{name} must be a non-empty 1-D array, got shape {arr.shape}")
    return arr


def check_weights(weights) -> np.ndarray:
    """Normalised particle weights as float64 (N,), or a ValueError/TypeError naming ``weights``.

    Two reductions on the hot path: a NaN or inf anywhere makes the sum non-finite, a negative
    entry makes the minimum negative; only then is the slow diagnosis run for the message.
    """
    w = _real_vector(weights, "weights")
    total = float(w.sum())  # (entries near 1e308 overflow it with a RuntimeWarning, then are refused below)
    if abs(total - 1.0) <= WEIGHT_SUM_TOLERANCE and w.min() >= 0.0:
        return w
    if not np.all(np.isfinite(w)):
        bad = np.flatnonzero(~np.isfinite(w))
        raise ValueError(f"weights must be finite; {bad.size} entries are not (first at index {bad[0]}: {w[bad[0]]})")
    if w.min() < 0.0:
        bad = np.flatnonzero(w < 0)
        raise ValueError(f"weights must be non-negative; {bad.size} entries are negative (first at index {bad[0]}: {w[bad[0]]})")
    if total == 0.0:
        raise ValueError("weights are all zero: there is no particle to draw (normalise non-zero weights first)")
    raise ValueError(f"weights must sum to one (within {WEIGHT_SUM_TOLERANCE:g}); they sum to {total!r}: normalise them first")


def _check_rng(rng) -> np.random.Generator:
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator (e.g. numpy.random.default_rng(seed)), got {type(rng).__name__}")
    return rng


def _draws(weights: np.ndarray, n_draws) -> int:
    if n_draws is None:
        return weights.shape[0]
    if isinstance(n_draws, (bool, np.bool_)) or not isinstance(n_draws, (int, np.integer)):
        raise TypeError(f"n_draws must be an integer, got {type(n_draws).__name__}")
    if n_draws < 0:
        raise ValueError(f"n_draws must be >= 0, got {n_draws}")
    return int(n_draws)


def inverse_cdf(weights: np.ndarray, sorted_uniforms: np.ndarray) -> np.ndarray:
    """Indices i with cdf[i-1] <= u < cdf[i] for sorted u in [0, 1].

    A u of 1.0 (systematic and stratified uniforms (k + U) / m can round up to it) draws the last particle of
    positive weight, never the index len(weights) nor a particle of zero weight."""
    cdf = np.cumsum(weights)
    cdf /= cdf[-1]  # absorb round-off (within WEIGHT_SUM_TOLERANCE) so every u < 1 finds an index
    indices = np.searchsorted(cdf, sorted_uniforms, side="right")
    if indices.size and indices[-1] == cdf.size:  # sorted: only the last ones can be beyond the end
        indices[indices == cdf.size] = np.flatnonzero(weights)[-1]
    return indices


def multinomial_resample(weights: np.ndarray, rng: np.random.Generator, n_draws: int | None = None) -> np.ndarray:
    weights = check_weights(weights)
    m = _draws(weights, n_draws)
    return inverse_cdf(weights, np.sort(_check_rng(rng).random(m)))


def stratified_resample(weights: np.ndarray, rng: np.random.Generator, n_draws: int | None = None) -> np.ndarray:
    weights = check_weights(weights)
    m = _draws(weights, n_draws)
    return inverse_cdf(weights, (np.arange(m) + _check_rng(rng).random(m)) / max(m, 1))


def systematic_resample(weights: np.ndarray, rng: np.random.Generator, n_draws: int | None = None) -> np.ndarray:
    weights = check_weights(weights)
    m = _draws(weights, n_draws)
    return inverse_cdf(weights, (np.arange(m) + _check_rng(rng).random()) / max(m, 1))


def residual_resample(weights: np.ndarray, rng: np.random.Generator, n_draws: int | None = None) -> np.ndarray:
    weights = check_weights(weights)
    m = _draws(weights, n_draws)
    rng = _check_rng(rng)
    total = float(weights.sum())
    if total != 1.0:
        weights = weights / total  # round-off within WEIGHT_SUM_TOLERANCE
    copies = np.floor(m * weights).astype(np.int64)
    deterministic = np.repeat(np.arange(weights.shape[0]), copies)
    n_rest = m - deterministic.shape[0]
    if n_rest == 0:
        return deterministic
    residual = m * weights - copies
    rest = inverse_cdf(residual, np.sort(rng.random(n_rest)))  # multinomial draws from the residual weights
    return np.sort(np.concatenate([deterministic, rest]))


RESAMPLERS: dict[str, Resampler] = {
    "multinomial": multinomial_resample,
    "stratified": stratified_resample,
    "systematic": systematic_resample,
    "residual": residual_resample,
}


def normalise_log_weights(log_weights: np.ndarray) -> tuple[np.ndarray, float]:
    """(normalised weights, log of the mean unnormalised weight) by log-sum-exp.

    ``log_weights``: non-empty 1-D real array; entries may be -inf (zero weight), never NaN or
    +inf (ValueError naming ``log_weights``: a NaN is a bug upstream, e.g. a diverged particle,
    and must not be turned into weights).

    All -inf (every likelihood underflowed, e.g. an outlier far beyond every particle): the
    weights fall back to uniform and the log-mean is -inf. The caller keeps the particles, which
    is the only unbiased choice without information, and can see from the -inf that it happened.
    """
    if not (type(log_weights) is np.ndarray and log_weights.dtype == np.float64 and log_weights.ndim == 1
            and log_weights.shape[0]):  # (the checks cost more than the work for a filter's own weights)
        log_weights = _real_vector(log_weights, "log_weights")
    n = log_weights.shape[0]
    peak = float(log_weights.max())  # NaN anywhere makes the maximum NaN
    if peak == -math.inf:
        return np.full(n, 1.0 / n), -math.inf
    if not math.isfinite(peak):
        bad = np.flatnonzero(np.isnan(log_weights) | (log_weights == math.inf))
        raise ValueError(f"log_weights must not contain NaN or +inf; {bad.size} entries do "
                         f"(first at index {bad[0]}: {log_weights[bad[0]]})")
    weights = log_weights - peak
    np.exp(weights, out=weights)
    total = float(weights.sum())
    weights /= total
    return weights, peak + math.log(total / n)


def effective_sample_size(weights: np.ndarray) -> float:
    """1 / sum w_i^2 of normalised weights (N for uniform weights, 1 for a single survivor)."""
    weights = check_weights(weights)
    return 1.0 / float(np.dot(weights, weights))


@dataclass(frozen=True)
class ResamplingPolicy:
    """When and how to resample, at a fixed particle number.

    scheme: a key of RESAMPLERS. threshold: resample when ESS < threshold * N; 1.0 (or more)
    means every step, 0 never.

    A resampling policy (this class, or ``KLDResampling`` which also sets the next particle number) tells
    the SIR engine (filters/particle/engine.py) three things: ``capacity(n)``, the most particles it can
    ever ask for when a filter starts with n; ``due(ess, n)``, whether to resample now; and
    ``ancestors(weights, rng, states)``, the indices of the particles kept (as many as the next step runs
    with).
    """

    scheme: str = "systematic"
    threshold: float = 0.5

    def __post_init__(self):
        if self.scheme not in RESAMPLERS:
            raise ValueError(f"unknown resampling scheme {self.scheme!r}; choose one of {sorted(RESAMPLERS)}")
        if isinstance(self.threshold, (bool, np.bool_)) or not isinstance(self.threshold, (int, float, np.integer, np.floating)):
            raise TypeError(f"threshold must be a real number, got {type(self.threshold).__name__}")
        if not self.threshold >= 0:
            raise ValueError(f"threshold must be >= 0, got {self.threshold}")

    def capacity(self, n_particles: int) -> int:
        """The largest particle number this policy leads to from n_particles: n_particles (fixed N)."""
        return n_particles

    def check(self, n_states: int) -> None:
        """Whether the policy fits a state of n_states rows (nothing to check at a fixed N)."""

    def due(self, ess: float, n: int) -> bool:
        """Resample now? (every step at threshold >= 1, else when ESS < threshold * N)"""
        return self.threshold >= 1.0 or ess < self.threshold * n

    def should_resample(self, weights: np.ndarray) -> bool:
        return self.due(effective_sample_size(weights), weights.shape[0])

    def ancestors(self, weights: np.ndarray, rng: np.random.Generator, states: np.ndarray | None = None) -> np.ndarray:
        """N ancestor indices drawn by the scheme (states unused at a fixed N)."""
        return RESAMPLERS[self.scheme](weights, rng, None)
