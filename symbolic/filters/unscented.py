"""Sigma-point Kalman filters: UKF (scaled unscented rule, alpha/beta/kappa at run time) and CKF
(cubature rule). Additive noise: Q and R are runtime inputs.

    <m>_ckf_predict(x, P, u, p, dt, Q)         -> (x_pred, P_pred, ok)
    <m>_ckf_update(x, P, z, p, R, mask)        -> (x_post, P_post, innovation, S, ok)
    <m>_ukf_predict(x, P, u, p, dt, Q, abk)    -> (x_pred, P_pred, ok)
    <m>_ukf_update(x, P, z, p, R, mask, abk)   -> (x_post, P_post, innovation, S, ok)
    <m>_ckf_step(x, P, u, p, dt, Q, z, R, mask) -> (x_post, P_post, innovation, S, ok)
                                                  calls predict then update (one C call per
                                                  step for the runtime's step())

Predict (seed 000 eqs. 22-24, seed 002 eqs. 7-10): points from the symmetrised P by a guarded
Cholesky factor, propagated through f, weighted mean, covariance of the residuals + Q (the
centred form of eq. 24, which is algebraically equal and loses less precision).
Update (seed 000 eqs. 25-29, seed 002 eqs. 11-18): points redrawn from the given (predicted)
x and P, passed through h; z_pred, Pzz + R, Pxz; gain, mean, P - K S K^T. Measurement
residuals of angle outputs are wrapped to (-pi, pi]. ``ok`` is 1 when every Cholesky pivot
passed its guard and every output is finite.

Each step is a few calls to leaves (common.py, SigmaPointFamily below): the points' leaf, one
call of the model's f (or h) per point, and the moments' or update's leaf.
"""
from __future__ import annotations

import casadi as ca

from ..model import Model
from .common import call_columns, exported, leaf, measurement, step_inputs, transition
from .linalg import (
    all_finite, guarded_cholesky, symmetric_from_upper, symmetrise, weight_groups, weighted_outer, weighted_sum,
)
from .measurement import gain_update, masked_columns, masked_covariance, masked_innovation, residual
from .sigma_points import SigmaPointRule, cubature_rule, scaled_unscented_rule

PREDICT_IN = ["x", "P", "u", "p", "dt", "Q"]
UPDATE_IN = ["x", "P", "z", "p", "R", "mask"]
PREDICT_OUT = ["x_pred", "P_pred", "ok"]
UPDATE_OUT = ["x_post", "P_post", "innovation", "S", "ok"]
#: fused predict + update (one C call per step for the runtime's step()); same outputs as an update
STEP_IN = PREDICT_IN + ["z", "R", "mask"]


def upper_mirrored(A: ca.SX) -> ca.SX:
    """A's upper triangle mirrored below the diagonal (exactly symmetric output for any input)."""
    n = A.size1()
    return symmetric_from_upper({(i, j): A[i, j] for i in range(n) for j in range(i, n)}, n)


class SigmaPointFamily:
    """The leaves of one sigma-point rule for one model, and the steps built from them.

    rule_args: the runtime symbols the rule depends on, by name ({} for the cubature rule,
    {"abk": abk} for the scaled unscented rule); leaves and steps take them after their own
    inputs. Leaves (plain SX, emitted once per C file, see common.leaf):

        <prefix>_points(x, P, *rule_args) -> (X, L, ok)    X = x + L xi_k, L the guarded
                                                           Cholesky factor of sym(P)
        <prefix>_weights(*rule_args) -> (wm, wc)           one mean and one covariance weight per
                                                           group of points with equal weights
        <prefix>_outer(y, mean) -> (y - mean)(y - mean)^T  summed over the points of a group
        <prefix>_predicted(x_pred, C, Q) -> (P_pred, ok)   P_pred = C + sym(Q), finiteness
        <prefix>_moments(L, Z, z, mask, *rule_args) -> (innovation, Pzz, Pxz)   masked, Pzz without R
        <prefix>_noise(R, mask, Pzz, innovation) -> (R_used, ok)   sym(R) masked (robust.py: inflated)
        <prefix>_kalman(x, P, Pzz, Pxz, R_used, innovation) -> (x_post, P_post, S, ok)

    and the model's f and h (common.transition, common.measurement). A step is an MX graph
    over them: f or h in a loop over the points (Function.map), and the predicted covariance
    a loop over the points (map with a summed output), so the C holds each piece once whatever
    the number of points. Each weighted sum is w_g * (sum of the group's terms), the grouping of
    linalg._grouped_sum: one product per entry and group instead of one per point. The update's
    cross-covariance needs no loop over points: with the points' offsets L xi_k,
    Pxz = sum_k wc_k L xi_k dz_k^T = L (Xi diag(wc) DZ^T), and Xi has one entry per column.
    """

    def __init__(self, model: Model, prefix: str, rule_of, rule_args: dict[str, ca.SX]):
        self.model, self.prefix = model, prefix
        self.rule_names, self.rule_args = list(rule_args), list(rule_args.values())
        n = model.n_x
        self.rule: SigmaPointRule = rule_of(n)
        self.f, self.h = transition(model), measurement(model)
        x, P = ca.SX.sym("x", n), ca.SX.sym("P", n, n)
        L, ok = guarded_cholesky(symmetrise(P))
        self.points = leaf(f"{prefix}_points", [x, P, *self.rule_args], [self.rule.points(x, L), L, ok],
                           ["x", "P", *self.rule_names], ["X", "L", "ok"])
        groups_m, groups_c = weight_groups(self.rule.wm), weight_groups(self.rule.wc)
        self.ranges = [(ks[0], ks[-1] + 1) for _, ks in groups_m]
        if [list(range(a, b)) for a, b in self.ranges] != [ks for _, ks in groups_m] or \
                [ks for _, ks in groups_c] != [ks for _, ks in groups_m]:
            raise ValueError(f"{prefix}: the weights of a rule must come in the same contiguous groups for mean and "
                             "covariance")
        self.weights = leaf(f"{prefix}_weights", self.rule_args,
                            [ca.vertcat(*[w for w, _ in groups_m]), ca.vertcat(*[w for w, _ in groups_c])],
                            self.rule_names, ["wm", "wc"])
        y, mean = ca.SX.sym("y", n), ca.SX.sym("mean", n)
        d = y - mean
        self.outer = leaf(f"{prefix}_outer", [y, mean], [weighted_outer(d, (1,))], ["y", "mean"], ["ddT"])
        C, Q = ca.SX.sym("C", n, n), ca.SX.sym("Q", n, n)
        P_pred = upper_mirrored(C + symmetrise(Q))
        self.predicted = leaf(f"{prefix}_predicted", [x, C, Q], [P_pred, all_finite(x, P_pred)],
                              ["x_pred", "C", "Q"], ["P_pred", "ok"])
        self.measurement_moments = self._measurement_moments_leaf()
        self.noise = self.noise_leaf(f"{prefix}_noise", measurement_noise=None)
        self.kalman = self._kalman_leaf()

    def _measurement_moments_leaf(self) -> ca.Function:
        """innovation, Pzz (without R) and Pxz of the points' measurements Z, masked (measurement.py).

        z_pred and Pzz = sum_k wc_k dz_k dz_k^T (grouped weights); Pxz = L (Xi diag(wc) DZ^T): the
        points' offsets are L xi_k, and L enters by its lower triangle.
        """
        model, rule = self.model, self.rule
        n, m, k = model.n_x, model.n_y, rule.n_points
        L, Z, z, mask = ca.SX.sym("L", n, n), ca.SX.sym("Z", m, k), ca.SX.sym("z", m), ca.SX.sym("mask", m)
        z_pred = weighted_sum(Z, rule.wm)
        DZ = ca.horzcat(*[residual(Z[:, j], z_pred, model.angle_outputs) for j in range(k)])
        Pzz = masked_covariance(weighted_outer(DZ, rule.wc), mask, fill_identity=False)  # identity comes with R
        weighted_xi = ca.horzcat(*[rule.xi[:, j] * rule.wc[j] for j in range(k)])  # one entry per column
        Pxz = masked_columns(ca.mtimes(ca.tril(L), ca.mtimes(weighted_xi, DZ.T)), mask)
        innovation = masked_innovation(z, z_pred, mask, model.angle_outputs)
        return leaf(f"{self.prefix}_moments", [L, Z, z, mask, *self.rule_args], [innovation, Pzz, Pxz],
                    ["L", "Z", "z", "mask", *self.rule_names], ["innovation", "Pzz", "Pxz"])

    def noise_leaf(self, name: str, measurement_noise, extra_args=(), extra_names=()) -> ca.Function:
        """R_used: sym(R) masked (identity on unused entries), or measurement_noise(a, Pzz, innovation) -> R~
        (robust.py; a is the guarded Cholesky factor of the masked R); ok is that factor's guard."""
        m = self.model.n_y
        R, mask, Pzz, innovation = ca.SX.sym("R", m, m), ca.SX.sym("mask", m), ca.SX.sym("Pzz", m, m), ca.SX.sym("nu", m)
        R_used, ok = masked_covariance(symmetrise(R), mask), ca.SX(1)
        if measurement_noise is not None:
            a, ok = guarded_cholesky(R_used)
            R_used = measurement_noise(a, upper_mirrored(Pzz), innovation)
        return leaf(name, [R, mask, Pzz, innovation, *extra_args], [R_used, ok],
                    ["R", "mask", "Pzz", "innovation", *extra_names], ["R_used", "ok"])

    def _kalman_leaf(self) -> ca.Function:
        """x + K nu and P - K S K^T with S = Pzz + R_used (measurement.gain_update), and finiteness."""
        n, m = self.model.n_x, self.model.n_y
        x, P, Pzz, Pxz = ca.SX.sym("x", n), ca.SX.sym("P", n, n), ca.SX.sym("Pzz", m, m), ca.SX.sym("Pxz", n, m)
        R_used, innovation = ca.SX.sym("R_used", m, m), ca.SX.sym("nu", m)
        S = upper_mirrored(Pzz + R_used)
        x_post, P_post, _, ok = gain_update(x, symmetrise(P), Pxz, S, innovation)
        return leaf(f"{self.prefix}_kalman", [x, P, Pzz, Pxz, R_used, innovation],
                    [x_post, P_post, S, ok * all_finite(x_post, P_post, innovation, S)],
                    ["x", "P", "Pzz", "Pxz", "R_used", "innovation"], ["x_post", "P_post", "S", "ok"])

    # ------------------------------------------------------------------ sums over points (MX)
    def _group_weights(self, rule: list[ca.MX]) -> tuple[ca.MX, ca.MX]:
        """(wm, wc) per group: constants for a rule without runtime arguments (the cubature rule)."""
        if rule:
            return self.weights(*rule)
        constant = self.weights()
        return ca.MX(constant["wm"]), ca.MX(constant["wc"])

    def _mean(self, w: ca.MX, Y: ca.MX) -> ca.MX:
        """sum_g w_g sum_{k in g} Y[:, k]."""
        terms = [w[g] * ca.sum2(Y[:, a:b] if b - a < Y.size2() else Y) for g, (a, b) in enumerate(self.ranges)]
        return sum(terms[1:], terms[0])

    def _weighted_terms(self, w: ca.MX, term: ca.Function, columns, shared) -> list[ca.MX]:
        """sum_g w_g sum_{k in g} term(columns[:, k]..., shared...) per output of term, as loops."""
        n_cols = len(columns)
        totals = None
        for g, (a, b) in enumerate(self.ranges):
            summed = term.map(f"{term.name()}_sum_{a}_{b}", "serial", b - a,
                              list(range(n_cols, n_cols + len(shared))), list(range(term.n_out())))
            parts = summed(*[C[:, a:b] if b - a < C.size2() else C for C in columns], *shared)
            parts = [parts] if isinstance(parts, ca.MX) else list(parts)
            scaled = [w[g] * part for part in parts]
            totals = scaled if totals is None else [t + s for t, s in zip(totals, scaled)]
        return totals

    # ------------------------------------------------------------------ exported steps
    def _inputs(self, names, extra_args=(), extra_names=()):
        extra = {name: arg.shape for name, arg in zip(self.rule_names + list(extra_names), self.rule_args + list(extra_args))}
        inputs = step_inputs(self.model, names, extra)
        return inputs, [inputs[name] for name in self.rule_names], [inputs[name] for name in extra_names]

    def predict_function(self, name: str) -> ca.Function:
        """(x, P, u, p, dt, Q, *rule_args) -> (x_pred, P_pred, ok): points, f per point, moments."""
        s, rule, _ = self._inputs(PREDICT_IN)
        X, _, ok_points = self.points(s["x"], s["P"], *rule)
        Y = call_columns(self.f, X, s["u"], s["p"], s["dt"])
        wm, wc = self._group_weights(rule)
        x_pred = self._mean(wm, Y)
        C, = self._weighted_terms(wc, self.outer, [Y], [x_pred])
        P_pred, ok_moments = self.predicted(x_pred, C, s["Q"])
        return exported(name, s, {"x_pred": x_pred, "P_pred": P_pred, "ok": ok_points * ok_moments})

    def update_function(self, name: str, noise: ca.Function | None = None, extra_args=(), extra_names=()) -> ca.Function:
        """(x, P, z, p, R, mask, *rule_args, *extra) -> (x_post, P_post, innovation, S, ok).

        Points redrawn from the given (predicted) x and P, h per point, their moments, the noise used
        (`noise`, a noise_leaf; default self.noise: R itself), the Kalman gain.
        """
        s, rule, extra = self._inputs(UPDATE_IN, extra_args, extra_names)
        X, L, ok_points = self.points(s["x"], s["P"], *rule)
        Z = call_columns(self.h, X, s["p"])
        innovation, Pzz, Pxz = self.measurement_moments(L, Z, s["z"], s["mask"], *rule)
        R_used, ok_noise = (noise or self.noise)(s["R"], s["mask"], Pzz, innovation, *extra)
        x_post, P_post, S, ok = self.kalman(s["x"], s["P"], Pzz, Pxz, R_used, innovation)
        return exported(name, s, {"x_post": x_post, "P_post": P_post, "innovation": innovation, "S": S,
                                  "ok": ok_points * ok_noise * ok})


def fused_step(name: str, model: Model, predict: ca.Function, update: ca.Function) -> ca.Function:
    """(x, P, u, p, dt, Q, z, R, mask) -> update(predict(...)): one C call per step, calling both."""
    s = step_inputs(model, STEP_IN)
    x_pred, P_pred, ok_pred = predict(s["x"], s["P"], s["u"], s["p"], s["dt"], s["Q"])
    x_post, P_post, innovation, S, ok_update = update(x_pred, P_pred, s["z"], s["p"], s["R"], s["mask"])
    return exported(name, s, {"x_post": x_post, "P_post": P_post, "innovation": innovation, "S": S,
                              "ok": ok_pred * ok_update})


def ckf_functions(model: Model) -> tuple[ca.Function, ...]:
    """<m>_ckf_predict, <m>_ckf_update and the fused <m>_ckf_step (one C file)."""
    m = model.name
    family = SigmaPointFamily(model, f"{m}_ckf", cubature_rule, {})
    predict = family.predict_function(f"{m}_ckf_predict")
    update = family.update_function(f"{m}_ckf_update")
    return predict, update, fused_step(f"{m}_ckf_step", model, predict, update)


def unscented_family(model: Model) -> SigmaPointFamily:
    """The scaled unscented rule with alpha, beta, kappa = abk at run time."""
    abk = ca.SX.sym("abk", 3)
    return SigmaPointFamily(model, f"{model.name}_ukf", lambda n: scaled_unscented_rule(n, abk[0], abk[1], abk[2]),
                            {"abk": abk})


def ukf_functions(model: Model, family: SigmaPointFamily | None = None) -> tuple[ca.Function, ...]:
    """<m>_ukf_predict and <m>_ukf_update (`family`: the unscented leaves, shared with the robust updates)."""
    m = model.name
    family = family or unscented_family(model)
    return family.predict_function(f"{m}_ukf_predict"), family.update_function(f"{m}_ukf_update")
