"""Gaussian-sum filters on batched generated cubature steps (see gaussian_sum.py)."""
from .gaussian_sum import EMMixtureCubatureParticleFilter, GaussianSumCKF, MixtureCubatureParticleFilter

__all__ = ["EMMixtureCubatureParticleFilter", "GaussianSumCKF", "MixtureCubatureParticleFilter"]
