"""Extended Kalman filter steps, additive noise (Q, R runtime inputs).

    <m>_ekf_predict(x, P, u, p, dt, Q)    -> (x_pred, P_pred, ok)
    <m>_ekf_update(x, P, z, p, R, mask)   -> (x_post, P_post, innovation, S, ok)
    <m>_ekf_step(x, P, u, p, dt, Q, z, R, mask) -> (x_post, P_post, innovation, S, ok)   predict + update

Predict: x_pred = f(x, u, p, dt), P_pred = F P F^T + Q with F = df/dx at x.
Update: nu = z - h(x) (angles wrapped), S = H P H^T + R, K = P H^T S^-1 (guarded Cholesky of S),
x_post = x + K nu and the Joseph form P_post = (I - K H) P (I - K H)^T + K R K^T, which stays
symmetric positive semi-definite under roundoff. Unused measurement entries (mask 0) have their
row of H and their row/column of R removed exactly (see measurement.py).
"""
from __future__ import annotations

import casadi as ca

from ..codegen import FUNCTION_OPTIONS
from ..model import Model
from .common import filter_symbols, measurement, transition
from .linalg import all_finite, congruence, symmetrise
from .measurement import gain_update, masked_covariance, masked_innovation, used
from .unscented import PREDICT_OUT, STEP_IN, UPDATE_OUT


def ekf_predict(model: Model, x, P, u, p, dt, Q):
    x_pred = transition(model)(x, u, p, dt)
    F = ca.jacobian(x_pred, x)
    P_pred = congruence(F, symmetrise(P)) + symmetrise(Q)
    return x_pred, P_pred, all_finite(x_pred, P_pred)


def ekf_update(model: Model, x, P, z, p, R, mask):
    z_pred = measurement(model)(x, p)
    H = ca.Function("H", [model.x, model.p], [ca.jacobian(model.y, model.x)])(x, p)  # x may be an expression
    H = ca.vertcat(*[u * H[i, :] for i, u in enumerate(used(mask))])
    P = symmetrise(P)
    R_used = masked_covariance(symmetrise(R), mask)
    innovation = masked_innovation(z, z_pred, mask, model.angle_outputs)
    PHt = ca.mtimes(P, H.T)
    S = symmetrise(ca.mtimes(H, PHt)) + R_used
    x_post, _, K, ok = gain_update(x, P, PHt, S, innovation)
    A = ca.SX.eye(model.n_x) - ca.mtimes(K, H)
    P_post = congruence(A, P) + congruence(K, R_used)  # Joseph form
    return x_post, P_post, innovation, S, ok * all_finite(x_post, P_post, innovation, S)


def ekf_functions(model: Model) -> tuple[ca.Function, ...]:
    s = filter_symbols(model)
    m = model.name
    predict = ca.Function(
        f"{m}_ekf_predict", [s.x, s.P, s.u, s.p, s.dt, s.Q],
        [ca.densify(e) for e in ekf_predict(model, s.x, s.P, s.u, s.p, s.dt, s.Q)],
        ["x", "P", "u", "p", "dt", "Q"], PREDICT_OUT, FUNCTION_OPTIONS)
    update = ca.Function(
        f"{m}_ekf_update", [s.x, s.P, s.z, s.p, s.R, s.mask],
        [ca.densify(e) for e in ekf_update(model, s.x, s.P, s.z, s.p, s.R, s.mask)],
        ["x", "P", "z", "p", "R", "mask"], UPDATE_OUT, FUNCTION_OPTIONS)
    return predict, update


def ekf_step_function(model: Model) -> ca.Function:
    """<m>_ekf_step: predict then update in one function (what the runtime's step() calls)."""
    s = filter_symbols(model)
    m = model.name
    x_pred, P_pred, ok_pred = ekf_predict(model, s.x, s.P, s.u, s.p, s.dt, s.Q)
    x_post, P_post, innovation, S, ok_update = ekf_update(model, x_pred, P_pred, s.z, s.p, s.R, s.mask)
    step = ca.Function(
        f"{m}_ekf_step", [s.x, s.P, s.u, s.p, s.dt, s.Q, s.z, s.R, s.mask],
        [ca.densify(e) for e in (x_post, P_post, innovation, S, ok_pred * ok_update)],
        STEP_IN, UPDATE_OUT, FUNCTION_OPTIONS)
    return step
