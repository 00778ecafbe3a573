"""Resampling of weighted particles: schemes and the ESS policy (see schemes.py for the contract)."""
from .schemes import (RESAMPLERS, ResamplingPolicy, effective_sample_size, multinomial_resample, normalise_log_weights,
                      residual_resample, stratified_resample, systematic_resample)

__all__ = ["RESAMPLERS", "ResamplingPolicy", "effective_sample_size", "multinomial_resample", "normalise_log_weights",
           "residual_resample", "stratified_resample", "systematic_resample"]
