"""Unscented particle filters of seed 002: UPF, HRUPF and MCUPF (with KLD-resampling).

    upf = UnscentedParticleFilter(cn, x0, P0, Q, R, 5000, rng)                       # UPF, eqs. 7-24
    hrupf = UnscentedParticleFilter(cn, x0, P0, Q, R, 5000, rng, update="huber")     # HRUPF
    mcupf = UnscentedParticleFilter(cn, x0, P0, Q, R, 5000, rng, update="mcc",
                                    resampling=KLDResampling(n_max=2000))           # MCUPF, Table 3

The SIR engine (engine.py) with the unscented proposal (proposals.py, ``UnscentedProposal``):
every particle j carries its own Gaussian (x^j, P^j) (van der Merwe's UPF, the paper's eqs. 5-6
and 7-19). One step, all per-particle work in the C runtime over all particles in one call each
(compiled.kalman.BatchStep, the algebra of the Kalman filters, on the model's generated h and f):

1. ``ukf_predict`` on (x^j_{k-1}, P^j_{k-1}) with Q (eqs. 7-10);
2. ``ukf_update`` (UPF), ``huber_ukf_update`` (HRUPF: Huber gamma, 3 IRLS
   iterations) or ``mcukf_update`` (MCUPF: R~ = R / C_k with the
   correntropy kernel of bandwidth sigma, eqs. 36-39) with the range and the leader position p;
3. a draw x^j_k ~ N(x^j_{k|k}, P^j_{k|k}) (eq. 19), weights by eq. 20 -- the Gaussian
   likelihood p(z | x) with the filter's R, the transition density N(x; f(x^j_{k-1}), Q) and the
   proposal density -- normalised in the log domain (eq. 21);
4. resampling every step: multinomial ("simple random", the paper's PF/UPF), or KLD-resampling
   (runtime/resampling/kld.py, a resampling policy) which also sets the next particle number;
   P^j follows its particle.

Decisions:

* Sigma points: the scaled unscented rule with alpha = 1, beta = 0, kappa = 3 - n, i.e. the
  paper's lambda = 3 - n. For n = 2 that is lambda = 1: 2n + 1 = 5 points at +-sqrt(3) standard
  deviations, weights 1/3 (centre) and 1/6 -- all positive, so P stays positive definite, and the
  points match the Gaussian's fourth moment along each axis. (cn2d's f is linear in x, so the
  predict is exact for any lambda; lambda only matters in the range update.)
* The MCC kernel weight C_k underflows for large whitened innovations (sigma = 15, R = 0.1: a 30 m
  innovation gives ~2e-9, 60 m gives 1e-35). It is floored in the update
  (runtime/c/abyssal_kalman_steps.c: the kernel exponent is capped at ABYSSAL_MCC_MAX_EXPONENT = 50, so
  C_k >= e^-50 ~ 2e-22 and R/C_k stays finite); the capped update then ignores the range.
* Estimates: x and P are the weighted mean and covariance before resampling (eqs. 23-24 after
  resampling have the same expectation and more noise).
* Q may be singular (the particles then move only on its subspace, with the importance ratio exact
  there, as every SIR filter of the engine); R must be positive definite. A singular P0 starts the
  carried covariances at its nearest factorable matrix.
* The engine's innovation gate and underflow rule apply (engine.py): a range far outside the cloud's
  predicted range is left out of the proposal and the weights; the robust updates' S is Pzz + R~,
  so the gate sees their own down-weighting. A likelihood that underflows at every particle leaves
  the weights as they were (``uninformative``); ``underflow="normalise"`` and ``estimate="after"`` give the
  paper's rules instead (eq. 21 normalised whatever the likelihoods; the estimate of eqs. 23-24 from the
  resampled particles), engine.py.
* ``update(z)`` alone (the contract's) reweights the particles where they are by p(z | x) and
  resamples: the unscented proposal needs the step's input, so ``step`` is where it acts.
* Particle number: ``n_particles`` is the number before the step's resampling; with
  KLD-resampling it starts at ``n_particles`` (N_start = 5000) and is set by every resampling
  after that (at most ``resampling.n_max``: 2000 in Table 6).
"""
from __future__ import annotations

import numpy as np

from ...contract import check_covariance, register
from ...noise.mixtures import GaussianMixture
from ...resampling import KLDResampling, ResamplingPolicy
from .engine import SIRFilter, check_model
from .proposals import UnscentedProposal

__all__ = ["UnscentedParticleFilter"]

#: resampling of the paper's PF and UPF: "simple random" (multinomial) every step
EVERY_STEP = ResamplingPolicy("multinomial", 1.0)


@register("particle")
class UnscentedParticleFilter(SIRFilter):
    """UPF / HRUPF / MCUPF: the SIR engine with the unscented proposal (see the module docstring).

    Q (n_x, n_x) and R (n_y, n_y) are covariance matrices; ``resampling`` None (multinomial every
    step) or a resampling policy (``KLDResampling`` for the MCUPF)."""

    @classmethod
    def contract_example(cls, model, *, x0=None, P0=None, n_particles=None, rng=0):
        """For the contract test: an MCUPF (MCC update + KLD-resampling, the most moving parts)."""
        n, m = model.n_x, model.n_y
        return cls(model, np.zeros(n) if x0 is None else x0, np.eye(n) if P0 is None else P0, 0.05 * np.eye(n),
                   0.5 * np.eye(m), 40 if n_particles is None else n_particles, rng, update="mcc",
                   resampling=KLDResampling(bin_size=(0.5, 0.5), n_min=10, n_max=60))

    def __init__(self, model, x0, P0, Q, R, n_particles, rng, *, update: str = "ukf", sigma: float = 15.0,
                 gamma: float = 1.345, resampling: KLDResampling | ResamplingPolicy | None = None,
                 name: str | None = None, gate_probability: float = 1e-10, gate_patience: int = 5,
                 gate_inflation: float = 4.0, underflow: str = "keep", estimate: str = "before"):
        check_model(model, type(self).__name__)
        proposal = UnscentedProposal(update, sigma=sigma, gamma=gamma)
        R = check_covariance(R, model.n_y, "R", definite=True)
        super().__init__(model, x0, P0, Q, GaussianMixture.gaussian(np.zeros(model.n_y), R), n_particles, rng,
                         proposal=proposal, policy=EVERY_STEP if resampling is None else resampling,
                         gate_probability=gate_probability, gate_patience=gate_patience, gate_inflation=gate_inflation,
                         process_noise_name="Q", underflow=underflow, estimate=estimate)
        self.update_kind = update
        self.name = name or {"ukf": "UPF", "huber": "HRUPF", "mcc": "MCUPF"}[update]

    @property
    def carried(self) -> np.ndarray:
        """The covariances the N particles carry (n, n, N): a view of the buffer."""
        return self.proposal.carried
