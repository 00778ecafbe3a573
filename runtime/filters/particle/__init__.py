"""Particle filters: one SIR engine (engine.py) with pluggable proposals (proposals.py) and resampling policies
(runtime/resampling); PF, CPF (sir.py); UPF / HRUPF / MCUPF (unscented.py, seed 002); the terrain-aided SIR with
fuzzy process noise (terrain.py, seed 003)."""
from .engine import BootstrapProposal, Proposal, SIRFilter, informative, measurement_residuals
from .proposals import CarriedCubatureProposal, CarriedGaussianProposal, OptimalCubatureProposal, UnscentedProposal
from .sir import CubatureParticleFilter, ParticleFilter
from .terrain import TerrainParticleFilter
from .unscented import UnscentedParticleFilter

__all__ = ["BootstrapProposal", "CarriedCubatureProposal", "CarriedGaussianProposal", "CubatureParticleFilter",
           "OptimalCubatureProposal", "ParticleFilter", "Proposal", "SIRFilter", "TerrainParticleFilter",
           "UnscentedParticleFilter", "UnscentedProposal", "informative", "measurement_residuals"]
