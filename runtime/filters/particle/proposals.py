"""Cubature proposals for the SIR engine (engine.py): the CPF of seed 000 in its two forms.

* ``CarriedCubatureProposal`` -- van der Merwe's unscented-PF form (seed 000 eqs. 30-33 as
  printed): every particle carries its own covariance P^i; the generated CKF predict + update of
  (x^i_{k-1}, P^i_{k-1}) gives N(m^i, P^i_{k|k}), the particle is drawn from it and P^i_{k|k} is
  kept (and follows its particle through resampling). P^i converges to the CKF posterior, which
  is much wider than the one-step process noise, so the importance ratio p(x|x_prev)/q is often
  degenerate (ESS near 1): see tests/runtime/test_particle_filters.py.
* ``OptimalCubatureProposal`` -- the locally optimal form: each particle's cubature step starts
  from P^i = 0, so its predicted density is N(f(x^i_{k-1}), Q_k) and the cubature update with z
  approximates p(x_k | x^i_{k-1}, z) (exact for a linear measurement, where the weight becomes
  the predictive likelihood p(z | x^i_{k-1})). Nothing is carried between steps. Computed in
  NumPy from h at the 2r cubature points of N(f(x^i), Q) (one SIMD call of h over N (2r + 1)
  points), where r is the rank of Q.

Singular Q (both): the transition lives on the subspace V (n x r) of Q's positive eigenvalues
(``TransitionNoise``). Particles are drawn there, x = f + V y with y from the proposal's
marginal on the subspace, and the ratio log N(y; 0, Lambda) - log q(y) is exact on it (both
densities are with respect to the same r-dimensional Lebesgue measure). No floor is added.

The proposals use the moment-matched (single Gaussian) covariances of mixture noises; the
engine's weights use the exact mixture likelihood.
"""
from __future__ import annotations

import numpy as np

from ...compiled.batches import CubaturePredictBatch, CubatureStepBatch, CubatureUpdateBatch, MeasureBatch
from ...noise.mixtures import LOG_2PI
from ...numerics import stacked_cholesky, wrap_to_pi
from .engine import Proposal

__all__ = ["CarriedCubatureProposal", "OptimalCubatureProposal"]


def _gaussian_draw(engine, f: np.ndarray, mean: np.ndarray, C: np.ndarray) -> np.ndarray:
    """engine.proposed = f + V y, y ~ N(V^T (mean - f), V^T C V) per particle; returns the log ratio.

    mean (n, N), C (N, n, n) per particle; log ratio = log p_w(V y) - log q(y) on the subspace.
    """
    tr = engine.transition
    N, r = engine.N, tr.rank
    xi = engine.rng.standard_normal((r, N))
    if tr.support is not None:
        idx = tr.support
        mean_y = (mean - f)[idx]
        C_y = C if tr.full else C[:, idx][:, :, idx]
    else:
        V = tr.basis
        mean_y = V.T @ (mean - f)
        C_y = V.T @ C @ V
    L, log_det = stacked_cholesky(C_y, repair=True)
    y = mean_y + np.matmul(L, xi.T[:, :, None])[:, :, 0].T
    np.add(f, tr.embed(y), out=engine.proposed)
    log_q = -0.5 * np.einsum("rn,rn->n", xi, xi) - log_det - 0.5 * r * LOG_2PI
    return tr.log_density(engine.proposed - f) - log_q


class CarriedCubatureProposal(Proposal):
    """CKF predict + update of (x^i, P^i) per particle, P^i carried (see the module docstring)."""

    name = "cubature, carried P^i"
    _state = ("carried",)

    def bind(self, engine) -> None:
        model, N = engine.model, engine.N
        self._pb = CubaturePredictBatch(model, N, engine.p)
        self._ub = CubatureUpdateBatch(model, N, engine.p, self._pb.mean_pred, self._pb.cov_pred)
        self._pb.Q[...] = engine.transition.covariance[:, :, None]
        self._ub.R[...] = engine.noise.covariance[:, :, None]
        self._r_mean, self._q_mean = engine.noise.mean, engine.transition.mean
        self._fused = None if self._q_mean.any() else CubatureStepBatch(model, self._pb, self._ub)
        self._pb.cov[...] = engine.P[:, :, None]  # P^i_0 = P0
        self._next_cov = None  # P^i of the step under way, committed by commit()
        self.repairs = 0

    def _inputs(self, engine, u, dt) -> None:
        self._pb.mean[...] = engine.particles
        self._pb.u[...] = u
        self._pb.dt[0] = dt

    def _check_dt(self, engine, u, dt) -> None:
        if dt > engine._checked_dt and engine.pieces(u, dt) > 1:
            raise ValueError(f"{engine.name} (carried P^i): dt = {dt!r} s is beyond the model's stable range (f needs "
                             f"{engine.pieces(u, dt)} substeps there) and the generated cubature step cannot be "
                             "subdivided; use a smaller dt or the optimal proposal")

    def predict(self, engine, u, dt) -> None:
        self._check_dt(engine, u, dt)
        engine.transition_draw(u, dt)
        self._inputs(engine, u, dt)
        self._pb(engine.N)
        self._next_cov = self._pb.cov_pred

    def move(self, engine, u, dt, z, present):
        pb, ub, N = self._pb, self._ub, engine.N
        self._check_dt(engine, u, dt)
        f = engine.propagate(u, dt)  # transition means f(x^i_{k-1}) + E[w]
        self._inputs(engine, u, dt)
        ub.present[:] = present
        ub.z[...] = np.where(present, z - self._r_mean, 0.0)[:, None]
        if self._fused is not None:
            self._fused(N)
        else:
            pb(N)
            pb.mean_pred += self._q_mean[:, None]
            ub(N)
        self._next_cov = ub.cov_post
        C = np.moveaxis(ub.cov_post, -1, 0)  # (N, n, n) view
        return _gaussian_draw(engine, f, ub.mean_post, C)

    def commit(self, ancestors, mode) -> None:
        cov = self._pb.cov
        source = self._next_cov if mode != "update" else cov
        if ancestors is not None:
            cov[...] = source[:, :, ancestors]
        elif source is not cov:
            cov[...] = source
        self._next_cov = None

    @property
    def carried(self) -> np.ndarray:
        """P^i of every particle (n, n, N): the generated predict's input buffer."""
        return self._pb.cov


class OptimalCubatureProposal(Proposal):
    """Cubature approximation of p(x_k | x^i_{k-1}, z) from P^i = 0 (see the module docstring)."""

    name = "cubature, locally optimal"
    #: a measurement entry more than this many standard deviations of S from its prediction (at any
    #: particle) is left out of the proposal, as in ``CubatureUpdateBatch``; the weights keep it
    gate_sigma = 100.0

    def bind(self, engine) -> None:
        model, tr, N = engine.model, engine.transition, engine.N
        r = tr.rank
        self._r = r
        # cubature points of N(0, Q) in subspace coordinates: +-sqrt(r) sqrt(lambda_j) e_j
        self._dy = np.sqrt(r) * np.concatenate([np.diag(np.sqrt(tr.variances)), -np.diag(np.sqrt(tr.variances))], axis=1)
        self._dx = tr.embed(self._dy)  # (n, 2r)
        self._dy_scale = np.sqrt(r) * np.sqrt(tr.variances)  # (r,)
        self._points = np.zeros((model.n_x, N * (2 * r + 1)))  # column i (2r+1) + j: point j of particle i
        self._h = MeasureBatch(model, self._points, engine.p)
        self._R, self._r_mean = engine.noise.covariance, engine.noise.mean
        self._angles = engine.angle_outputs

    def move(self, engine, u, dt, z, present):
        N, r, n = engine.N, self._r, engine.model.n_x
        f = engine.propagate(u, dt)
        if r == 0:  # no process noise: the particles move deterministically, the ratio is 1
            engine.proposed[...] = f
            return np.zeros(N)
        points = self._points.reshape(n, N, 2 * r + 1)
        points[:, :, 0] = f
        np.add(f[:, :, None], self._dx[:, None, :], out=points[:, :, 1:])
        Y = self._h(N * (2 * r + 1)).reshape(-1, N, 2 * r + 1)
        rows = np.flatnonzero(present)
        Y = Y[rows]
        centre = Y[:, :, 0]
        spread = Y[:, :, 1:] - centre[:, :, None]  # (m, N, 2r)
        angle_rows = [i for i, row in enumerate(rows) if row in self._angles]
        for i in angle_rows:
            spread[i] = wrap_to_pi(spread[i])
        offset = spread.mean(axis=2)
        z_hat = centre + offset
        dZ = spread - offset[:, :, None]
        weight = 1.0 / (2 * r)
        dZt = dZ.transpose(1, 0, 2)  # (N, m, 2r)
        S = dZt @ dZt.transpose(0, 2, 1)
        S *= weight
        S += self._R[np.ix_(rows, rows)]
        # P_yz: the subspace offsets are +-sqrt(r) sqrt(lambda_k) e_k, so only the pair k, k + r contributes
        Pyz = (dZ[:, :, :r] - dZ[:, :, r:]).transpose(1, 2, 0) * (weight * self._dy_scale)[None, :, None]  # (N, r, m)
        innovation = (z[rows] - self._r_mean[rows])[:, None] - z_hat
        for i in angle_rows:
            innovation[i] = wrap_to_pi(innovation[i])
        outliers = np.any(np.abs(innovation) > self.gate_sigma * np.sqrt(np.einsum("naa->an", S)), axis=1)
        if outliers.any():  # propose without them (with none left: the transition)
            kept = present.copy()
            kept[rows[outliers]] = False
            if not kept.any():
                engine.transition_draw(u, dt)
                return np.zeros(N)
            return self.move(engine, u, dt, z, kept)
        KT = np.linalg.solve(S, np.swapaxes(Pyz, 1, 2))  # (N, m, r) = (S^-1 Pzy)
        mean_y = np.einsum("nar,an->rn", KT, innovation)
        C_y = np.diag(engine.transition.variances)[None] - Pyz @ KT  # Lambda - K S K^T
        C_y = 0.5 * (C_y + np.swapaxes(C_y, 1, 2))
        L, log_det = stacked_cholesky(C_y, repair=True)
        xi = engine.rng.standard_normal((r, N))
        y = mean_y + np.matmul(L, xi.T[:, :, None])[:, :, 0].T
        tr = engine.transition
        np.add(f, tr.embed(y), out=engine.proposed)
        log_q = -0.5 * np.einsum("rn,rn->n", xi, xi) - log_det - 0.5 * r * LOG_2PI
        return tr.log_density(engine.proposed - f) - log_q
