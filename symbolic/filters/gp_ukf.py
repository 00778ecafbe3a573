"""GP-UKF prediction (Ko et al. 2007; seed 004 Table 2, lines 1-2) as one CasADi Function.

    <name>(x, P, u, abk) -> (x_pred, P_pred, Q, ok)

One Gaussian process per state predicts that state's increment over one step from the
features g(x, u) (seed 004: the NARX input [eta, u]); x_pred_i = x_i + mean_i(g). The
scaled unscented points of (x, P) (alpha, beta, kappa = abk at run time, as the UKF) go
through the GP means; Q_k = diag(variance_i(g(x, u))) is the GP predictive variance at the
prior mean (seed 004 section 5: "at the previous mean sigma point"), including each GP's
learned noise; P_pred = covariance of the points + Q_k.

Why increments: far from the training data a GP reverts to its prior mean; for an increment
that is "the state stays" (with a large Q_k), for a next-state GP it would be the training
mean of that state, a jump. Ko et al. also model the state change.

Built in MX: the GP Functions (abyssal.symbolic.gp) keep their training data as constant
arrays; each GP's means at all sigma points are one matrix product with them. The sigma points and
moments are SX pieces (guarded Cholesky as in the other sigma-point filters), so the C stays
about the size of the GP constants.
"""
from __future__ import annotations

import casadi as ca

from .linalg import all_finite, guarded_cholesky, symmetrise, weighted_outer, weighted_sum
from .sigma_points import scaled_unscented_rule


def gp_ukf_predict_function(name: str, mean_fns, var_fns, n_u: int, features=None) -> ca.Function:
    """The GP-UKF predict of len(mean_fns) states; features(x, u) -> GP input (default [x; u]).

    mean_fns[i] maps the features of all 2n+1 sigma points, (d, 2n+1), to their means (1, 2n+1)
    (abyssal.symbolic.gp.gp_mean_batch_function); var_fns[i] maps one feature vector to a variance.
    """
    n = len(mean_fns)
    features = features or (lambda x, u: ca.vertcat(x, u))

    # SX pieces: sigma points of (x, P) and the weighted moments of the propagated points.
    xs, Ps, abks = ca.SX.sym("x", n), ca.SX.sym("P", n, n), ca.SX.sym("abk", 3)
    rule = scaled_unscented_rule(n, abks[0], abks[1], abks[2])
    L, ok = guarded_cholesky(symmetrise(Ps))
    points = ca.Function(f"{name}_points", [xs, Ps, abks], [rule.points(xs, L), ok])
    Ys = ca.SX.sym("Y", n, rule.n_points)
    mean = weighted_sum(Ys, rule.wm)
    cov = weighted_outer(Ys - ca.repmat(mean, 1, rule.n_points), rule.wc)
    moments = ca.Function(f"{name}_moments", [Ys, abks], [mean, cov])

    # The GP-input features of one state, and the GP variances at one point.
    xz, uz = ca.MX.sym("x", n), ca.MX.sym("u", n_u)
    g = features(xz, uz)
    feature_map = ca.Function(f"{name}_features", [xz, uz], [g])
    step_var = ca.Function(f"{name}_variance", [xz, uz], [ca.vertcat(*[fn(g) for fn in var_fns])])

    x, P, u, abk = ca.MX.sym("x", n), ca.MX.sym("P", n, n), ca.MX.sym("u", n_u), ca.MX.sym("abk", 3)
    X, ok_points = points(x, P, abk)
    G = feature_map.map(rule.n_points)(X, ca.repmat(u, 1, rule.n_points))   # (d, 2n+1)
    Y = X + ca.vertcat(*[fn(G) for fn in mean_fns])                          # x + increment, per point
    x_pred, P_points = moments(Y, abk)
    Q = ca.diag(step_var(x, u))
    P_pred = P_points + Q
    finite = ca.Function(f"{name}_finite", [xs, Ps], [all_finite(xs, Ps)])
    ok_out = ok_points * finite(x_pred, P_pred)
    return ca.Function(name, [x, P, u, abk], [x_pred, P_pred, ca.densify(Q), ok_out],
                       ["x", "P", "u", "abk"], ["x_pred", "P_pred", "Q", "ok"])
