"""Sigma-point Kalman filters: UKF (scaled unscented rule, alpha/beta/kappa at run time) and CKF
(cubature rule). Additive noise: Q and R are runtime inputs.

    <m>_ckf_predict(x, P, u, p, dt, Q)         -> (x_pred, P_pred, ok)
    <m>_ckf_update(x, P, z, p, R, mask)        -> (x_post, P_post, innovation, S, ok)
    <m>_ukf_predict(x, P, u, p, dt, Q, abk)    -> (x_pred, P_pred, ok)
    <m>_ukf_update(x, P, z, p, R, mask, abk)   -> (x_post, P_post, innovation, S, ok)
    <m>_ckf_step(x, P, u, p, dt, Q, z, R, mask) -> (x_post, P_post, innovation, S, ok)
                                                  calls predict then update (one C call)
    <m>_ckf_predict_points(x, P)               -> (X, ok)           the points and weights of a predict, for
    <m>_ckf_predict_weights()                  -> (wm, wc)          the C runtime (runtime/c): it propagates
    <m>_ukf_predict_points(x, P, abk), <m>_ukf_predict_weights(abk)  X through <m>_f_soa and forms the moments

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
from .families import FUNCTIONS
from .linalg import (
    all_finite, guarded_cholesky, symmetrise, upper_mirrored, weight_groups, weighted_outer, weighted_sum,
)
from .measurement import gain_update, masked_columns, masked_covariance, masked_innovation, residual
from .sigma_points import SigmaPointRule, cubature_rule, scaled_unscented_rule

PREDICT_IN = ["x", "P", "u", "p", "dt", "Q"]
UPDATE_IN = ["x", "P", "z", "p", "R", "mask"]
PREDICT_OUT = ["x_pred", "P_pred", "ok"]
UPDATE_OUT = ["x_post", "P_post", "innovation", "S", "ok"]
#: fused predict + update (one C call per step for the runtime's step()); same outputs as an update
STEP_IN = PREDICT_IN + ["z", "R", "mask"]
#: a measurement of at most this many SX instructions (a selection of states, a range) is inlined at every
#: point of an update instead of called in a loop: the loop's copies would cost more than h (benchmarks/README.md)
INLINE_MEASUREMENT = 64
#: an update whose measurement is inlined (INLINE_MEASUREMENT) and whose residual products m (m + 1) / 2 per point,
#: times the points, are at most this many computes h at the points, their mean, the residuals and their weighted
#: outer products in one leaf (straight-line SX) instead of a loop of calls over the points, whose calls and copies
#: cost more than the few products (rov4dof: 240 products)
INLINE_RESIDUALS = 1000


def noise_leaf(model: Model, name: str, measurement_noise, extra_args=(), extra_names=()) -> ca.Function:
    """R_used: sym(R) masked (identity on unused entries), or measurement_noise(a, Pzz, innovation) -> R~
    (robust.py; a is the guarded Cholesky factor of the masked R); ok is that factor's guard."""
    m = model.n_y
    R, mask, Pzz, innovation = ca.SX.sym("R", m, m), ca.SX.sym("mask", m), ca.SX.sym("Pzz", m, m), ca.SX.sym("nu", m)
    R_used, ok = masked_covariance(symmetrise(R), mask), ca.SX(1)
    if measurement_noise is not None:
        a, ok = guarded_cholesky(R_used)
        R_used = measurement_noise(a, upper_mirrored(Pzz), innovation)
    return leaf(name, [R, mask, Pzz, innovation, *extra_args], [R_used, ok],
                ["R", "mask", "Pzz", "innovation", *extra_names], ["R_used", "ok"])


class SharedLeaves:
    """The leaves of a model that no sigma-point rule changes; one copy serves every family in a C file.

        <m>_step, <m>_measurement                        f and h (common.transition, common.measurement)
        <m>_cholesky(P) -> (L, ok)                       guarded Cholesky factor of sym(P) (linalg.py)
        <m>_outer(y, mean) -> (y - mean)(y - mean)^T     its upper triangle, summed over a weight group
        <m>_residual(z_k, z_pred) -> (dz, dz dz^T)       dz = z_k - z_pred (angles wrapped); dz dz^T summed
        <m>_predicted(x_pred, C, Q) -> (P_pred, ok)      P_pred = C (upper, mirrored) + sym(Q), finiteness
        <m>_noise(R, mask, Pzz, innovation) -> (R_used, ok)   sym(R) masked (robust.py: inflated)
        <m>_kalman(x, P, Pzz, Pxz, R_used, innovation) -> (x_post, P_post, S, ok)
    """

    def __init__(self, model: Model):
        m, n, n_y = model.name, model.n_x, model.n_y
        self.f, self.h = transition(model), measurement(model)
        P = ca.SX.sym("P", n, n)
        self.cholesky = leaf(f"{m}_cholesky", [P], list(guarded_cholesky(symmetrise(P))), ["P"], ["L", "ok"])
        y, mean = ca.SX.sym("y", n), ca.SX.sym("mean", n)
        # the upper triangle only (structurally sparse output): the loop sums n(n+1)/2 entries per point, not n^2
        self.outer = leaf(f"{m}_outer", [y, mean], [ca.triu(weighted_outer(y - mean, (1,)))], ["y", "mean"], ["ddT"],
                          dense=False)
        zk, z_pred = ca.SX.sym("z_k", n_y), ca.SX.sym("z_pred", n_y)
        dz = residual(zk, z_pred, model.angle_outputs)
        self.residual = leaf(f"{m}_residual", [zk, z_pred], [dz, weighted_outer(dz, (1,))], ["z_k", "z_pred"],
                             ["dz", "dzdzT"])
        x, C, Q = ca.SX.sym("x", n), ca.SX.sym("C", ca.Sparsity.upper(n)), ca.SX.sym("Q", n, n)
        P_pred = upper_mirrored(C + symmetrise(Q))
        self.predicted = leaf(f"{m}_predicted", [x, C, Q], [P_pred, all_finite(x, P_pred)],
                              ["x_pred", "C", "Q"], ["P_pred", "ok"])
        self.noise = noise_leaf(model, f"{m}_noise", measurement_noise=None)
        # x + K nu and P - K S K^T with S = Pzz + R_used (measurement.gain_update), and finiteness
        Pzz, Pxz = ca.SX.sym("Pzz", n_y, n_y), ca.SX.sym("Pxz", n, n_y)
        R_used, innovation = ca.SX.sym("R_used", n_y, n_y), ca.SX.sym("nu", n_y)
        S = upper_mirrored(Pzz + R_used)
        x_post, P_post, _, ok = gain_update(x, symmetrise(P), Pxz, S, innovation)
        self.kalman = leaf(f"{m}_kalman", [x, P, Pzz, Pxz, R_used, innovation],
                           [x_post, P_post, S, ok * all_finite(x_post, P_post, innovation, S)],
                           ["x", "P", "Pzz", "Pxz", "R_used", "innovation"], ["x_post", "P_post", "S", "ok"])


class SigmaPointFamily:
    """The leaves of one sigma-point rule for one model, and the steps built from them.

    rule_args: the runtime symbols the rule depends on, by name ({} for the cubature rule,
    {"abk": abk} for the scaled unscented rule); leaves and steps take them after their own
    inputs. Leaves (plain SX, emitted once per C file, see common.leaf):

        <prefix>_points(x, L, *rule_args) -> X             X = x + L xi_k
        <prefix>_measured_points(x, L, p, *rule_args) -> Z h at every point, inlined (a measurement of
                                                           at most INLINE_MEASUREMENT instructions;
                                                           a costlier h is called in a loop instead)
        <prefix>_measured_moments(x, L, p, *rule_args) -> (z_pred, DZ, Czz)   instead, when the residuals'
                                                           products are few (INLINE_RESIDUALS): h, the mean,
                                                           the residuals and sum_k wc_k dz_k dz_k^T in one leaf
        <prefix>_weights(*rule_args) -> (wm, wc)           one mean and one covariance weight per
                                                           group of points with equal weights
        <prefix>_moments(L, DZ, Czz, z_pred, z, mask, *rule_args) -> (innovation, Pzz, Pxz)   masked,
                                                           Pzz = Czz without R

    and the rule-independent SharedLeaves (`shared`, one per C file). A step is an MX graph
    over them: f or h in a loop over the points (Function.map), and the predicted covariance
    a loop over the points (map with a summed output), so the C holds each piece once whatever
    the number of points. Each weighted sum is w_g * (sum of the group's terms), the grouping of
    linalg._grouped_sum: one product per entry and group instead of one per point. The update's
    cross-covariance needs no loop over points: with the points' offsets L xi_k,
    Pxz = sum_k wc_k L xi_k dz_k^T = L (Xi diag(wc) DZ^T), and Xi has one entry per column.
    """

    def __init__(self, model: Model, prefix: str, rule_of, rule_args: dict[str, ca.SX],
                 shared: SharedLeaves | None = None):
        self.model, self.prefix = model, prefix
        self.shared = shared or SharedLeaves(model)
        self.rule_names, self.rule_args = list(rule_args), list(rule_args.values())
        n = model.n_x
        self.rule: SigmaPointRule = rule_of(n)
        x, L = ca.SX.sym("x", n), ca.SX.sym("L", n, n)
        X = self.rule.points(x, ca.tril(L))
        self.points = leaf(f"{prefix}_points", [x, L, *self.rule_args], [X], ["x", "L", *self.rule_names], ["X"])
        self.measured_points = self.measured_moments = None
        m, points = model.n_y, self.rule.n_points
        if self.shared.h.n_instructions() <= INLINE_MEASUREMENT:
            p = ca.SX.sym("p", model.n_p)
            h = ca.Function("h", [model.x, model.p], [model.y])  # inlined at each point
            Z = ca.horzcat(*[h(X[:, k], p) for k in range(points)])
            if m * (m + 1) // 2 * points <= INLINE_RESIDUALS:
                z_pred = weighted_sum(Z, self.rule.wm)
                DZ = ca.horzcat(*[residual(Z[:, k], z_pred, model.angle_outputs) for k in range(points)])
                self.measured_moments = leaf(f"{prefix}_measured_moments", [x, L, p, *self.rule_args],
                                             [z_pred, DZ, weighted_outer(DZ, self.rule.wc)],
                                             ["x", "L", "p", *self.rule_names], ["z_pred", "DZ", "Czz"])
            else:
                self.measured_points = leaf(f"{prefix}_measured_points", [x, L, p, *self.rule_args], [Z],
                                            ["x", "L", "p", *self.rule_names], ["Z"])
        groups_m, groups_c = weight_groups(self.rule.wm), weight_groups(self.rule.wc)
        self.ranges = [(ks[0], ks[-1] + 1) for _, ks in groups_m]
        if [list(range(a, b)) for a, b in self.ranges] != [ks for _, ks in groups_m] or \
                [ks for _, ks in groups_c] != [ks for _, ks in groups_m]:
            raise ValueError(f"{prefix}: the weights of a rule must come in the same contiguous groups for mean and "
                             "covariance")
        self.weights = leaf(f"{prefix}_weights", self.rule_args,
                            [ca.vertcat(*[w for w, _ in groups_m]), ca.vertcat(*[w for w, _ in groups_c])],
                            self.rule_names, ["wm", "wc"])
        self.measurement_moments = self._measurement_moments_leaf()

    def _measurement_moments_leaf(self) -> ca.Function:
        """innovation, Pzz (without R) and Pxz from the points' residuals DZ and Czz = sum_k wc_k dz_k dz_k^T,
        masked (measurement.py). Pxz = L (Xi diag(wc) DZ^T): the points' offsets are L xi_k, and L enters
        by its lower triangle."""
        model, rule = self.model, self.rule
        n, m, k = model.n_x, model.n_y, rule.n_points
        L, DZ, Czz = ca.SX.sym("L", n, n), ca.SX.sym("DZ", m, k), ca.SX.sym("Czz", m, m)
        z_pred, z, mask = ca.SX.sym("z_pred", m), ca.SX.sym("z", m), ca.SX.sym("mask", m)
        Pzz = masked_covariance(upper_mirrored(Czz), mask, fill_identity=False)  # identity comes with R
        weighted_xi = ca.horzcat(*[rule.xi[:, j] * rule.wc[j] for j in range(k)])  # one entry per column
        Pxz = masked_columns(ca.mtimes(ca.tril(L), ca.mtimes(weighted_xi, DZ.T)), mask)
        innovation = masked_innovation(z, z_pred, mask, model.angle_outputs)
        return leaf(f"{self.prefix}_moments", [L, DZ, Czz, z_pred, z, mask, *self.rule_args], [innovation, Pzz, Pxz],
                    ["L", "DZ", "Czz", "z_pred", "z", "mask", *self.rule_names], ["innovation", "Pzz", "Pxz"])

    # ------------------------------------------------------------------ sums over points (MX)
    def _group_weights(self, rule: list[ca.MX]) -> tuple[ca.MX, ca.MX]:
        """(wm, wc) per group: constants for a rule without runtime arguments (the cubature rule)."""
        if rule:
            return self.weights(*rule)
        constant = self.weights()
        return ca.MX(constant["wm"]), ca.MX(constant["wc"])

    def _group(self, M: ca.MX, g: int) -> ca.MX:
        """The columns (points) of weight group g of M (M itself when the group is every point)."""
        a, b = self.ranges[g]
        return M[:, a:b] if b - a < M.size2() else M

    def _mean(self, w: ca.MX, Y: ca.MX) -> ca.MX:
        """sum_g w_g sum_{k in g} Y[:, k]."""
        terms = [w[g] * ca.sum2(self._group(Y, g)) for g in range(len(self.ranges))]
        return sum(terms[1:], terms[0])

    def _looped(self, w: ca.MX, term: ca.Function, columns, shared, summed) -> list[ca.MX]:
        """term looped over the points (columns[j][:, k], then the shared inputs), one loop per weight group:
        the outputs in `summed` as sum_g w_g sum_{k in g} (map with a summed output), the others side by side."""
        n_cols, outputs = len(columns), [[] for _ in range(term.n_out())]
        for g, (a, b) in enumerate(self.ranges):
            looped = term.map(f"{term.name()}_{a}_{b}", "serial", b - a,
                              list(range(n_cols, n_cols + len(shared))), list(summed))
            parts = looped(*[self._group(C, g) for C in columns], *shared)
            for out, part in zip(outputs, [parts] if isinstance(parts, ca.MX) else parts):
                out.append(part)
        return [sum((w[g] * part for g, part in enumerate(out[1:], 1)), w[0] * out[0]) if k in summed
                else ca.horzcat(*out) for k, out in enumerate(outputs)]

    # ------------------------------------------------------------------ exported steps
    def _inputs(self, names, extra_args=(), extra_names=()):
        extra = {name: arg.shape for name, arg in zip(self.rule_names + list(extra_names), self.rule_args + list(extra_args))}
        inputs = step_inputs(self.model, names, extra)
        return inputs, [inputs[name] for name in self.rule_names], [inputs[name] for name in extra_names]

    def predict_function(self, name: str) -> ca.Function:
        """(x, P, u, p, dt, Q, *rule_args) -> (x_pred, P_pred, ok): points, f per point, moments."""
        s, rule, _ = self._inputs(PREDICT_IN)
        L, ok_points = self.shared.cholesky(s["P"])
        X = self.points(s["x"], L, *rule)
        Y = call_columns(self.shared.f, X, s["u"], s["p"], s["dt"])
        wm, wc = self._group_weights(rule)
        x_pred = self._mean(wm, Y)
        C, = self._looped(wc, self.shared.outer, [Y], [x_pred], summed=(0,))
        P_pred, ok_moments = self.shared.predicted(x_pred, C, s["Q"])
        return exported(name, s, {"x_pred": x_pred, "P_pred": P_pred, "ok": ok_points * ok_moments})

    def predict_points_function(self, name: str) -> ca.Function:
        """(x, P, *rule_args) -> (X, ok): the first half of the predict, the points as the rows of X
        (n_points, n_x). Column-major, point k's entry i is at X[k + i n_points]: the structure-of-arrays layout
        of the model's SIMD kernel <m>_f_soa with ld = n_points, so the C runtime propagates them in one call."""
        s, rule, _ = self._inputs(["x", "P"])
        L, ok = self.shared.cholesky(s["P"])
        return exported(name, s, {"X": self.points(s["x"], L, *rule).T, "ok": ok})

    def predict_weights_function(self, name: str) -> ca.Function:
        """(*rule_args) -> (wm, wc): the mean and covariance weight of each point, in the order of predict_points'
        rows (the C runtime forms the predicted moments of the propagated points with them, in loops over the
        points that the compiler vectorises)."""
        inputs = {name_: ca.MX.sym(name_, *arg.shape) for name_, arg in zip(self.rule_names, self.rule_args)}
        rule = ca.Function(f"{self.prefix}_point_weights", self.rule_args,
                           [ca.vertcat(*self.rule.wm), ca.vertcat(*self.rule.wc)], self.rule_names, ["wm", "wc"])
        wm, wc = rule(*inputs.values()) if inputs else (ca.MX(ca.DM(rule()["wm"])), ca.MX(ca.DM(rule()["wc"])))
        return exported(name, inputs, {"wm": wm, "wc": wc})

    def update_function(self, name: str, noise: ca.Function | None = None, extra_args=(), extra_names=()) -> ca.Function:
        """(x, P, z, p, R, mask, *rule_args, *extra) -> (x_post, P_post, innovation, S, ok).

        Points redrawn from the given (predicted) x and P, h per point, their moments, the noise used
        (`noise`, a noise_leaf; default: R itself), the Kalman gain.
        """
        s, rule, extra = self._inputs(UPDATE_IN, extra_args, extra_names)
        L, ok_points = self.shared.cholesky(s["P"])
        if self.measured_moments is not None:
            z_pred, DZ, Czz = self.measured_moments(s["x"], L, s["p"], *rule)
        else:
            if self.measured_points is not None:
                Z = self.measured_points(s["x"], L, s["p"], *rule)
            else:
                Z = call_columns(self.shared.h, self.points(s["x"], L, *rule), s["p"])
            wm, wc = self._group_weights(rule)
            z_pred = self._mean(wm, Z)
            DZ, Czz = self._looped(wc, self.shared.residual, [Z], [z_pred], summed=(1,))
        innovation, Pzz, Pxz = self.measurement_moments(L, DZ, Czz, z_pred, s["z"], s["mask"], *rule)
        R_used, ok_noise = (noise or self.shared.noise)(s["R"], s["mask"], Pzz, innovation, *extra)
        x_post, P_post, S, ok = self.shared.kalman(s["x"], s["P"], Pzz, Pxz, R_used, innovation)
        return exported(name, s, {"x_post": x_post, "P_post": P_post, "innovation": innovation, "S": S,
                                  "ok": ok_points * ok_noise * ok})


def fused_step(name: str, model: Model, predict: ca.Function, update: ca.Function) -> ca.Function:
    """(x, P, u, p, dt, Q, z, R, mask) -> update(predict(...)): one C call per step, calling both."""
    s = step_inputs(model, STEP_IN)
    x_pred, P_pred, ok_pred = predict(s["x"], s["P"], s["u"], s["p"], s["dt"], s["Q"])
    x_post, P_post, innovation, S, ok_update = update(x_pred, P_pred, s["z"], s["p"], s["R"], s["mask"])
    return exported(name, s, {"x_post": x_post, "P_post": P_post, "innovation": innovation, "S": S,
                              "ok": ok_pred * ok_update})


def ckf_functions(model: Model, shared: SharedLeaves | None = None) -> tuple[ca.Function, ...]:
    """<m>_ckf_predict, <m>_ckf_update and the fused <m>_ckf_step."""
    m = model.name
    family = SigmaPointFamily(model, f"{m}_ckf", cubature_rule, {}, shared)
    names = FUNCTIONS["ckf"]
    predict = family.predict_function(f"{m}_{names['predict']}")
    update = family.update_function(f"{m}_{names['update']}")
    return (predict, update, fused_step(f"{m}_{names['step']}", model, predict, update),
            family.predict_points_function(f"{m}_{names['predict_points']}"),
            family.predict_weights_function(f"{m}_{names['predict_weights']}"))


def unscented_family(model: Model, shared: SharedLeaves | None = None) -> SigmaPointFamily:
    """The scaled unscented rule with alpha, beta, kappa = abk at run time."""
    abk = ca.SX.sym("abk", 3)
    return SigmaPointFamily(model, f"{model.name}_ukf", lambda n: scaled_unscented_rule(n, abk[0], abk[1], abk[2]),
                            {"abk": abk}, shared)


def ukf_functions(model: Model, family: SigmaPointFamily | None = None) -> tuple[ca.Function, ...]:
    """<m>_ukf_predict and <m>_ukf_update (`family`: the unscented leaves, shared with the robust updates)."""
    m = model.name
    family = family or unscented_family(model)
    names = FUNCTIONS["ukf"]
    return (family.predict_function(f"{m}_{names['predict']}"), family.update_function(f"{m}_{names['update']}"),
            family.predict_points_function(f"{m}_{names['predict_points']}"),
            family.predict_weights_function(f"{m}_{names['predict_weights']}"))
