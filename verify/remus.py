"""`abyssal verify` section for seed 004: the GP export (abyssal.symbolic.gp) against scikit-learn.

remus100 itself is covered by the generic model checks (abyssal.verify.models, with its NumPy twin in
reference_models). Here, on the remus100 bundle only:

* from_sklearn (CasADi evaluation, the data as constants) == GaussianProcessRegressor.predict(return_std=True),
  mean and std**2, for ConstantKernel * RBF (ARD and isotropic) + WhiteKernel with and without normalize_y, and
  RBF + WhiteKernel; points inside and outside the training data.
* mean_function / variance_function (the GP-UKF's: the data as run-time inputs, all sigma points at once, two
  GPs side by side, a regressor count that is not a multiple of the factor's block size) == scikit-learn.
* the same, generated C compiled once (through the compile cache), called with the data of two GPs trained on
  different data with different hyperparameters: both == scikit-learn, from the one library (a new training
  set needs no recompilation).

Errors: mean, max |a - b| / max |b|; variance, max |a - b| / b pointwise (relative), <= 1e-9.
"""
from __future__ import annotations

import importlib

import numpy as np

from .report import Check

TOLERANCE = 1e-9
SEED = 4


def _variants():
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

    return {
        "C*RBF(ARD)+White, normalize_y": (ConstantKernel(1.0) * RBF(np.ones(4)) + WhiteKernel(1e-2), True),
        "C*RBF(iso)+White": (ConstantKernel(1.0) * RBF(1.0) + WhiteKernel(1e-2), False),
        "C*RBF(iso)+White, normalize_y": (ConstantKernel(1.0) * RBF(1.0) + WhiteKernel(1e-2), True),
        "RBF(ARD)+White": (RBF(np.ones(4)) + WhiteKernel(1e-2), False),
    }


def _data(rng, n: int = 60):
    X = rng.uniform(-2, 2, (n, 4))
    y = np.sin(X[:, 0]) * X[:, 1] + 0.3 * X[:, 2] ** 2 + 0.05 * rng.normal(size=n) + 5.0
    test = np.vstack([rng.uniform(-3, 3, (30, 4)), X[:5], rng.uniform(-8, 8, (5, 4))])
    return X, y, test


def _errors(mean, var, m_ref, v_ref) -> tuple[float, float]:
    e_mean = float(np.max(np.abs(mean - m_ref)) / np.max(np.abs(m_ref)))
    e_var = float(np.max(np.abs(var - v_ref) / v_ref))
    return e_mean, e_var


def _fit(kernel, normalize, X, y):
    import warnings

    from sklearn.gaussian_process import GaussianProcessRegressor

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return GaussianProcessRegressor(kernel, normalize_y=normalize, random_state=0).fit(X, y)


def _runtime_data_checks(gprs, test, evaluate, what: str) -> list[Check]:
    """evaluate(layout, data) -> (means (k, m), variances (m, k)) at the test points; compared with each GP."""
    from abyssal.symbolic import gp

    layout, data = gp.gp_data(gprs, block=24)   # 60 regressors: blocks of 24, padded to 72
    means, variances = evaluate(layout, data)
    out = []
    for i, g in enumerate(gprs):
        m_ref, s_ref = g.predict(test, return_std=True)
        e_mean, e_var = _errors(means[i], variances[:, i], m_ref, s_ref**2)
        label = what if len(gprs) == 1 else f"{what}, GP {i + 1} of {len(gprs)}"
        out.append(Check("gp", f"{label} mean", "sklearn predict", e_mean, TOLERANCE,
                         f"{len(test)} points at once, data as inputs"))
        out.append(Check("gp", f"{label} variance", "sklearn predict(return_std)**2", e_var, TOLERANCE,
                         "pointwise relative; blocked triangular factor, padded regressors"))
    return out


def checks(bundle, target=None) -> list[Check]:
    if bundle.name != "remus100" or (target is not None and not getattr(target, "builtin", True)):
        return []  # once, with the built-in remus100
    import casadi as ca
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

    from abyssal.symbolic import gp

    rng = np.random.default_rng(SEED)
    X, y, test = _data(rng)
    out = []
    fitted = {label: _fit(kernel, normalize, X, y) for label, (kernel, normalize) in _variants().items()}
    for label, gpr in fitted.items():
        fn = gp.from_sklearn(gpr, "gp_check")
        m_ref, s_ref = gpr.predict(test, return_std=True)
        mean = np.array([float(fn(t)[0]) for t in test])
        var = np.array([float(fn(t)[1]) for t in test])
        e_mean, e_var = _errors(mean, var, m_ref, s_ref**2)
        out.append(Check("gp", f"from_sklearn mean, {label}", "sklearn predict", e_mean, TOLERANCE, f"{len(test)} points"))
        out.append(Check("gp", f"from_sklearn variance, {label}", "sklearn predict(return_std)**2", e_var, TOLERANCE,
                         "pointwise relative; includes the WhiteKernel noise"))

    # two GPs on other data, with other hyperparameters: the GP-UKF's functions, data passed at run time
    X2, y2, _ = _data(np.random.default_rng(SEED + 1))
    pair = [fitted["C*RBF(ARD)+White, normalize_y"],
            _fit(ConstantKernel(2.0) * RBF(np.full(4, 0.7)) + WhiteKernel(1e-3), True, X2, 3.0 * y2)]

    def casadi_evaluation(layout, data):
        means = np.asarray(gp.mean_function(layout, len(test))(test.T, *data))
        variance = gp.variance_function(layout)
        return means, np.array([np.asarray(variance(t, *data)).reshape(-1) for t in test])

    out += _runtime_data_checks(pair, test, casadi_evaluation, "run-time data (CasADi)")

    # the same as generated C, compiled once: each GP's data through the one library
    build = importlib.import_module("abyssal.generated.build")
    layout = gp.gp_data(pair[:1], block=24)[0]
    x, points = ca.MX.sym("x", layout.n_inputs), ca.MX.sym("X", layout.n_inputs, len(test))
    data = layout.symbols()
    fn = ca.Function("abyssal_gp_check", [points, x, *data],
                     [gp.mean_function(layout, len(test))(points, *data), gp.variance_function(layout)(x, *data)])
    library = build.build("abyssal_gp_check", {"abyssal_gp_check.c": gp.c_source([fn])}, symbols=("abyssal_gp_check",))
    compiled = ca.external("abyssal_gp_check", str(library))

    def compiled_evaluation(layout, data):
        means = np.asarray(compiled(test.T, test[0], *data)[0])
        variances = np.array([float(compiled(test.T, t, *data)[1]) for t in test])
        return means, variances.reshape(-1, 1)

    for i, g in enumerate(pair):
        out += _runtime_data_checks([g], test, compiled_evaluation, f"generated C (one library), training set {i + 1}")
    return out
