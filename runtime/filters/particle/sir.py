"""The particle filters of seed 000 on the SIR engine (engine.py): PF and CPF. The Gaussian-sum
filters (MOGCPF, EM-MOGCPF, GS-CKF) are in filters/mixture; the CKF is filters/kalman's.

Every filter is built from a ``ModelBundle`` (``abyssal.generated.load``), an initial mean and
covariance, a process noise and a measurement noise given as ``GaussianMixture`` objects (one
component for Gaussian noise; the process noise may also be a covariance matrix, singular
allowed), a particle count and an ``rng`` (int seed or ``numpy.random.Generator``). They keep
the one filter contract (runtime/contract.py): ``step(u, dt, z=None, p=None)``, ``x``, ``P``,
``run``, ``ess`` per step. Particles are
(n, N) arrays; all per-particle model and filter evaluations are calls of generated C over the
whole batch (``bind_soa`` for f and h, ``bind_batch`` for ``ckf_predict`` / ``ckf_update``),
never Python loops over particles. Loops over mixture components (a handful) are allowed.

Noise conventions: the process noise is additive on the discrete state, x_{k+1} = f(x_k, u_k)
+ w_k with w_k ~ process_noise (already scaled to one step by the caller); measurement residuals
z - h(x) of angle outputs are wrapped to (-pi, pi]. Likelihoods are Gaussian or Gaussian
mixtures, evaluated in the log domain and normalised by log-sum-exp.

Decisions where seed 000 is ambiguous:

* PF: bootstrap SIR, proposal p(x_k | x_{k-1}), weights the exact (mixture) likelihood.
* Cubature steps inside CPF / MOGCPF / EM-MOGCPF / CKF use the moment-matched (single
  Gaussian) covariance of a mixture noise; the particle weights then use the exact mixture.
* CPF (eqs. 30-33) has two proposals (``proposal="carried"`` or ``"optimal"``, proposals.py):
  carried -- each particle carries its own covariance P^i, as in van der Merwe's unscented PF;
  the CKF predict+update of (x^i_{k-1}, P^i_{k-1}) gives the proposal N(x^i_{k|k}, P^i_{k|k})
  (eq. 30), the particle is drawn from it (eq. 31) and weighted by p(z|x) p(x|x_{k-1}) / q
  (eq. 32); P^i_{k|k} is kept (and copied on resampling). optimal -- the same cubature step
  from P^i = 0 each step (predicted covariance Q_k), the locally optimal proposal. The default
  is "carried" (the paper as printed). The estimate is the weighted mean before resampling
  (eq. 33 after resampling is the same in expectation with more Monte-Carlo noise).
* MOGCPF (eqs. 34-40) is implemented as a Gaussian-sum particle filter (Kotecha & Djuric, the
  paper's ref. 22): G posterior components x K process-noise components give G' predicted
  components (eqs. 35-39, the process-noise mean is added to the cubature mean), each updated
  with every one of the M measurement-noise components gives G'' = G' M components (eq. 40)
  weighted by w_i' gamma_m N(z - mu_m; z_hat, S). N/G'' particles are drawn from each, weighted
  by gamma_m p_m(z|x) N(x; predicted_i') / N(x; updated_j); a component's weight is multiplied
  by its mean particle weight and its moments become the weighted particle moments (the
  cubature moments when its effective sample size is below 2n). The reduction G'' -> G keeps
  the G - 1 heaviest components and merges the rest by moment matching (``reduce_mixture``).
* EM-MOGCPF (eqs. 41-45): the same G'' cubature posterior is the importance density q for N
  particles (allocated to components by systematic resampling of the weights), weighted by
  p(z|x) p_G'(x) / q(x) with the exact mixture likelihood and the predicted G'-mixture; weighted
  EM (``mixtures.weighted_em``) refits G components, warm-started from the moment-matched
  children of each predicted component. Estimate and covariance are eq. 45. No resampling is
  needed: the EM refit replaces it, as the paper says.
* Initial mixtures (G > 1): component means drawn from N(x0, P0/2) with covariances P0/2, so
  the mixture's covariance is about P0 and the components are not identical (identical
  components would never separate under EM or Gaussian-sum updates).
* Extra baseline ``GaussianSumCKF``: the Gaussian-sum CKF with the exact mixture measurement
  noise (MOGCPF without particles), reduced to G components by ``reduce_mixture``.
* Outlier gate (not in the paper): the engine's innovation gate on the cloud's predicted
  measurement (engine.py; ``gate_probability`` 1e-10, ``gate_patience``, ``gate_inflation``, as the
  Kalman filters') leaves an entry far outside the cloud out of the proposal and the weights, and
  widens the cloud when an entry stays gated (a jump). When the likelihood underflows at every
  particle (below the smallest normal double) the measurement is treated as carrying no
  information for the weights (``informative``): the log domain would otherwise hand all the
  weight to whichever particle lies nearest the outlier.
* A cubature step whose Cholesky guard fails (ok = 0) is rerun after repairing the offending
  input covariances (``numerics.repair_covariance``).
"""
from __future__ import annotations

from ...contract import register
from ...resampling import ResamplingPolicy
from .engine import BootstrapProposal, SIRFilter, informative, measurement_residuals
from .proposals import CarriedCubatureProposal, OptimalCubatureProposal

__all__ = ["CubatureParticleFilter", "ParticleFilter", "informative", "measurement_residuals"]


@register("particle")
class ParticleFilter(SIRFilter):
    """Bootstrap SIR particle filter (PF): proposal p(x_k|x_{k-1}), weights p(z|x) in the log domain."""

    name = "PF"

    def __init__(self, model, x0, P0, process_noise, measurement_noise, n_particles, rng, *,
                 policy: ResamplingPolicy = ResamplingPolicy(), gate_probability: float = 1e-10,
                 gate_patience: int = 5, gate_inflation: float = 4.0, underflow: str = "keep", estimate: str = "before"):
        super().__init__(model, x0, P0, process_noise, measurement_noise, n_particles, rng,
                         proposal=BootstrapProposal(), policy=policy, gate_probability=gate_probability,
                         gate_patience=gate_patience, gate_inflation=gate_inflation, underflow=underflow,
                         estimate=estimate)


CPF_PROPOSALS = {"carried": CarriedCubatureProposal, "optimal": OptimalCubatureProposal}


@register("particle")
class CubatureParticleFilter(SIRFilter):
    """CPF (eqs. 30-33): per-particle cubature proposal, weights p(z|x) p(x|x_prev) / q.

    proposal: "carried" (P^i carried between steps, van der Merwe's UPF form, the default) or
    "optimal" (P^i = 0 at each step: the locally optimal proposal); see proposals.py.
    """

    name = "CPF"

    def __init__(self, model, x0, P0, process_noise, measurement_noise, n_particles, rng, *,
                 proposal: str = "carried", policy: ResamplingPolicy = ResamplingPolicy(),
                 gate_probability: float = 1e-10, gate_patience: int = 5, gate_inflation: float = 4.0):
        if proposal not in CPF_PROPOSALS:
            raise ValueError(f"proposal must be one of {sorted(CPF_PROPOSALS)}, got {proposal!r}")
        super().__init__(model, x0, P0, process_noise, measurement_noise, n_particles, rng,
                         proposal=CPF_PROPOSALS[proposal](), policy=policy, gate_probability=gate_probability,
                         gate_patience=gate_patience, gate_inflation=gate_inflation)
