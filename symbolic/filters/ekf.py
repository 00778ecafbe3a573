"""Extended Kalman filter steps, additive noise (Q, R runtime inputs).

    <m>_ekf_predict(x, P, u, p, dt, Q)    -> (x_pred, P_pred, ok)
    <m>_ekf_update(x, P, z, p, R, mask)   -> (x_post, P_post, innovation, S, ok)
    <m>_ekf_step(x, P, u, p, dt, Q, z, R, mask) -> (x_post, P_post, innovation, S, ok)   calls predict, update

Predict: x_pred = f(x, u, p, dt), P_pred = F P F^T + Q with F = df/dx at x.
Update: nu = z - h(x) (angles wrapped), S = H P H^T + R, K = P H^T S^-1 (guarded Cholesky of S),
x_post = x + K nu and the Joseph form P_post = (I - K H) P (I - K H)^T + K R K^T, valid for any
gain K (see joseph_covariance for how it is evaluated). Unused measurement entries (mask 0) have
their row of H and their row/column of R removed exactly (see measurement.py and ekf_update).

Cost notes (rov4dof, SX instructions of <m>_ekf_step in generated/<m>/manifest.json): F comes
from the variational equation of the step (common.transition_with_jacobian), F P F^T and H P H^T
are computed on one triangle with the sparser factor row (linalg.congruence), symmetric inputs
are symmetrised only where they are not symmetric by construction (linalg.symmetrise), and
the Joseph form is expanded so that no n x n product with I - K H is formed.
"""
from __future__ import annotations

import casadi as ca

from ..model import Model
from .common import exported, filter_symbols, leaf, step_inputs, transition_with_jacobian
from .families import FUNCTIONS
from .linalg import all_finite, congruence, symmetric_from_upper, symmetrise
from .measurement import gain_update, masked_columns, masked_covariance, masked_innovation
from .unscented import PREDICT_IN, UPDATE_IN, UPDATE_OUT, fused_step


def covariance_leaf(model: Model, F_sparsity: ca.Sparsity) -> ca.Function:
    """<m>_ekf_covariance(x_pred, F, P, Q) -> (P_pred, ok): F P F^T + Q on F's structural nonzeros, finiteness."""
    n = model.n_x
    x, F, P, Q = ca.SX.sym("x_pred", n), ca.SX.sym("F", F_sparsity), ca.SX.sym("P", n, n), ca.SX.sym("Q", n, n)
    P_pred = congruence(F, symmetrise(P)) + symmetrise(Q)  # both mirrored: P_pred is symmetric by construction
    return leaf(f"{model.name}_ekf_covariance", [x, F, P, Q], [P_pred, all_finite(x, P_pred)],
                ["x_pred", "F", "P", "Q"], ["P_pred", "ok"])


def joseph_covariance(P: ca.SX, K: ca.SX, PHt: ca.SX, S: ca.SX) -> ca.SX:
    """The Joseph form (I - K H) P (I - K H)^T + K R K^T, for symmetric P and S = H P H^T + R.

    Expanded, it is P - K (P H^T)^T - (P H^T) K^T + K S K^T for every K (the optimality of K is
    not used, so it keeps the Joseph form's validity for the gain actually computed); with
    V = K S - P H^T (n x m):

        P_post[i, j] = P[i, j] - K[i, :] . PHt[j, :] + V[i, :] . K[j, :]

    on and above the diagonal, mirrored. That is 2 m products per entry plus n m^2 for V,
    instead of the n x n (sparse) products of (I - K H) P (I - K H)^T plus those of K R K^T
    (rov4dof: P_post costs 816 multiplications and 1896 SX instructions instead of 1200 and 2578).
    """
    n, m = K.shape
    V = ca.mtimes(K, S) - PHt
    entries = {(i, j): P[i, j] - ca.dot(K[i, :], PHt[j, :]) + ca.dot(V[i, :], K[j, :])
               for i in range(n) for j in range(i, n)}
    return symmetric_from_upper(entries, n)


def ekf_update(model: Model, x, P, z, p, R, mask):
    """(x_post, P_post, innovation, S, ok).

    The mask is applied to P H^T (columns) and to S (rows/columns, identity on unused entries)
    and never to H itself: the columns of K of unused entries are then exactly zero (S has an
    identity row and column there, P H^T a zero column), so K H = K H_masked and every use of H
    below equals the masked one. H keeps its structural sparsity and constant entries (rov4dof:
    H = [I 0], so P H^T and H P H^T are just entries of P).
    """
    h_and_H = ca.Function("h_and_H", [model.x, model.p], [model.y, ca.jacobian(model.y, model.x)])
    z_pred, H = h_and_H(x, p)  # inlined: H keeps its structural sparsity and constant entries
    P = symmetrise(P)
    PHt = ca.mtimes(P, H.T)
    S = masked_covariance(congruence(H, P, PHt) + symmetrise(R), mask)
    PHt = masked_columns(PHt, mask)
    innovation = masked_innovation(z, z_pred, mask, model.angle_outputs)
    _, _, K, ok = gain_update(x, P, PHt, S, innovation, with_gain=True)
    x_post = x + ca.mtimes(K, innovation)
    P_post = joseph_covariance(P, K, PHt, S)
    return x_post, P_post, innovation, S, ok * all_finite(x_post, P_post, innovation, S)


def ekf_functions(model: Model) -> tuple[ca.Function, ...]:
    """<m>_F, <m>_ekf_predict, <m>_ekf_update and the fused <m>_ekf_step.

    The model's F lives here (not in the model's file) so that it and the predict call one copy of
    the step-and-Jacobian leaf (the variational equation, usually the largest piece of a model).
    """
    m = model.name
    step_and_F = transition_with_jacobian(model)
    covariance = covariance_leaf(model, step_and_F.sparsity_out(1))
    s = step_inputs(model, PREDICT_IN)
    x_pred, F = step_and_F(s["x"], s["u"], s["p"], s["dt"])
    P_pred, ok = covariance(x_pred, F, s["P"], s["Q"])
    names = FUNCTIONS["ekf"]
    predict = exported(f"{m}_{names['predict']}", s, {"x_pred": x_pred, "P_pred": P_pred, "ok": ok})
    jacobian = exported(f"{m}_F", {name: s[name] for name in ("x", "u", "p", "dt")}, {"dfdx": F})
    sx = filter_symbols(model)
    update = leaf(f"{m}_{names['update']}", [sx.x, sx.P, sx.z, sx.p, sx.R, sx.mask],
                  ekf_update(model, sx.x, sx.P, sx.z, sx.p, sx.R, sx.mask), UPDATE_IN, UPDATE_OUT)
    return jacobian, predict, update, fused_step(f"{m}_{names['step']}", model, predict, update)
