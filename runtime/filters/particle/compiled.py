"""The SIR engine's bootstrap step as one compiled call (``abyssal.runtime.compiled.sir``).

For the bootstrap proposal (``ParticleFilter``, or ``SIRFilter`` with ``BootstrapProposal``) the engine's steps
1-6 (engine.py) -- the transition draws, f (with the substeps the engine chose), the gate's statistics on the
cloud's predicted measurement, the exact (mixture) likelihood of the kept entries with the underflow rule,
log-weights, ESS, moments and systematic or stratified resampling -- are one C call over the step's double
buffers; Python keeps the contract's checks, the gate's counters and streaks (``InnovationGate.note``) and the
rare re-acquisition widening. What changes against the NumPy engine is the random stream only: the process
noise and the resampling uniforms come from the step's own counter-based generator (Philox4x32-10, keyed
once from the filter's ``rng`` at construction; its key and step counter are in ``streams`` and in
``checkpoint()``), not from the numpy Generator, which KLD-resampling and the schemes done in Python
(multinomial, residual) still use. Everything else is the engine's rule, computed in C:

* the gate: nu = sum_i w_i (z - h(x_i)) - E[v] and S = the prior-weighted spread of the residuals + R, tested
  entry-wise as ``InnovationGate.select`` does (the C's ``gate_select``), an entry left out of the likelihood
  is counted in ``gated`` and its streak goes through ``InnovationGate.note`` as before;
* a likelihood that underflows at every particle keeps the weights (``uninformative``);
* re-acquisition ("widen"): a step that may widen (an entry is on a gated streak) runs with the resampling left
  to Python, so the widening (``SIRFilter._widen``) moves the moved particles before they are resampled, as in
  the engine; the ancestors then come from the same Philox uniforms the C step would have used;
* KLD-resampling (and multinomial / residual): the C step does everything but the ancestors, which the policy
  draws from the filter's ``rng`` with ``kld_resample`` (vectorised in chunks); the active particle number
  changes inside the capacity the buffers were sized for. KLD in C (draws until Fox's bound over the occupied
  bins holds: a set of bins growing draw by draw) is not written yet.

A refused step (ValueError naming the cause) changes nothing: the C step writes only the uncommitted side of
its buffers, and ``commit`` is the last line of ``advance``.
"""
from __future__ import annotations

import math

import numpy as np

from ...compiled import sir
from ...compiled.batches import MeasureBatch
from ...resampling import ResamplingPolicy
from ...resampling.schemes import inverse_cdf

__all__ = ["CompiledBootstrap"]


def _philox_ancestors(step: sir.CompiledSIR, scheme: int, weights: np.ndarray) -> np.ndarray:
    """The ancestors the C step draws (systematic or stratified, from its resampling uniforms), in NumPy. (Where
    a uniform rounds up to 1.0, ~2^-53 per step, inverse_cdf takes the last particle of positive weight and the C
    step particle n - 1: the two differ only if that one has zero weight.)"""
    n = weights.shape[0]
    key, counter = int(step.rng[0]), int(step.rng[1])
    u = sir.uniforms(key, counter, sir.TAG_RESAMPLING, 1 if scheme == sir.SYSTEMATIC else n)
    return inverse_cdf(weights, (np.arange(n) + u) / n)


class CompiledBootstrap:
    """The compiled step bound to one SIRFilter's model, noises, parameters and policy (module docstring)."""

    @staticmethod
    def fits(engine) -> bool:
        """Whether the engine's step can be the compiled one: the bootstrap proposal, a model with
        structure-of-arrays kernels of f(x, u) and h(x), at most 64 states and outputs."""
        from .engine import BootstrapProposal

        model = engine.model
        if type(engine.proposal) is not BootstrapProposal or model.n_x > 64 or model.n_y > 64 or model.n_y < 1:
            return False
        f, h = model.function("f"), model.function("h")
        return f.soa_batched_inputs == ("x", "u") and h.soa_batched_inputs == ("x",)

    def __init__(self, engine, capacity: int):
        from .engine import MAX_STATE

        model = engine.model
        self.policy = policy = engine.policy
        self.step = step = sir.CompiledSIR(
            capacity, model.n_x, model.n_u, model.n_y, engine._p, f=model.function("f").soa_address,
            measure=(sir.address("abyssal_sir_soa_measure"), sir.SoaMeasure(h=model.function("h").soa_address)),
            process=sir.ProcessNoise.from_transition(engine.transition), measurement=engine.noise.mixture,
            angle_outputs=list(engine.angle_outputs), max_abs=MAX_STATE)
        gate = engine.gate
        step.thresholds[...] = gate.thresholds if gate.probability > 0.0 else math.inf
        #: the scheme the C step resamples with (CALLER: the policy draws the ancestors in Python)
        in_c = isinstance(policy, ResamplingPolicy) and policy.scheme in sir.SCHEMES
        self.scheme = sir.SCHEMES[policy.scheme] if in_c else sir.CALLER
        step.scheme = self.scheme
        self._threshold = policy.threshold
        self._measure = None  # h at the moved particles for a widening (built when first needed)

    def start(self, engine, x0: np.ndarray, P0: np.ndarray) -> None:
        """The first committed side: uniform weights over the N particles drawn, the moments (x0, P0); the
        generator's key, one draw from the filter's rng."""
        self.first_side(engine, x0, P0)
        self.step.rng[0] = sir.draw_key(engine.rng)

    def first_side(self, engine, x0: np.ndarray, P0: np.ndarray) -> None:
        """The first committed side: uniform weights over the N particles drawn, the moments (x0, P0)."""
        step, n = self.step, engine.N
        step.count = n
        step.log_w[0][:n], step.w[0][:n] = -math.log(n), 1.0 / n
        step.means[0][...], step.covs[0][...] = x0, P0
        self.point(engine, n, True)

    @property
    def streams(self) -> np.ndarray | None:
        """The step's generator state [Philox key, step counter]."""
        return self.step.rng

    # ---------------------------------------------------------------- views of the committed side
    def particles(self, n: int) -> np.ndarray:
        x = self.step.particles[self.step.cur]
        return x if n == x.shape[1] else x[:, :n]

    def proposed(self, n: int) -> np.ndarray:
        x = self.step.next_particles
        return x if n == x.shape[1] else x[:, :n]

    def point(self, engine, n_weights: int, uniform: bool) -> None:
        """The engine's reports as views of the committed side: log-weights (engine.N), the last step's weights
        (n_weights), its moments, the gate's prior weights (None when uniform)."""
        step, side = self.step, self.step.side
        engine.log_weights = step.log_w[side][:engine.N]
        engine.weights = step.w[side][:n_weights]
        engine._prior = None if uniform else engine.weights
        engine._x, engine._P = step.means[side], step.covs[side]

    def checkpoint(self) -> tuple:
        step = self.step
        return step.cur, step.side, step.weights_match, step.count, step.rng.copy()

    def restore(self, engine, saved: tuple, weights: np.ndarray, prior) -> None:
        """Put the sides back (the engine then restores its arrays into the views of those sides)."""
        step = self.step
        step.cur, step.side, step.weights_match, count, step.rng[...] = saved
        step.count = count
        self.point(engine, weights.shape[0], prior is None)

    # ---------------------------------------------------------------- the step
    def _refuse(self, engine, status: int, dt) -> ValueError:
        from .engine import MAX_STATE

        if status == 1:
            return ValueError(f"{engine.name}: a particle left the finite range |x| <= {MAX_STATE:g} (u, p or dt drive the "
                              f"model's integration beyond it: dt = {dt!r} s may be beyond the model's stable range); "
                              "state left unchanged")
        if status in (2, 3):
            return ValueError(f"{engine.name}: the step's importance weights are not finite ({self.step.message(status)}); "
                              "u, z or p drive the particles out of the finite range; state left unchanged")
        return ValueError(f"{engine.name}: the compiled step failed ({self.step.message(status)}); state left unchanged")

    def _residuals(self, engine, z: np.ndarray, present: np.ndarray, proposed: np.ndarray) -> np.ndarray:
        """z - h(x) at the moved particles (m, N), angle rows wrapped (for a widening)."""
        from .engine import measurement_residuals

        if self._measure is None:
            self._x_scratch = np.zeros((engine.model.n_x, self.step.n))
            self._measure = MeasureBatch(engine.model, self._x_scratch, engine._p)
        n = proposed.shape[1]
        self._x_scratch[:, :n] = proposed
        return measurement_residuals(z, self._measure(n), [i for i in engine.angle_outputs if present[i]])

    def advance(self, engine, u, dt, measurement) -> bool:
        """The engine's _advance for the bootstrap proposal (engine.py steps 1-7) with one compiled call."""
        step, gate, N = self.step, engine.gate, engine.N
        inputs = step.inputs
        if u is not None:
            inputs[sir.IN_MOVE] = sir.MOVE_TRANSITION
            step.u[...] = u
            inputs[sir.IN_DT] = dt
            inputs[sir.IN_PIECES] = 1 if dt <= engine._checked_dt else engine.pieces(u, dt)
        else:
            inputs[sir.IN_MOVE], inputs[sir.IN_DT], inputs[sir.IN_PIECES] = sir.MOVE_NONE, 0.0, 1
        gating = measurement is not None and gate.probability > 0.0
        if measurement is not None:
            z, present = measurement
            step.z[...] = z
            step.present[...] = present
            inputs[sir.IN_MEASURE] = 1.0
        else:
            inputs[sir.IN_MEASURE] = 0.0
        # the resampling threshold of this N; a step that may widen leaves the resampling to Python
        step.settings[sir.SET_RESAMPLE_BELOW] = math.inf if self._threshold >= 1.0 else self._threshold * N
        may_widen = gating and gate.inflation > 1.0 and (gate.streaking or gate.patience == 1)
        step.settings[sir.SET_SCHEME] = sir.CALLER if may_widen else self.scheme
        status = step()
        nxt = 1 - step.side
        x, P = step.means[nxt], step.covs[nxt]
        if status == sir.NONFINITE_MOMENTS:  # the contract's finite-out check, made by the C step
            engine._check_finite(x, P, u, dt, measurement)
        if status:
            raise self._refuse(engine, status, dt)
        ess, resampled, resample, uninformative = step.head(nxt)[:sir.R_UNINFORMATIVE + 1]
        weights = step.w[nxt][:N]
        proposed = self.proposed(N)
        kept = False
        if measurement is not None:
            gated = step.gated(nxt) != 0.0
            kept = bool((present & ~gated).any())
            if gating:  # the gate's counters and streaks; an underflowed update left its entries out too
                if uninformative:
                    gated = present
                if (gated.any() or gate.streaking) and gate.note(gated, present):
                    engine._widen(proposed, weights, x, self._residuals(engine, z, present, proposed)[gated])
        # resampling left to Python: the policy's ancestors (or the C step's own uniforms), gathered
        n_next = N
        if resample and not resampled:
            if isinstance(self.policy, ResamplingPolicy) and self.policy.scheme in sir.SCHEMES:
                ancestors = _philox_ancestors(step, sir.SCHEMES[self.policy.scheme], weights)
            else:
                ancestors = self.policy.ancestors(weights, engine.rng, proposed)
            n_next = ancestors.size
            step.particles[(step.cur + 2) % 3][:, :n_next] = proposed[:, ancestors]
            step.log_w[nxt][:n_next] = -math.log(n_next)
            resampled = 1.0
        # commit: nothing below can fail
        step.commit(resampled != 0.0)
        step.count = n_next
        engine.N = n_next
        self.point(engine, N, resampled != 0.0)
        engine.ess = ess
        engine.n_particles = float(N)
        engine.resamples += resampled != 0.0
        engine.uninformative += uninformative != 0.0
        if measurement is not None:
            engine._admit = None
        return kept
