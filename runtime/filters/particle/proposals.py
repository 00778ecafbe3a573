"""Proposals for the SIR engine (engine.py) that use the measurement: the CPF of seed 000 in its two
forms and the UPF family of seed 002.

* ``CarriedGaussianProposal`` -- van der Merwe's unscented-PF form, shared by the two below: every
  particle i carries its own covariance P^i; a generated sigma-point predict + update of
  (x^i_{k-1}, P^i_{k-1}) over all particles gives N(m^i, P^i_{k|k}); the particle is drawn from it
  and P^i_{k|k} is kept, following its particle through resampling (``commit``). A particle whose
  update fails its guards even on a repaired covariance proposes from its prediction
  (``failed_slices``).
  * ``CarriedCubatureProposal`` -- the CPF of seed 000 (eqs. 30-33 as printed): the C runtime's CKF
    predict + update per particle (fused into one call when nothing is added between them). P^i converges to
    the CKF posterior, which is much wider than the one-step process noise, so the importance
    ratio p(x|x_prev)/q is often degenerate (ESS near 1): see tests/runtime/test_particle_filters.py.
  * ``UnscentedProposal(update="ukf" | "huber" | "mcc")`` -- the UPF / HRUPF / MCUPF of seed 002
    (eqs. 7-19, 36-39): the C runtime's ``ukf_predict`` with the scaled unscented rule alpha = 1,
    beta = 0, kappa = 3 - n (the paper's lambda = 3 - n) and the update ``ukf_update``,
    ``huber_ukf_update`` (Huber gamma, 3 IRLS iterations) or ``mcukf_update``
    (R~ = R / C_k, the correntropy kernel of bandwidth sigma; its exponent is capped at 50 in
    runtime/c/abyssal_kalman_steps.c, so C_k >= e^-50 and R~ stays finite).
* ``OptimalCubatureProposal`` -- the locally optimal form: each particle's cubature step starts
  from P^i = 0, so its predicted density is N(f(x^i_{k-1}), Q_k) and the cubature update with z
  approximates p(x_k | x^i_{k-1}, z) (exact for a linear measurement, where the weight becomes
  the predictive likelihood p(z | x^i_{k-1})). Nothing is carried between steps. Computed in
  NumPy from h at the 2r cubature points of N(f(x^i), Q) (one SIMD call of h over N (2r + 1)
  points), where r is the rank of Q.

Each of them hands its per-particle predicted measurement and covariance to the engine's
innovation gate (``engine.screen``) before z enters the proposal, and uses only the entries it
keeps; with every entry gated the particles move by the transition and carried covariances become
their prediction. With the gate off (``gate_probability=0``) the cubature proposals keep their own
guard: an entry more than 100 standard deviations of a particle's S from its prediction is left
out of that proposal (the weights keep it), so an outlier far beyond every particle does not throw
the particles to it.

Singular Q (all): the transition lives on the subspace V (n x r) of Q's positive eigenvalues
(``TransitionNoise``). Particles are drawn there, x = f + V y with y from the proposal's
marginal on the subspace, and the ratio log N(y; 0, Lambda) - log q(y) is exact on it (both
densities are with respect to the same r-dimensional Lebesgue measure). No floor is added.

The proposals use the moment-matched (single Gaussian) covariances of mixture noises; the
engine's weights use the exact mixture likelihood.
"""
from __future__ import annotations

import numpy as np


from ...compiled.batches import (CubaturePredictBatch, CubatureStepBatch, CubatureUpdateBatch, MeasureBatch,
                                 UnscentedPredictBatch, UnscentedUpdateBatch)
from ...noise.mixtures import LOG_2PI
from ...numerics import factorable_covariance, stacked_cholesky, stacked_times, wrap_to_pi
from .engine import Proposal

__all__ = ["CarriedCubatureProposal", "CarriedGaussianProposal", "OptimalCubatureProposal", "UnscentedProposal"]


def _gaussian_draw(engine, f: np.ndarray, mean: np.ndarray, C: np.ndarray) -> np.ndarray:
    """engine.proposed = f + V y, y ~ N(V^T (mean - f), V^T C V) per particle; returns the log ratio.

    mean (n, N), C (N, n, n) per particle; log ratio = log p_w(V y) - log q(y) on the subspace.
    """
    tr = engine.transition
    N, r = engine.N, tr.rank
    xi = engine.rng.standard_normal((r, N))
    if tr.full:
        mean_y, C_y = mean - f, C
    elif tr.support is not None:
        idx = tr.support
        mean_y, C_y = (mean - f)[idx], C[:, idx][:, :, idx]
    else:
        V = tr.basis
        mean_y = V.T @ (mean - f)
        C_y = V.T @ C @ V
    L, log_det = stacked_cholesky(C_y, repair=True)
    y = mean_y + stacked_times(L, xi)
    np.add(f, tr.embed(y), out=engine.proposed)
    log_q = -0.5 * np.einsum("rn,rn->n", xi, xi) - log_det - 0.5 * r * LOG_2PI
    return tr.log_density(engine.proposed - f) - log_q


class CarriedGaussianProposal(Proposal):
    """A generated sigma-point predict + update of (x^i, P^i) per particle, P^i carried (module docstring).

    A subclass builds the two batches over engine.capacity slices (``_batches``) and may fuse them
    (``_evaluate``)."""

    _state = ("carried", "failed_slices")
    #: an entry gated gate_patience times in a row is used by the next update: each particle's own sigma-point
    #: update then moves it towards z, as an ungated Kalman filter would (engine.py)
    reacquire = "admit"

    def _batches(self, engine):
        """(predict batch, update batch chained to its outputs), sized to engine.capacity."""
        raise NotImplementedError

    def bind(self, engine) -> None:
        self._engine = engine
        self._pb, self._ub = self._batches(engine)
        self._r_mean, self._q_mean = engine.noise.mean, engine.transition.mean
        # P^i_0 = P0, or its nearest factorable when P0 is singular (a sigma-point step needs a factor)
        P0 = engine.P
        start = P0 if np.linalg.eigvalsh(P0)[0] > 0 else factorable_covariance(P0, engine.transition.covariance)
        self._pb.cov[:, :, :engine.N] = start[:, :, None]
        self._next_cov = None  # P^i of the step under way, committed by commit()
        self._next_failed = 0
        #: particles whose update failed its guards on a repaired covariance (they proposed from their prediction)
        self.failed_slices = 0

    @property
    def carried(self) -> np.ndarray:
        """P^i of the N particles (n, n, N): a view of the generated predict's input buffer."""
        return self._pb.cov[:, :, :self._engine.N]

    def _check_dt(self, engine, u, dt) -> None:
        pieces = 1 if dt <= engine._checked_dt else engine.pieces(u, dt)
        if pieces > 1:
            raise ValueError(f"{engine.name} ({self.name}): dt = {dt!r} s is beyond the model's stable range (f needs "
                             f"{pieces} substeps there) and the generated sigma-point step cannot be "
                             "subdivided; use a smaller dt")

    def _inputs(self, engine, u, dt) -> None:
        self._pb.mean[:, :engine.N] = engine.particles
        self._pb.u[...] = u
        self._pb.dt[0] = dt

    def _predict(self, count: int) -> None:
        self._pb(count)
        if self._q_mean.any():
            self._pb.mean_pred[:, :count] += self._q_mean[:, None]

    def _evaluate(self, count: int) -> bool:
        """Predict then update the first `count` slices; whether the predict batch's outputs are current (a fused
        step leaves them stale)."""
        self._predict(count)
        self._ub(count)
        return True

    def _update_again(self, count: int, predicted: bool) -> bool:
        """The update again, with the update batch's present entries changed (the gate's): whether the predict batch's
        outputs are current."""
        self._ub(count)
        return predicted

    def predict(self, engine, u, dt) -> None:
        self._next_failed = 0
        self._check_dt(engine, u, dt)
        engine.transition_draw(u, dt)
        self._inputs(engine, u, dt)
        self._predict(engine.N)
        if not np.isfinite(self._pb.cov_pred[:, :, :engine.N]).all():
            raise ValueError(f"{engine.name}: a particle's predicted covariance left the finite range (u, p or dt); "
                             "state left unchanged")
        self._next_cov = self._pb.cov_pred

    def move(self, engine, u, dt, z, present):
        N, pb, ub = engine.N, self._pb, self._ub
        self._next_failed = 0
        self._check_dt(engine, u, dt)
        f = engine.propagate(u, dt)  # transition means f(x^i_{k-1}) + E[w]
        self._inputs(engine, u, dt)
        ub.present[:] = present
        ub.set_measurement(np.where(present, z - self._r_mean, 0.0))
        predicted = self._evaluate(N)
        kept = engine.screen(ub.innovation[:, :N], present, S=ub.S[:, :, :N])
        if kept is None:  # every entry gated: the transition, and P^i its prediction
            if not predicted:
                self._predict(N)
            engine.add_transition_noise(f)
            self._next_cov = pb.cov_pred
            return None
        if not np.array_equal(kept, present):
            ub.present[:] = kept
            predicted = self._update_again(N, predicted)
        mean, cov = ub.mean_post[:, :N], ub.cov_post[:, :, :N]
        ok = ub.ok[0, :N] > 0
        if not ok.all():  # proposes from its prediction
            if not predicted:
                self._predict(N)
            mean = np.where(ok, mean, pb.mean_pred[:, :N])
            cov = np.where(ok, cov, pb.cov_pred[:, :, :N])
            self._next_failed = int((~ok).sum())
        self._next_cov = cov
        return _gaussian_draw(engine, f, mean, np.moveaxis(cov, -1, 0))

    def commit(self, ancestors, mode, count) -> None:
        cov = self._pb.cov
        if mode == "update":  # the particles did not move: their P^i stay
            if ancestors is not None:
                cov[:, :, :ancestors.size] = cov[:, :, ancestors]
        elif ancestors is not None:  # (np.take with out: 2-5x faster than fancy indexing on the last axis)
            np.take(self._next_cov, ancestors, axis=2, out=cov[:, :, :ancestors.size], mode="clip")
        else:
            cov[:, :, :count] = self._next_cov[:, :, :count]
        self.failed_slices += self._next_failed
        self._next_cov, self._next_failed = None, 0


class CarriedCubatureProposal(CarriedGaussianProposal):
    """The CKF predict + update of (x^i, P^i) per particle, P^i carried (the CPF of seed 000)."""

    name = "cubature, carried P^i"

    def _batches(self, engine):
        model, cap = engine.model, engine.capacity
        pb = CubaturePredictBatch(model, cap, engine.p)
        # the engine's gate on the cloud, or (gate off) the batch's own per-particle outlier guard, proposal only
        ub = CubatureUpdateBatch(model, cap, engine.p, pb.mean_pred, pb.cov_pred,
                                 gate_sigma=np.inf if engine.gate.probability > 0.0 else 100.0)
        pb.Q[...] = engine.transition.covariance[:, :, None]
        ub.R[...] = engine.noise.covariance[:, :, None]
        self._fused = None if engine.transition.mean.any() else CubatureStepBatch(model, pb, ub)
        return pb, ub

    def _evaluate(self, count: int) -> bool:
        if self._fused is None:
            return super()._evaluate(count)
        return not self._fused(count)  # the fused results stand (predict outputs stale), or the two-stage path ran

    def _update_again(self, count: int, predicted: bool) -> bool:
        if self._fused is None or predicted:
            return super()._update_again(count, predicted)
        return not self._fused(count)  # one fused call (it honours the present entries) rather than predict + update


#: update kind -> (generated function, its extra argument)
UNSCENTED_UPDATES = {"ukf": ("ukf_update", None), "huber": ("huber_ukf_update", "gamma"), "mcc": ("mcukf_update", "sigma")}


class UnscentedProposal(CarriedGaussianProposal):
    """The UKF predict + update (ukf | huber | mcc) of (x^i, P^i) per particle, P^i carried (UPF / HRUPF / MCUPF)."""

    def __init__(self, update: str = "ukf", *, sigma: float = 15.0, gamma: float = 1.345):
        if update not in UNSCENTED_UPDATES:
            raise ValueError(f"update must be one of {sorted(UNSCENTED_UPDATES)}, got {update!r}")
        for label, value in (("sigma", sigma), ("gamma", gamma)):
            if not (isinstance(value, (int, float, np.integer, np.floating)) and value > 0):
                raise ValueError(f"{label} must be a positive number, got {value!r}")
        self.update, self.sigma, self.gamma = update, float(sigma), float(gamma)
        self.name = {"ukf": "unscented", "huber": "unscented, Huber update", "mcc": "unscented, MCC update"}[update]

    def _batches(self, engine):
        model, cap = engine.model, engine.capacity
        function, extra = UNSCENTED_UPDATES[self.update]
        #: the scaled unscented rule (alpha, beta, kappa) = (1, 0, 3 - n): the paper's lambda = 3 - n
        self.abk = np.array([1.0, 0.0, 3.0 - model.n_x])
        extra = [np.array([self.sigma if extra == "sigma" else self.gamma])] if extra else []
        pb = UnscentedPredictBatch(model, cap, engine.p, engine.transition.covariance, self.abk)
        ub = UnscentedUpdateBatch(model, function, cap, engine.p, pb.mean_pred, pb.cov_pred, engine.noise.covariance,
                                  self.abk, extra)
        return pb, ub


class OptimalCubatureProposal(Proposal):
    """Cubature approximation of p(x_k | x^i_{k-1}, z) from P^i = 0 (see the module docstring)."""

    name = "cubature, locally optimal"
    #: an entry gated gate_patience times in a row is used by the next update: the proposal moves every particle
    #: towards z (engine.py)
    reacquire = "admit"
    #: with the engine's gate off: a measurement entry more than this many standard deviations of S from its
    #: prediction (at any particle) is left out of the proposal, as in ``CubatureUpdateBatch``; the weights keep it
    gate_sigma = 100.0

    def bind(self, engine) -> None:
        model, tr, cap = engine.model, engine.transition, engine.capacity
        r = tr.rank
        self._r = r
        # cubature points of N(0, Q) in subspace coordinates: +-sqrt(r) sqrt(lambda_j) e_j
        self._dy = np.sqrt(r) * np.concatenate([np.diag(np.sqrt(tr.variances)), -np.diag(np.sqrt(tr.variances))], axis=1)
        self._dx = tr.embed(self._dy)  # (n, 2r)
        self._dy_scale = np.sqrt(r) * np.sqrt(tr.variances)  # (r,)
        self._points = np.zeros((model.n_x, cap * (2 * r + 1)))  # column i (2r+1) + j: point j of particle i
        self._h = MeasureBatch(model, self._points, engine.p)
        self._R, self._r_mean = engine.noise.covariance, engine.noise.mean
        self._angles = engine.angle_outputs

    def move(self, engine, u, dt, z, present):
        N, r, n = engine.N, self._r, engine.model.n_x
        f = engine.propagate(u, dt)
        if r == 0:  # no process noise: the particles move deterministically, the ratio is 1
            engine.proposed[...] = f
            return np.zeros(N)
        points = self._points[:, :N * (2 * r + 1)].reshape(n, N, 2 * r + 1)  # a view (each row is contiguous)
        points[:, :, 0] = f
        np.add(f[:, :, None], self._dx[:, None, :], out=points[:, :, 1:])
        Y = self._h(N * (2 * r + 1)).reshape(-1, N, 2 * r + 1)
        with np.errstate(over="ignore", invalid="ignore"):  # h beyond the finite range: refused by the engine
            return self._draw(engine, u, dt, z, present, f, Y)

    def _draw(self, engine, u, dt, z, present, f, Y):
        N, r = engine.N, self._r
        centre = Y[:, :, 0]
        spread = Y[:, :, 1:] - centre[:, :, None]  # (m, N, 2r)
        for i in self._angles:
            spread[i] = wrap_to_pi(spread[i])
        offset = spread.mean(axis=2)
        z_hat = centre + offset
        dZ = spread - offset[:, :, None]
        weight = 1.0 / (2 * r)
        dZt = dZ.transpose(1, 0, 2)  # (N, m, 2r)
        S = dZt @ dZt.transpose(0, 2, 1)
        S *= weight
        S += self._R
        innovation = (z - self._r_mean)[:, None] - z_hat
        for i in self._angles:
            innovation[i] = wrap_to_pi(innovation[i])
        if engine.gate.probability > 0.0:
            kept = engine.screen(innovation, present, S=np.moveaxis(S, 0, -1))
        else:  # the proposal's own outlier guard (the weights keep every entry)
            kept = present & ~np.any(np.abs(innovation) > self.gate_sigma * np.sqrt(np.einsum("naa->an", S)), axis=1)
            kept = kept if kept.any() else None
        if kept is None:  # every entry left out: the transition
            engine.add_transition_noise(f)
            return None
        rows = np.flatnonzero(kept)
        if rows.size < S.shape[1]:
            S, dZ, innovation = S[:, rows][:, :, rows], dZ[rows], innovation[rows]
        # P_yz: the subspace offsets are +-sqrt(r) sqrt(lambda_k) e_k, so only the pair k, k + r contributes
        Pyz = (dZ[:, :, :r] - dZ[:, :, r:]).transpose(1, 2, 0) * (weight * self._dy_scale)[None, :, None]  # (N, r, m)
        KT = np.linalg.solve(S, np.swapaxes(Pyz, 1, 2))  # (N, m, r) = (S^-1 Pzy)
        mean_y = np.einsum("nar,an->rn", KT, innovation)
        C_y = np.diag(engine.transition.variances)[None] - Pyz @ KT  # Lambda - K S K^T
        C_y = 0.5 * (C_y + np.swapaxes(C_y, 1, 2))
        L, log_det = stacked_cholesky(C_y, repair=True)
        xi = engine.rng.standard_normal((r, N))
        y = mean_y + stacked_times(L, xi)
        tr = engine.transition
        np.add(f, tr.embed(y), out=engine.proposed)
        log_q = -0.5 * np.einsum("rn,rn->n", xi, xi) - log_det - 0.5 * r * LOG_2PI
        return tr.log_density(engine.proposed - f) - log_q
