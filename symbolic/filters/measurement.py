"""The measurement side shared by every update: masks, angle residuals, the Kalman gain.

Mask convention (all updates): mask is an (n_y,) vector of 1/0; an entry with mask 0 is
ignored exactly as if the measurement did not have it. Its innovation is 0 (even when z holds
NaN there), its column of the cross-covariance is 0, and its row and column of S are those
of the identity, so K has a zero column there and nu^T S^-1 nu and log det S only count the
used entries.
"""
from __future__ import annotations

import casadi as ca

from .linalg import (
    backward_substitute_transposed, forward_substitute, guarded_cholesky, is_mirrored, symmetric_from_upper, wrap_angle,
)


def used(mask: ca.SX) -> list:
    """1/0 SX per measurement entry: whether it is used."""
    return [mask[i] != 0 for i in range(mask.size1())]


def residual(a: ca.SX, b: ca.SX, angle_outputs) -> ca.SX:
    """a - b, wrapped to (-pi, pi] for the angle outputs."""
    d = a - b
    if not angle_outputs:
        return d
    return ca.vertcat(*[wrap_angle(d[i]) if i in angle_outputs else d[i] for i in range(d.size1())])


def masked_innovation(z: ca.SX, z_pred: ca.SX, mask: ca.SX, angle_outputs) -> ca.SX:
    """z - z_pred (angles wrapped) on used entries, 0 elsewhere (never reading z there)."""
    d = residual(z, z_pred, angle_outputs)
    return ca.vertcat(*[ca.if_else(u, d[i], 0) for i, u in enumerate(used(mask))])


def masked_covariance(C: ca.SX, mask: ca.SX, fill_identity: bool = True) -> ca.SX:
    """C on the used rows/columns; identity (or zero) on the others (symmetric C stays mirrored)."""
    u = used(mask)
    n = C.size1()

    def entry(i, j):
        return u[i] * u[j] * C[i, j] + ((1 - u[i]) if i == j and fill_identity else 0)

    if is_mirrored(C):  # one expression per pair, mirrored: half the products, and S stays mirrored
        return symmetric_from_upper({(i, j): entry(i, j) for i in range(n) for j in range(i, n)}, n)
    out = ca.SX.zeros(n, n)
    for i in range(n):
        for j in range(n):
            out[i, j] = entry(i, j)
    return out


def masked_columns(C: ca.SX, mask: ca.SX) -> ca.SX:
    """C with the columns of unused entries set to zero."""
    return ca.horzcat(*[u * C[:, j] for j, u in enumerate(used(mask))])


def gain_update(x: ca.SX, P: ca.SX, Pxz: ca.SX, S: ca.SX, innovation: ca.SX, with_gain: bool = False):
    """x + K nu and P - K S K^T with K = Pxz S^-1 (seed 000 eq. 29, seed 002 eqs. 16-18).

    With S = L L^T and W = L^-1 Pxz^T: K = W^T L^-1, so K nu = W^T (L^-1 nu) and K S K^T = W^T W
    (symmetric by construction); K itself (L^-T W, transposed) is formed only when asked for.
    Returns (x_post, P_post, K or None, ok) with ok the Cholesky guard of S.
    """
    L, ok = guarded_cholesky(S)
    W = forward_substitute(L, Pxz.T)
    x_post = x + ca.mtimes(W.T, forward_substitute(L, innovation))
    K = backward_substitute_transposed(L, W).T if with_gain else None
    n = P.size1()
    P_post = ca.SX.zeros(n, n)
    for i in range(n):
        for j in range(i, n):
            P_post[i, j] = P[i, j] - ca.dot(W[:, i], W[:, j])
            P_post[j, i] = P_post[i, j]
    return x_post, P_post, K, ok
