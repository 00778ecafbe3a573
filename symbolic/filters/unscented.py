"""Sigma-point Kalman filters: UKF (scaled unscented rule, alpha/beta/kappa at run time) and CKF
(cubature rule). Additive noise: Q and R are runtime inputs.

    <m>_ckf_predict(x, P, u, p, dt, Q)         -> (x_pred, P_pred, ok)
    <m>_ckf_update(x, P, z, p, R, mask)        -> (x_post, P_post, innovation, S, ok)
    <m>_ukf_predict(x, P, u, p, dt, Q, abk)    -> (x_pred, P_pred, ok)
    <m>_ukf_update(x, P, z, p, R, mask, abk)   -> (x_post, P_post, innovation, S, ok)
    <m>_ckf_step(x, P, u, p, dt, Q, z, R, mask) -> (x_post, P_post, innovation, S, ok)
                                                  predict then update in one call (unit "steps",
                                                  for the runtime's step(): one call per step)

Predict (seed 000 eqs. 22-24, seed 002 eqs. 7-10): points from the symmetrised P by a guarded
Cholesky factor, propagated through f, weighted mean, covariance of the residuals + Q (the
centred form of eq. 24, which is algebraically equal and loses less precision).
Update (seed 000 eqs. 25-29, seed 002 eqs. 11-18): points redrawn from the given (predicted)
x and P, passed through h; z_pred, Pzz + R, Pxz; gain, mean, P - K S K^T. Measurement
residuals of angle outputs are wrapped to (-pi, pi]. ``ok`` is 1 when every Cholesky pivot
passed its guard and every output is finite.
"""
from __future__ import annotations

import casadi as ca

from ..codegen import FUNCTION_OPTIONS
from ..model import Model
from .common import filter_symbols, measurement, transition
from .linalg import all_finite, guarded_cholesky, symmetrise, weighted_outer, weighted_sum
from .measurement import gain_update, masked_columns, masked_covariance, masked_innovation, residual
from .sigma_points import SigmaPointRule, cubature_rule, scaled_unscented_rule

PREDICT_OUT = ["x_pred", "P_pred", "ok"]
UPDATE_OUT = ["x_post", "P_post", "innovation", "S", "ok"]
#: fused predict + update (one C call per step for the runtime's step()); same outputs as an update
STEP_IN = ["x", "P", "u", "p", "dt", "Q", "z", "R", "mask"]


def sigma_point_predict(model: Model, rule_of, x, P, u, p, dt, Q, check_finite: bool = True):
    """(x_pred, P_pred, ok) of a sigma-point rule; rule_of(n) builds the rule.

    check_finite=False leaves the finiteness test of x_pred and P_pred to the caller (ok is then
    the Cholesky guard alone).
    """
    f = transition(model)
    P = symmetrise(P)
    L, ok = guarded_cholesky(P)
    rule: SigmaPointRule = rule_of(model.n_x)
    X = rule.points(x, L)
    Y = ca.horzcat(*[f(X[:, k], u, p, dt) for k in range(rule.n_points)])
    x_pred = weighted_sum(Y, rule.wm)
    D = Y - ca.repmat(x_pred, 1, rule.n_points)
    P_pred = weighted_outer(D, rule.wc) + symmetrise(Q)
    return x_pred, P_pred, (ok * all_finite(x_pred, P_pred)) if check_finite else ok


def sigma_point_moments(model: Model, rule_of, x, P, p, mask):
    """Points redrawn from (x, P) through h: (P symmetrised, z_pred, Pzz without R, Pxz, ok); Pzz and Pxz masked."""
    h = measurement(model)
    P = symmetrise(P)
    L, ok = guarded_cholesky(P)
    rule: SigmaPointRule = rule_of(model.n_x)
    DX = rule.offsets(L)
    X = ca.repmat(x, 1, rule.n_points) + DX
    Z = ca.horzcat(*[h(X[:, k], p) for k in range(rule.n_points)])
    z_pred = weighted_sum(Z, rule.wm)
    DZ = ca.horzcat(*[residual(Z[:, k], z_pred, model.angle_outputs) for k in range(rule.n_points)])
    Pzz = masked_covariance(weighted_outer(DZ, rule.wc), mask, fill_identity=False)  # identity comes with R
    Pxz = masked_columns(weighted_outer(DX, rule.wc, DZ), mask)
    return P, z_pred, Pzz, Pxz, ok


def sigma_point_update(model: Model, rule_of, x, P, z, p, R, mask):
    """(x_post, P_post, innovation, S, ok) of a sigma-point rule."""
    P, z_pred, Pzz, Pxz, ok_p = sigma_point_moments(model, rule_of, x, P, p, mask)
    innovation = masked_innovation(z, z_pred, mask, model.angle_outputs)
    S = Pzz + masked_covariance(symmetrise(R), mask)
    x_post, P_post, _, ok_s = gain_update(x, P, Pxz, S, innovation)
    return x_post, P_post, innovation, S, ok_p * ok_s * all_finite(x_post, P_post, innovation, S)


def ckf_functions(model: Model) -> tuple[ca.Function, ...]:
    s = filter_symbols(model)
    m = model.name
    predict = ca.Function(
        f"{m}_ckf_predict", [s.x, s.P, s.u, s.p, s.dt, s.Q],
        list(sigma_point_predict(model, cubature_rule, s.x, s.P, s.u, s.p, s.dt, s.Q)),
        ["x", "P", "u", "p", "dt", "Q"], PREDICT_OUT, FUNCTION_OPTIONS)
    update = ca.Function(
        f"{m}_ckf_update", [s.x, s.P, s.z, s.p, s.R, s.mask],
        list(sigma_point_update(model, cubature_rule, s.x, s.P, s.z, s.p, s.R, s.mask)),
        ["x", "P", "z", "p", "R", "mask"], UPDATE_OUT, FUNCTION_OPTIONS)
    return predict, update


def ckf_step_function(model: Model) -> ca.Function:
    """<m>_ckf_step: predict then update in one function (what the runtime's step() calls).

    Its ok is the predict's times the update's, except that the predict's finiteness test is
    left out: it is implied by the update's. x_post = x_pred + K nu and P_post = P_pred - W^T W
    entry by entry (gain_update; P_pred is symmetric by construction, so the update's symmetrise
    returns it as it is), and an IEEE sum with a NaN or infinite term is never finite.
    """
    s = filter_symbols(model)
    m = model.name
    x_pred, P_pred, ok_pred = sigma_point_predict(model, cubature_rule, s.x, s.P, s.u, s.p, s.dt, s.Q,
                                                  check_finite=False)
    x_post, P_post, innovation, S, ok_update = sigma_point_update(model, cubature_rule, x_pred, P_pred, s.z, s.p, s.R, s.mask)
    step = ca.Function(
        f"{m}_ckf_step", [s.x, s.P, s.u, s.p, s.dt, s.Q, s.z, s.R, s.mask],
        [x_post, P_post, innovation, S, ok_pred * ok_update],
        STEP_IN, UPDATE_OUT, FUNCTION_OPTIONS)
    return step


def unscented_rule_of(abk: ca.SX):
    return lambda n: scaled_unscented_rule(n, abk[0], abk[1], abk[2])


def ukf_functions(model: Model) -> tuple[ca.Function, ...]:
    s = filter_symbols(model)
    abk = ca.SX.sym("abk", 3)
    rule_of = unscented_rule_of(abk)
    m = model.name
    predict = ca.Function(
        f"{m}_ukf_predict", [s.x, s.P, s.u, s.p, s.dt, s.Q, abk],
        list(sigma_point_predict(model, rule_of, s.x, s.P, s.u, s.p, s.dt, s.Q)),
        ["x", "P", "u", "p", "dt", "Q", "abk"], PREDICT_OUT, FUNCTION_OPTIONS)
    update = ca.Function(
        f"{m}_ukf_update", [s.x, s.P, s.z, s.p, s.R, s.mask, abk],
        list(sigma_point_update(model, rule_of, s.x, s.P, s.z, s.p, s.R, s.mask)),
        ["x", "P", "z", "p", "R", "mask", "abk"], UPDATE_OUT, FUNCTION_OPTIONS)
    return predict, update
