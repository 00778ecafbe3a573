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
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

Resampler = Callable[[np.ndarray, np.random.Generator, "int | None"], np.ndarray]


def _draws(weights: np.ndarray, n_draws: int | None) -> int:
    return weights.shape[0] if n_draws is None else int(n_draws)


def _inverse_cdf(weights: np.ndarray, sorted_uniforms: np.ndarray) -> np.ndarray:
    """Indices i with cdf[i-1] <= u < cdf[i] for sorted u in [0, 1)."""
    cdf = np.cumsum(weights)
    cdf[-1] = 1.0  # absorb round-off so every u < 1 finds an index
    return np.searchsorted(cdf, sorted_uniforms, side="right")


def multinomial_resample(weights: np.ndarray, rng: np.random.Generator, n_draws: int | None = None) -> np.ndarray:
    m = _draws(weights, n_draws)
    return _inverse_cdf(weights, np.sort(rng.random(m)))


def stratified_resample(weights: np.ndarray, rng: np.random.Generator, n_draws: int | None = None) -> np.ndarray:
    m = _draws(weights, n_draws)
    return _inverse_cdf(weights, (np.arange(m) + rng.random(m)) / m)


def systematic_resample(weights: np.ndarray, rng: np.random.Generator, n_draws: int | None = None) -> np.ndarray:
    m = _draws(weights, n_draws)
    return _inverse_cdf(weights, (np.arange(m) + rng.random()) / m)


def residual_resample(weights: np.ndarray, rng: np.random.Generator, n_draws: int | None = None) -> np.ndarray:
    m = _draws(weights, n_draws)
    copies = np.floor(m * weights).astype(np.int64)
    deterministic = np.repeat(np.arange(weights.shape[0]), copies)
    n_rest = m - deterministic.shape[0]
    if n_rest == 0:
        return deterministic
    residual = m * weights - copies
    rest = multinomial_resample(residual / residual.sum(), rng, n_rest)
    return np.sort(np.concatenate([deterministic, rest]))


RESAMPLERS: dict[str, Resampler] = {
    "multinomial": multinomial_resample,
    "stratified": stratified_resample,
    "systematic": systematic_resample,
    "residual": residual_resample,
}


def normalise_log_weights(log_weights: np.ndarray) -> tuple[np.ndarray, float]:
    """(normalised weights, log of the mean unnormalised weight) by log-sum-exp.

    When every log weight is -inf (all likelihoods underflowed, e.g. an outlier far beyond every
    particle) the weights fall back to uniform and the log-mean is -inf: the caller keeps the
    particles, which is the only unbiased choice without information.
    """
    log_weights = np.asarray(log_weights)
    n = log_weights.shape[0]
    peak = float(log_weights.max())
    if not math.isfinite(peak):
        return np.full(n, 1.0 / n), -np.inf
    weights = log_weights - peak
    np.exp(weights, out=weights)
    total = float(weights.sum())
    weights /= total
    return weights, peak + math.log(total / n)


def effective_sample_size(weights: np.ndarray) -> float:
    """1 / sum w_i^2 of normalised weights (N for uniform weights, 1 for a single survivor)."""
    return 1.0 / float(np.dot(weights, weights))


@dataclass(frozen=True)
class ResamplingPolicy:
    """When and how to resample.

    scheme: a key of RESAMPLERS. threshold: resample when ESS < threshold * N; 1.0 (or more)
    means every step, 0 never.
    """

    scheme: str = "systematic"
    threshold: float = 0.5

    def __post_init__(self):
        if self.scheme not in RESAMPLERS:
            raise ValueError(f"unknown resampling scheme {self.scheme!r}; choose one of {sorted(RESAMPLERS)}")
        if not self.threshold >= 0:
            raise ValueError(f"threshold must be >= 0, got {self.threshold}")

    def should_resample(self, weights: np.ndarray) -> bool:
        return self.threshold >= 1.0 or effective_sample_size(weights) < self.threshold * weights.shape[0]

    def ancestors(self, weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        return RESAMPLERS[self.scheme](weights, rng, None)
