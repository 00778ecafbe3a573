"""The SIR engine's step for the carried Gaussian proposals (CPF carried, UPF, HRUPF, MCUPF) in C.

For a ``CarriedGaussianProposal`` (proposals.py) with a Gaussian, zero-mean process noise, the engine's steps 1-6
(engine.py) are two C calls over the buffers of a compiled SIR step (``compiled.sir.CompiledSIR``, as the bootstrap
step's, compiled.py):

1. the proposal (``compiled.proposal.CompiledProposal``, runtime/c/abyssal_proposal.h): the transition means, every
   particle's Kalman predict and update (the runtime's algebra, as the batched steps compute it), the innovation gate
   on the cloud's predicted measurement with the update redone for the entries it keeps (from the kept
   predictions: a gated step no longer runs the predict again), each particle's draw from its proposal and its log
   importance ratio, written into the SIR step's proposals and log-ratio buffers;
2. the SIR step on those proposals (its ``MOVE_GIVEN``): the exact (mixture) likelihood of the kept entries with the
   underflow rule, log-weights with the ratios, ESS, the weighted moments (refused when not finite).

Then, in Python, the gate's counters and the re-acquisition (``InnovationGate.note``; an entry that stays gated is
admitted to the next updates), and resampling from the filter's Generator: systematic and multinomial ancestors and
KLD-resampling's by the C of compiled.resample from the Generator's own uniforms, other schemes by the policy; the
particles and the carried covariances gathered in C.

Random stream: the normals of the draws and the resampling uniforms are the filter's numpy Generator's, drawn as
the NumPy engine draws them (one (rank, N) block of standard normals per step or predict, then the policy's
uniforms), so a filter on this path is its NumPy twin's to rounding (tests/runtime/test_compiled_proposals.py).

A refused step changes nothing: the proposal and the SIR step write only the uncommitted sides of their buffers, and
the commit is the last line of ``advance``. An update alone (no u) reweights the particles where they are, the gate
on their own residuals (the proposal's screen); a predict moves them by the transition and carries each P^i to its
prediction.
"""
from __future__ import annotations

import math

import numpy as np

from ...compiled import proposal as cproposal
from ...compiled import sir
from ...compiled.kalman import KalmanRuntime
from ...compiled.resample import Ancestors, KLDSampler, gather_items, gather_rows
from ...resampling import KLDResampling, ResamplingPolicy
from .compiled import CompiledBootstrap

__all__ = ["CompiledCarried"]

_MODES = {"step": cproposal.STEP, "predict": cproposal.PREDICT, "update": cproposal.SCREEN}


class CompiledCarried(CompiledBootstrap):
    """The carried proposal's step in C over the buffers of a compiled SIR step (module docstring)."""

    @staticmethod
    def fits(engine) -> bool:
        """Whether the engine's step can be this one: a carried Gaussian proposal, a Gaussian zero-mean process noise,
        a model with a descriptor and structure-of-arrays kernels of f(x, u) and h(x), at most 64 states and outputs."""
        from .proposals import CarriedGaussianProposal

        model, transition = engine.model, engine.transition
        if not isinstance(engine.proposal, CarriedGaussianProposal) or model.n_x > 64 or not 1 <= model.n_y <= 64:
            return False
        if transition.mixture is not None or transition.mean.any():
            return False
        f, h = model.function("f"), model.function("h")
        if f.soa_batched_inputs != ("x", "u") or h.soa_batched_inputs != ("x",):
            return False
        return KalmanRuntime.of(model).descriptor is not None

    def __init__(self, engine, capacity: int):
        super().__init__(engine, capacity)
        step = self.step
        step.thresholds[...] = math.inf  # the gate is the proposal's: the SIR step weighs with the entries it kept
        step.scheme = self.scheme = sir.CALLER  # resampling from the filter's Generator (module docstring)
        kind, abk, sigma, gamma, guard = engine.proposal.algebra(engine)
        self.proposal = cproposal.CompiledProposal(engine.model, kind, capacity, step, engine._p, engine.transition,
                                                   engine.noise.covariance, engine.noise.mean, engine.gate, abk=abk,
                                                   sigma=sigma, gamma=gamma, guard_sigma=guard)
        policy = engine.policy
        self._ancestors = Ancestors(capacity)
        self._kld = (KLDSampler(capacity, policy.n_max, len(policy.coordinates)) if isinstance(policy, KLDResampling)
                     else None)

    def start(self, engine, x0: np.ndarray, P0: np.ndarray) -> None:
        """The first committed side (no generator key: every draw is the filter's Generator's)."""
        self.first_side(engine, x0, P0)

    @property
    def streams(self) -> None:
        """None: the draws are the filter's Generator's."""
        return None

    def checkpoint(self) -> dict:
        step = self.step
        return {"cur": step.cur, "side": step.side, "weights_match": step.weights_match, "count": step.count,
                "carried_side": self.proposal.side}

    def restore(self, engine, saved: dict, weights: np.ndarray, prior) -> None:
        """Put the sides back (the engine then restores its arrays into the views of those sides)."""
        step = self.step
        step.cur, step.side, step.weights_match = saved["cur"], saved["side"], saved["weights_match"]
        step.count = saved["count"]
        self.proposal.side = saved["carried_side"]
        self.point(engine, weights.shape[0], prior is None)

    # ---------------------------------------------------------------- resampling from the filter's Generator
    def _draw_ancestors(self, engine, weights: np.ndarray, proposed: np.ndarray) -> np.ndarray:
        """The policy's ancestors, from the same uniforms of the filter's Generator as policy.ancestors."""
        policy, rng = engine.policy, engine.rng
        if self._kld is not None:
            return self._kld.ancestors(weights, proposed, rng, policy)
        if isinstance(policy, ResamplingPolicy) and policy.scheme == "systematic":
            return self._ancestors.systematic(weights, rng.random())
        if isinstance(policy, ResamplingPolicy) and policy.scheme == "multinomial":
            return self._ancestors.multinomial(weights, rng.random(weights.shape[0]))
        return policy.ancestors(weights, rng, proposed)

    # ---------------------------------------------------------------- the step
    def advance(self, engine, u, dt, measurement) -> bool:
        """The engine's _advance for a carried proposal (engine.py steps 1-7): the proposal's call, the SIR step's."""
        step, prop, gate, N = self.step, self.proposal, engine.gate, engine.N
        mode = "update" if u is None else "predict" if measurement is None else "step"
        if u is not None:
            engine.proposal.check_dt(engine, u, dt)
            engine.rng.standard_normal(out=prop.normals(N))  # the draws' normals (the NumPy engine's, in its order)
        z, present = measurement if measurement is not None else (None, None)
        status = prop.run(_MODES[mode], N, step.cur, step.side, engine._prior is not None, 0.0 if dt is None else dt,
                          u, z, present, engine._admit)
        if status == cproposal.NONFINITE_PREDICTION:
            raise ValueError(f"{engine.name}: a particle's predicted covariance left the finite range (u, p or dt); "
                             "state left unchanged")
        if status:
            raise ValueError(f"{engine.name}: the compiled proposal refused its arguments (status {status}); state left "
                             "unchanged")
        kept = prop.kept if measurement is not None else None
        used = kept is not None and bool(kept.any())
        inputs = step.inputs
        inputs[sir.IN_MOVE] = sir.MOVE_NONE if mode == "update" else sir.MOVE_GIVEN
        inputs[sir.IN_DT], inputs[sir.IN_PIECES] = 0.0, 1
        inputs[sir.IN_MEASURE] = 1.0 if used else 0.0
        if used:
            step.z[...] = z
            step.present[...] = kept
        step.settings[sir.SET_RATIO] = 1.0 if used and mode == "step" else 0.0
        step.settings[sir.SET_RESAMPLE_BELOW] = math.inf if self._threshold >= 1.0 else self._threshold * N
        status = step()
        nxt = 1 - step.side
        x, P = step.means[nxt], step.covs[nxt]
        if status == sir.NONFINITE_MOMENTS:
            engine._check_finite(x, P, u, dt, measurement)
        if status:
            raise self._refuse(engine, status, dt)
        ess, _, resample, uninformative = step.head(nxt)[:sir.R_UNINFORMATIVE + 1]
        weights = step.w[nxt][:N]
        proposed = self.proposed(N)  # (an update alone's: the particles, copied there by the SIR step)
        admit = None
        if measurement is not None and gate.probability > 0.0:  # the gate's counters, and the re-acquisition
            gated = present if uninformative else prop.gated
            if (gated.any() or gate.streaking) and gate.note(gated, present):
                admit = gated
        # resampling from the filter's Generator
        ancestors, n_next = None, N
        if resample:
            ancestors = self._draw_ancestors(engine, weights, proposed)
            n_next = ancestors.shape[0]
            gather_rows(step.particles[(step.cur + 2) % 3], proposed, ancestors)
            step.log_w[nxt][:n_next] = -math.log(n_next)
        # commit: nothing below can fail
        size = prop.n_x * prop.n_x
        if mode == "update":  # the particles did not move: their P^i stay (and follow the ancestors)
            if ancestors is not None:
                gather_items(prop.carried[1 - prop.side], prop.carried[prop.side], ancestors, size)
                prop.commit()
        elif ancestors is not None:
            gather_items(prop.carried[prop.side], prop.carried[1 - prop.side], ancestors, size)
        else:
            prop.commit()
        if mode == "step":
            engine.proposal.failed_slices += prop.failed
        step.commit(ancestors is not None)
        step.count = n_next
        engine.N = n_next
        self.point(engine, N, ancestors is not None)
        engine.ess = ess
        engine.n_particles = float(N)
        engine.resamples += ancestors is not None
        engine.uninformative += uninformative != 0.0
        if measurement is not None:
            engine._admit = admit
        return used
