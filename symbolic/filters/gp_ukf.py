"""GP-UKF prediction (Ko et al. 2007; seed 004 Table 2, lines 1-2) as one CasADi Function.

    <name>(x, P, u, abk, feature_shift, feature_scale, *GP data (5 per state)) -> (x_pred, P_pred, Q, ok)

One Gaussian process per state predicts that state's increment over one step (or its next value,
see ``increments``) from the standardised features g = (features(x, u) - feature_shift) / feature_scale
(seed 004: the NARX input [eta, u]): x_pred_i = x_i + mean_i(g), or mean_i(g). The scaled unscented
points of (x, P) (alpha, beta, kappa = abk at run time, as the UKF) go through the GP means; Q_k =
diag(variance_i(g(x, u))) is the GP predictive variance at the prior mean (seed 004 section 5: "at the
previous mean sigma point"), including each GP's learned noise; P_pred = covariance of the points + Q_k.

The GPs' training data, weights and hyperparameters, and the feature standardisation, are run-time
inputs (abyssal.symbolic.gp: DATA_NAMES per GP, one layout for all n GPs): the C is the same for every
training set of the same size, and is a few loops, not the data.

Increments or next states. Far from the training data a GP reverts to its prior mean; for an
increment that is "the state stays" (with a large Q_k), for a next-state GP it is the training mean of
that state, a jump. Ko et al. model the state change; Deisenroth's gpukf.m (cited by seed 004) the
next state: ``increments`` lists the states whose GP predicts the change (default: all).

The sigma points and moments are SX pieces (guarded Cholesky as in the other sigma-point filters);
the GP parts are the MX Functions of abyssal.symbolic.gp.
"""
from __future__ import annotations

import casadi as ca

from .. import gp
from .linalg import all_finite, guarded_cholesky, symmetrise, weighted_outer, weighted_sum
from .sigma_points import scaled_unscented_rule

#: the predict's inputs after x, P, u, abk: the features' standardisation, then the GP data (GPLayout.input_names)
FEATURE_INPUTS = ("feature_shift", "feature_scale")


def gp_ukf_predict_function(name: str, layout: gp.GPLayout, n_u: int, features=None, increments=None) -> ca.Function:
    """The GP-UKF predict of layout.count states (one GP each, layout.n_inputs features).

    features(x, u) -> the raw GP input (MX, layout.n_inputs; default [x; u]), standardised by the
    run-time inputs feature_shift and feature_scale; increments: indices of the states whose GP predicts
    the increment x_{k+1} - x_k (default: all), the others' GPs predict x_{k+1} itself.
    """
    n = layout.count
    features = features or (lambda x, u: ca.vertcat(x, u))
    increments = range(n) if increments is None else increments
    if any(not 0 <= i < n for i in increments):
        raise ValueError(f"increments must index the {n} states, got {tuple(increments)}")
    d = layout.n_inputs

    # SX pieces: sigma points of (x, P) and the weighted moments of the propagated points.
    xs, Ps, abks = ca.SX.sym("x", n), ca.SX.sym("P", n, n), ca.SX.sym("abk", 3)
    rule = scaled_unscented_rule(n, abks[0], abks[1], abks[2])
    L, ok = guarded_cholesky(symmetrise(Ps))
    points = ca.Function(f"{name}_points", [xs, Ps, abks], [rule.points(xs, L), ok])
    Ys = ca.SX.sym("Y", n, rule.n_points)
    mean = weighted_sum(Ys, rule.wm)
    cov = weighted_outer(Ys - ca.repmat(mean, 1, rule.n_points), rule.wc)
    moments = ca.Function(f"{name}_moments", [Ys, abks], [mean, cov])

    # The standardised GP input of one state.
    xz, uz, shift, scale = ca.MX.sym("x", n), ca.MX.sym("u", n_u), ca.MX.sym("shift", d), ca.MX.sym("scale", d)
    raw = features(xz, uz)
    if raw.numel() != d:
        raise ValueError(f"features(x, u) has {raw.numel()} entries, the GP layout {d}")
    feature_map = ca.Function(f"{name}_features", [xz, uz, shift, scale], [(raw - shift) / scale])

    x, P, u, abk = ca.MX.sym("x", n), ca.MX.sym("P", n, n), ca.MX.sym("u", n_u), ca.MX.sym("abk", 3)
    shift, scale = ca.MX.sym("feature_shift", d), ca.MX.sym("feature_scale", d)
    data = layout.symbols()
    X, ok_points = points(x, P, abk)
    G = feature_map.map(rule.n_points)(X, u, shift, scale)                  # (d, 2n+1)
    predicted = gp.mean_function(layout, rule.n_points, f"{name}_mean")(G, *data)   # (n, 2n+1)
    if sorted(increments) == list(range(n)):
        Y = X + predicted                                                   # x + increment
    else:                                                                   # x + increment, or the next state
        kept = ca.DM.zeros(n, 1)
        for i in increments:
            kept[i] = 1
        Y = ca.repmat(kept, 1, rule.n_points) * X + predicted
    x_pred, P_points = moments(Y, abk)
    variances = gp.variance_function(layout, f"{name}_variance")(feature_map(x, u, shift, scale), *data)
    Q = ca.diag(variances)
    P_pred = P_points + Q
    finite = ca.Function(f"{name}_finite", [xs, Ps], [all_finite(xs, Ps)])
    ok_out = ok_points * finite(x_pred, P_pred)
    return ca.Function(name, [x, P, u, abk, shift, scale, *data], [x_pred, P_pred, ca.densify(Q), ok_out],
                       ["x", "P", "u", "abk", *FEATURE_INPUTS, *layout.input_names()], ["x_pred", "P_pred", "Q", "ok"])
