"""Particle filters on batched generated C (see sir.py)."""
from .sir import CubatureKalmanFilter, CubatureParticleFilter, ParticleFilter, informative, measurement_residuals

__all__ = ["CubatureKalmanFilter", "CubatureParticleFilter", "ParticleFilter", "informative", "measurement_residuals"]
