"""Resampling of weighted particles: schemes and the ESS policy (schemes.py), KLD-resampling (kld.py)."""
from .kld import KLDResampling, kld_resample, kld_sample_size
from .schemes import (RESAMPLERS, ResamplingPolicy, effective_sample_size, multinomial_resample, normalise_log_weights,
                      residual_resample, stratified_resample, systematic_resample)

__all__ = ["KLDResampling", "RESAMPLERS", "ResamplingPolicy", "effective_sample_size", "kld_resample",
           "kld_sample_size", "multinomial_resample", "normalise_log_weights", "residual_resample",
           "stratified_resample", "systematic_resample"]
