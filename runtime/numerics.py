"""Shared numerical helpers of the runtime: one implementation each (import them, never copy them).

* ``angle_indices(model, "states" | "outputs")``, ``wrap_angles(values, indices, axis)`` and
  ``wrap_to_pi(a)``: angle
  wrapping to (-pi, pi], driven by the model's ``angle_states`` / ``angle_outputs`` (never a
  hard-coded index).
* ``repair_covariance(P)``: the one covariance repair (symmetrise, clip eigenvalues at
  ``REPAIR_FLOOR`` times the largest |eigenvalue|); works on one (n, n) matrix or a stack
  (K, n, n).
* ``relative_error(a, b)``: max |a - b| / max(1, max |b|), the single definition used by checks.
* ``nees(errors, covariances)``: e^T P^-1 e per step, by eigen-decomposition with the eigenvalues
  floored at ``NEES_FLOOR`` times the largest: never negative, finite for a singular P (an error along
  a collapsed direction counts as the overconfidence it is). Every consistency number uses it.
* ``SYMMETRY_TOLERANCE``: the relative asymmetry a covariance given to abyssal may have.
* ``kalman_filter(A, B, H, Q, R, x0, P0, U, Z)``: the exact (linear) Kalman filter, an oracle;
  NaN entries of Z are left out entry by entry, as every runtime filter does.
* ``simulate_truth(model, x0, U, dt, Q, R, rng, p=None)``: truth and measurements of a model
  with additive Gaussian noise, x_{k+1} = f(x_k, u_k) + w_k, z_{k+1} = h(x_{k+1}) + v_{k+1}.
"""
from __future__ import annotations

import numpy as np

__all__ = ["NEES_FLOOR", "REPAIR_FLOOR", "SYMMETRY_TOLERANCE", "angle_indices", "covariance_root", "factorable_covariance",
           "gaussian_draws", "grew_beyond", "kalman_filter", "nees", "relative_error", "repair_covariance", "simulate_truth",
           "stacked_cholesky", "wrap_angles", "wrap_to_pi"]

#: eigenvalue floor of ``repair_covariance``, relative to the largest |eigenvalue|. 1e-10 makes
#: every pivot of the generated Cholesky factorisations pass their guard (1e-13).
REPAIR_FLOOR = 1e-10
#: eigenvalue floor of ``nees``, relative to each covariance's largest eigenvalue
NEES_FLOOR = 1e-12
#: relative asymmetry allowed in a covariance: |A - A^T| <= tol * max|A|
SYMMETRY_TOLERANCE = 1e-9


def angle_indices(model, which: str = "states") -> tuple[int, ...]:
    """The model's angle states or outputs (empty when the model declares none)."""
    if which not in ("states", "outputs"):
        raise ValueError(f"which must be 'states' or 'outputs', got {which!r}")
    return tuple(getattr(model, f"angle_{which}", ()) or ())


def wrap_to_pi(a):
    """Angles wrapped to (-pi, pi] (elementwise; the one wrapping formula of the runtime)."""
    return np.pi - np.remainder(np.pi - a, 2 * np.pi)


def wrap_angles(values: np.ndarray, indices, axis: int = -1) -> np.ndarray:
    """A copy of values with the entries at `indices` along `axis` wrapped to (-pi, pi]."""
    out = np.array(values, dtype=np.float64)
    if len(indices):
        moved = np.moveaxis(out, axis, 0)
        for i in indices:
            moved[i] = wrap_to_pi(moved[i])
    return out


def nees(errors: np.ndarray, covariances: np.ndarray, floor: float = NEES_FLOOR) -> np.ndarray:
    """e_t^T P_t^-1 e_t for errors (T, n) and covariances (T, n, n) (angles already wrapped by the caller).

    P_t = V diag(l) V^T (symmetrised), l clipped from below at floor * max(l) (and the smallest
    normal double), so the value is >= 0 for every input and finite for a singular or near-singular
    P; where P is zero (a particle cloud collapsed to a point) it is e^T e over the smallest normal double,
    inf (without a warning) once |e| > ~1.3; a non-finite error or covariance gives NaN for that step.
    """
    e = np.asarray(errors, dtype=np.float64)
    P = np.asarray(covariances, dtype=np.float64)
    out = np.full(e.shape[0], np.nan)
    ok = np.isfinite(e).all(axis=1) & np.isfinite(P).all(axis=(1, 2))
    if ok.any():
        values, vectors = np.linalg.eigh(0.5 * (P[ok] + np.swapaxes(P[ok], 1, 2)))
        largest = np.max(np.abs(values), axis=1, keepdims=True)
        values = np.maximum(values, np.maximum(floor * largest, np.finfo(np.float64).tiny))
        projected = np.einsum("tij,ti->tj", vectors, e[ok])
        with np.errstate(over="ignore"):  # e^2 / tiny for a zero P: inf as documented, no warning
            out[ok] = np.sum(projected ** 2 / values, axis=1)
    return out


def repair_covariance(P: np.ndarray, floor: float = REPAIR_FLOOR) -> np.ndarray:
    """Nearest-in-spectrum symmetric positive definite matrix (or stack of them, (..., n, n)).

    Eigenvalues are clipped from below at floor * max|eigenvalue| of each matrix. The matrix is
    scaled by its largest entry first, so entries near 1e308 do not overflow.
    """
    A = np.asarray(P, dtype=np.float64)
    A = 0.5 * (A + np.swapaxes(A, -1, -2))
    scale = np.max(np.abs(A), axis=(-2, -1), keepdims=True)
    scale = np.where(scale > 0, scale, 1.0)
    values, vectors = np.linalg.eigh(A / scale)
    top = np.max(np.abs(values), axis=-1, keepdims=True)
    clipped = np.maximum(values, floor * np.maximum(top, np.finfo(float).tiny))
    B = (vectors * clipped[..., None, :]) @ np.swapaxes(vectors, -1, -2)
    B = 0.5 * (B + np.swapaxes(B, -1, -2)) * scale
    return np.asfortranarray(B) if B.ndim == 2 else B


def factorable_covariance(P: np.ndarray, noise: np.ndarray, floor: float = REPAIR_FLOOR) -> np.ndarray:
    """The nearest covariance a sigma-point or cubature rule can factor: ``repair_covariance(P)``, and for
    P = 0 (a known state, the Dirac) floor * max(max |noise|, 1) * I, the Dirac's nearest Gaussian."""
    if np.any(P):
        return repair_covariance(P, floor)
    return np.asfortranarray(floor * max(float(np.max(np.abs(noise))), 1.0) * np.eye(P.shape[-1]))


def relative_error(a, b) -> float:
    """max |a - b| / max(1, max |b|): absolute near zero, relative for large values."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"relative_error: shapes differ, {a.shape} vs {b.shape}")
    if a.size == 0:
        return 0.0
    return float(np.max(np.abs(a - b)) / max(1.0, float(np.max(np.abs(b)))))


def kalman_filter(A, B, H, Q, R, x0, P0, U, Z):
    """Exact Kalman filter of x_{k+1} = A x_k + B u_k + w, z = H x + v: (xs (T, n), Ps (T, n, n)).

    Step k predicts with U[k] then updates with Z[k]; NaN entries of Z[k] are left out (the
    update uses the rows of H and R of the present entries); an all-NaN row only predicts.
    """
    A, B, H, Q, R = (np.asarray(a, dtype=np.float64) for a in (A, B, H, Q, R))
    x, P = np.array(x0, dtype=np.float64), np.array(P0, dtype=np.float64)
    U, Z = np.asarray(U, dtype=np.float64), np.asarray(Z, dtype=np.float64)
    xs, Ps = np.empty((len(U), x.size)), np.empty((len(U), x.size, x.size))
    for k, (u, z) in enumerate(zip(U, Z)):
        x, P = A @ x + B @ u, A @ P @ A.T + Q
        present = np.isfinite(z)
        if present.any():
            Hk, Rk = H[present], R[np.ix_(present, present)]
            S = Hk @ P @ Hk.T + Rk
            K = np.linalg.solve(S, Hk @ P).T
            x = x + K @ (z[present] - Hk @ x)
            I_KH = np.eye(x.size) - K @ Hk
            P = I_KH @ P @ I_KH.T + K @ Rk @ K.T  # Joseph form
        xs[k], Ps[k] = x, P
    return xs, Ps


def simulate_truth(model, x0, U, dt: float, Q, R, rng, p=None):
    """(states (T, n_x), measurements (T, n_y)) of a compiled model with additive Gaussian noise.

    states[k] = f(states[k-1], U[k], p, dt) + w_k, w_k ~ N(0, Q) (Q may be singular: drawn by
    its eigen-decomposition); measurements[k] = h(states[k], p) + v_k, v_k ~ N(0, R).
    """
    from .contract import as_generator

    rng = as_generator(rng)
    U = np.asarray(U, dtype=np.float64)
    noise_q, noise_r = covariance_root(Q, "Q"), covariance_root(R, "R")
    x = np.array(x0, dtype=np.float64)
    states = np.empty((len(U), model.n_x))
    for k, u in enumerate(U):
        x = model.f(x, u, p, dt) + noise_q @ rng.standard_normal(model.n_x)
        states[k] = x
    measurements = model.h_batch(states.T, p).T + (noise_r @ rng.standard_normal((model.n_y, len(U)))).T
    return states, measurements


def covariance_root(C, name: str = "covariance") -> np.ndarray:
    """L with L L^T = C for a symmetric positive semi-definite C (singular allowed: eigen-decomposition)."""
    C = np.asarray(C, dtype=np.float64)
    values, vectors = np.linalg.eigh(0.5 * (C + C.T))
    if values.size and values[0] < -1e-9 * max(abs(values[-1]), 1e-300):
        raise ValueError(f"{name} must be positive semi-definite; smallest eigenvalue {values[0]:.3g}")
    return vectors * np.sqrt(np.maximum(values, 0.0))


def gaussian_draws(mean: np.ndarray, C: np.ndarray, rng: np.random.Generator, count: int) -> np.ndarray:
    """count draws of N(mean, C) as columns (n, count); C may be singular (zero: every draw at the mean)."""
    return mean[:, None] + covariance_root(C) @ rng.standard_normal((mean.shape[0], count))


def stacked_times(L: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """The columns L_i xi_i (r, K) of a stack of factors L (K, r, r) and draws xi (r, K): a Gaussian
    square-root draw per particle. One einsum (np.matmul on the stack calls BLAS once per matrix)."""
    return np.einsum("kij,jk->ik", L, xi)


def stacked_cholesky(C: np.ndarray, *, repair: bool) -> tuple[np.ndarray, np.ndarray]:
    """(L, sum log diag L) of a stack of covariances C (K, r, r): lower factors (K, r, r) and (K,).

    repair=True: matrices that fail (not numerically positive definite) are replaced by
    ``repair_covariance`` first; repair=False: a failure raises numpy.linalg.LinAlgError. r = 2 is
    factored in closed form (the cooperative-navigation particle clouds: thousands of 2 x 2 matrices).
    """
    if C.shape[-1] == 2:
        a, b, c = C[:, 0, 0], C[:, 1, 0], C[:, 1, 1]
        with np.errstate(invalid="ignore", divide="ignore"):
            l11 = np.sqrt(a)
            l21 = b / l11
            l22 = np.sqrt(c - l21 * l21)
        if np.all(l11 > 0) and np.all(l22 > 0):
            L = np.zeros_like(C)
            L[:, 0, 0], L[:, 1, 0], L[:, 1, 1] = l11, l21, l22
            return L, np.log(l11) + np.log(l22)
    else:
        try:
            L = np.linalg.cholesky(C)
            return L, np.log(np.diagonal(L, axis1=1, axis2=2)).sum(axis=1)
        except np.linalg.LinAlgError:
            if not repair:
                raise
    if not repair:
        raise np.linalg.LinAlgError("a covariance of the stack is not positive definite")
    L = np.linalg.cholesky(repair_covariance(C))
    return L, np.log(np.diagonal(L, axis1=1, axis2=2)).sum(axis=1)


def grew_beyond(limit: float, before: np.ndarray, after: np.ndarray, noise: np.ndarray) -> bool:
    """Whether a predicted covariance (or a stack of them) grew more than `limit` times (largest prior variance +
    largest noise variance) in one predict, or stopped being finite: a dt beyond the model's stable range gives
    finite but absurd covariances that would poison every later step (every Kalman-type filter's growth test)."""
    def largest(A):
        return float(np.max(np.diagonal(A, axis1=-2, axis2=-1)))
    base = largest(before) + largest(noise)
    return not largest(after) <= limit * max(base, np.finfo(float).tiny)
