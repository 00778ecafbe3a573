"""`abyssal verify` section for seed 004: the GP export (abyssal.symbolic.gp) against scikit-learn.

remus100 itself is covered by the generic model checks (abyssal.verify.models, with its NumPy twin in
reference_models). Here, on the remus100 bundle only:

* from_sklearn (CasADi evaluation) == GaussianProcessRegressor.predict(return_std=True), mean and
  std**2, for ConstantKernel * RBF (ARD and isotropic) + WhiteKernel with and without
  normalize_y, and a bare RBF; points inside and outside the training data.
* gp_mean_batch_function (the GP-UKF's means of all sigma points at once) == scikit-learn.
* the same Function as generated C, compiled (through the compile cache), == scikit-learn.

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


def _data(rng):
    X = rng.uniform(-2, 2, (60, 4))
    y = np.sin(X[:, 0]) * X[:, 1] + 0.3 * X[:, 2] ** 2 + 0.05 * rng.normal(size=60) + 5.0
    test = np.vstack([rng.uniform(-3, 3, (30, 4)), X[:5], rng.uniform(-8, 8, (5, 4))])
    return X, y, test


def _errors(mean, var, m_ref, v_ref) -> tuple[float, float]:
    e_mean = float(np.max(np.abs(mean - m_ref)) / np.max(np.abs(m_ref)))
    e_var = float(np.max(np.abs(var - v_ref) / v_ref))
    return e_mean, e_var


def checks(bundle, target=None) -> list[Check]:
    if bundle.name != "remus100" or (target is not None and not getattr(target, "builtin", True)):
        return []  # once, with the built-in remus100
    import warnings

    import casadi as ca
    from sklearn.gaussian_process import GaussianProcessRegressor

    from abyssal.symbolic import gp

    rng = np.random.default_rng(SEED)
    X, y, test = _data(rng)
    out = []
    fitted = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for label, (kernel, normalize) in _variants().items():
            fitted[label] = GaussianProcessRegressor(kernel, normalize_y=normalize, random_state=0).fit(X, y)
    for label, gpr in fitted.items():
        fn = gp.from_sklearn(gpr, "gp_check")
        m_ref, s_ref = gpr.predict(test, return_std=True)
        mean = np.array([float(fn(t)[0]) for t in test])
        var = np.array([float(fn(t)[1]) for t in test])
        e_mean, e_var = _errors(mean, var, m_ref, s_ref**2)
        out.append(Check("gp", f"from_sklearn mean, {label}", "sklearn predict", e_mean, TOLERANCE, f"{len(test)} points"))
        out.append(Check("gp", f"from_sklearn variance, {label}", "sklearn predict(return_std)**2", e_var, TOLERANCE,
                         "pointwise relative; includes the WhiteKernel noise"))
    # the batched mean (what the GP-UKF predict uses): one matrix product for many points
    label = "C*RBF(ARD)+White, normalize_y"
    gpr = fitted[label]
    batch = gp.gp_mean_batch_function(gpr, len(test), "gp_check_batch")
    m_ref = gpr.predict(test)
    got = np.asarray(batch(test.T)).reshape(-1)
    out.append(Check("gp", f"batched mean (GP-UKF points), {label}", "sklearn predict",
                     float(np.max(np.abs(got - m_ref)) / np.max(np.abs(m_ref))), TOLERANCE, f"{len(test)} points at once"))
    # generated C, compiled
    build = importlib.import_module("abyssal.generated.build")
    label = "C*RBF(ARD)+White, normalize_y"
    gpr = fitted[label]
    fn = gp.from_sklearn(gpr, "abyssal_gp_check")
    cg = ca.CodeGenerator("abyssal_gp_check.c", {"with_header": False, "casadi_real": "double"})
    cg.add(fn)
    library = build.build("abyssal_gp_check", {"abyssal_gp_check.c": cg.dump()})
    compiled = ca.external("abyssal_gp_check", str(library))
    m_ref, s_ref = gpr.predict(test, return_std=True)
    mean = np.array([float(compiled(t)[0]) for t in test])
    var = np.array([float(compiled(t)[1]) for t in test])
    e_mean, e_var = _errors(mean, var, m_ref, s_ref**2)
    out.append(Check("gp", f"generated C mean, {label}", "sklearn predict", e_mean, TOLERANCE, "compiled from_sklearn"))
    out.append(Check("gp", f"generated C variance, {label}", "sklearn predict(return_std)**2", e_var, TOLERANCE,
                     "compiled from_sklearn"))
    return out
