"""Noise models as data: Gaussian mixtures and weighted EM (later: fuzzy and GP noise models)."""
from .mixtures import (GaussianMixture, initial_mixture, logsumexp, merge_components, reduce_mixture, weighted_em,
                       weighted_moments)

__all__ = ["GaussianMixture", "initial_mixture", "logsumexp", "merge_components", "reduce_mixture", "weighted_em",
           "weighted_moments"]
