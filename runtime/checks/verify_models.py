"""Model checks of `abyssal verify`: each generated model function against numerics it was not
produced by.

For a bundle, ``checks(bundle)`` returns, per generated model function (f, F, G, h, H, and xdot or
x_next):

    compiled C vs CasADi        the committed C, compiled, against CasADi's own evaluation of the
                                same symbolic Function (catches codegen, compiler and loader faults)
    vs NumPy model              xdot, h and f against the independent NumPy model
                                (runtime/checks/reference_models.py; catches equation errors)
    vs central differences      F, G, H against central differences of the NumPy step/measurement
    vs solve_ivp (DOP853)       one f step against a tight adaptive integration of the NumPy RHS,
                                and the order of the scheme from the error ratio when halving dt
                                (a model whose held-input flow the scheme integrates exactly is
                                checked for exactness instead)
    batch vs one-at-a-time      f_batch / h_batch (SIMD kernels) and the `_batch` entry point
                                against single calls of f and h, with shared and per-column inputs

A model without a NumPy twin (a user's model) gets the same families against its own compiled
functions, by computations other than the AD that produced them:

    vs central differences      F of the compiled f; G of the Euler/RK4 step of the compiled xdot
                                (or of the compiled x_next) in w; H of the compiled h
    vs {rk4,euler} of xdot      f against the scheme applied to the compiled xdot (continuous only)
    vs solve_ivp (DOP853)       one step and the order by halving dt, on the compiled xdot; a model
                                whose flow the scheme integrates exactly shows exactness instead

A discrete model (x_next given directly) has nothing to integrate: its solve_ivp checks are
reported as skipped, with that reason. Anything else that cannot run (no Model to evaluate
in CasADi, say) is reported as skipped with its reason.

Errors are relative in the max-norm: max|a - b| / max|b|, worst case over the sampled points.
Filter functions are verified by verify_filters; names this module does not know are skipped.
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy.integrate import solve_ivp

from . import reference_models
from ..numerics import relative_error
from .verify import Check

MODEL_FUNCTIONS = ("f", "F", "G", "h", "H", "xdot", "x_next")
N_POINTS = 24           # random points per comparison
N_BATCH = 257           # columns of the batch checks (odd: exercises SIMD remainders)
SEED = 20240611

TOL_C_VS_CASADI = 1e-12     # same SX graph; only rounding (FMA contraction, operation order) differs
TOL_VS_NUMPY = 1e-12        # same equations, independently written
TOL_JACOBIAN = 1e-6         # central differences: truncation ~h^2, rounding ~eps/h
TOL_ONE_STEP = 1e-6         # local error of one RK4 step is O(dt^5): ~3e-8 relative for rov4dof at dt = 0.1 s
TOL_EXACT_FLOW = 1e-11      # discretisation that must be exact, vs DOP853 at rtol = atol = 1e-13
TOL_BATCH_SIMD = 1e-15      # libmvec's vector sin/cos may differ from scalar libm in the last bit
TOL_SAME_SCHEME = 1e-12     # f vs the same scheme applied to the compiled xdot: only rounding differs
ORDER_DT = 0.1              # realistic filter step [s]
ORDER_HORIZON = 2.0         # global error over this horizon scales as dt^order
SCHEME_ORDER = {"euler": 1, "rk4": 4}  # halving dt divides the global error by 2^order (16 for RK4)
ORDER_SLACK = 0.25          # accepted ratio: 2^order * [0.75, 1.25], i.e. [12, 20] for RK4


def symbolic_functions(name_or_model) -> dict:
    """Suffix -> the CasADi Function the C was generated from, e.g. {"f": rov4dof_f, ...}.

    Takes a built-in model name (empty when it is not registered) or a Model.
    """
    from abyssal.symbolic import codegen
    from abyssal.symbolic.models import REGISTRY

    if isinstance(name_or_model, str):
        if name_or_model not in REGISTRY:
            return {}
        model = REGISTRY[name_or_model]()
    else:
        model = name_or_model
    return {fn.name()[len(model.name) + 1:]: fn for fn in (*codegen.model_functions(model), *model.functions)}


class _Points:
    """Random arguments of a model's functions, in the manifest's shapes."""

    def __init__(self, bundle, ref, rng: np.random.Generator):
        self.bundle, self.ref, self.rng = bundle, ref, rng

    def state(self):
        if self.ref:
            return self.ref.sample_state(self.rng)
        return self.rng.normal(size=self.bundle.n_x)

    def inputs(self):
        if self.ref:
            return self.ref.sample_input(self.rng)
        return self.rng.normal(size=self.bundle.n_u)

    def params(self):
        """Defaults perturbed by up to 10 %: parameters are runtime inputs and must be honoured."""
        p = self.bundle.params()
        return p * self.rng.uniform(0.9, 1.1, p.shape)

    def args(self, fn) -> list[np.ndarray]:
        values = {"x": self.state, "u": self.inputs, "p": self.params,
                  "w": lambda: self.rng.normal(size=self.bundle.n_w),
                  "dt": lambda: np.array([self.rng.uniform(0.01, 0.5)])}
        # a Model's further functions (Model.functions) take inputs of any name: standard normal entries
        return [values[s.name]() if s.name in values else self.rng.normal(size=s.shape).reshape(-1, order="F")
                for s in fn.inputs]


def _c_vs_casadi(bundle, symbolic: dict, points: _Points) -> list[Check]:
    out = []
    further = [suffix for suffix in symbolic if suffix not in MODEL_FUNCTIONS and suffix in bundle.functions]
    for suffix in (*MODEL_FUNCTIONS, *further):
        if suffix not in bundle.functions or suffix not in symbolic:
            continue
        compiled, reference = bundle.functions[suffix], symbolic[suffix]
        worst = 0.0
        for _ in range(N_POINTS):
            args = points.args(compiled)
            expected = reference(*args)
            expected = [expected] if compiled.external.n_out() == 1 else list(expected)
            got = compiled(*args)
            got = [got] if compiled.external.n_out() == 1 else list(got)
            for g, e, sig in zip(got, expected, compiled.outputs):
                worst = max(worst, relative_error(np.asarray(g).reshape(sig.shape, order="F"),
                                                  np.array(e.full()).reshape(sig.shape, order="F")))
        out.append(Check(bundle.name, f"{suffix}: compiled C vs CasADi", "CasADi SX evaluation", worst,
                         TOL_C_VS_CASADI, f"{N_POINTS} random points"))
    return out


def _vs_numpy(bundle, ref, points: _Points) -> list[Check]:
    disc, substeps = bundle.manifest["discretisation"], bundle.manifest["substeps"]
    worst = {"xdot": 0.0, "h": 0.0, "f": 0.0}
    for _ in range(N_POINTS):
        x, u, p = points.state(), points.inputs(), points.params()
        w = points.rng.normal(size=bundle.n_w)
        dt = points.rng.uniform(0.01, 0.5)
        worst["xdot"] = max(worst["xdot"], relative_error(bundle.xdot(x, u, p, w), ref.xdot(x, u, p, w)))
        worst["h"] = max(worst["h"], relative_error(bundle.h(x, p), ref.h(x, p)))
        worst["f"] = max(worst["f"], relative_error(bundle.f(x, u, p, dt), reference_models.step(ref, x, u, p, dt, disc, substeps)))
    label = {"xdot": "NumPy model", "h": "NumPy model", "f": f"NumPy {disc} step"}
    return [Check(bundle.name, f"{k} vs {label[k]}", "reference_models (independent NumPy)", v, TOL_VS_NUMPY,
                  f"{N_POINTS} random points") for k, v in worst.items()]


def central_difference(fun, z: np.ndarray, rel_step: float = 1e-5) -> np.ndarray:
    """d fun / d z by central differences, step rel_step * max(1, |z_i|) per coordinate."""
    z = np.asarray(z, dtype=float)
    columns = []
    for i in range(z.size):
        h = rel_step * max(1.0, abs(z[i]))
        zp, zm = z.copy(), z.copy()
        zp[i] += h
        zm[i] -= h
        columns.append((fun(zp) - fun(zm)) / (zp[i] - zm[i]))
    return np.stack(columns, axis=-1)


def _jacobians(bundle, ref, points: _Points) -> list[Check]:
    """F, G, H against central differences of the NumPy twin's step and measurement."""
    disc, substeps = bundle.manifest["discretisation"], bundle.manifest["substeps"]
    step = lambda x, u, p, dt, w=None: reference_models.step(ref, x, u, p, dt, disc, substeps, w=w)  # noqa: E731
    what = {"F": "NumPy step in x", "G": "NumPy step in w", "H": "NumPy measurement"}
    return _central_differences(bundle, points, step, step, ref.h, what, "central differences of reference_models")


def _central_differences(bundle, points: _Points, step_x, step_w, measure, what: dict, reference: str) -> list[Check]:
    """F = d step_x / dx, G = d step_w / dw at w = 0, H = d measure / dx, by central differences."""
    worst = {"F": 0.0, "G": 0.0, "H": 0.0}
    for _ in range(N_POINTS):
        x, u, p = points.state(), points.inputs(), points.params()
        dt = points.rng.uniform(0.01, 0.5)
        F_num = central_difference(lambda z: step_x(z, u, p, dt), x)
        worst["F"] = max(worst["F"], relative_error(bundle.F(x, u, p, dt), F_num))
        if "G" in bundle.functions and bundle.n_w:
            G_num = central_difference(lambda z: step_w(x, u, p, dt, w=z), np.zeros(bundle.n_w))
            worst["G"] = max(worst["G"], relative_error(bundle.G(x, u, p, dt), G_num))
        H_num = central_difference(lambda z: measure(z, p), x)
        worst["H"] = max(worst["H"], relative_error(bundle.H(x, p), H_num))
    return [Check(bundle.name, f"{k} vs central differences ({what[k]})", reference,
                  v, TOL_JACOBIAN, f"{N_POINTS} random points, step 1e-5 relative")
            for k, v in worst.items() if k in bundle.functions]


def _integrate(ref, x0, u, p, horizon: float) -> np.ndarray:
    sol = solve_ivp(lambda t, z: ref.xdot(z, u, p), (0.0, horizon), x0, method="DOP853", rtol=1e-13, atol=1e-13)
    if not sol.success:
        raise RuntimeError(f"solve_ivp failed: {sol.message}")
    return sol.y[:, -1]


def _repeated_steps(bundle, x0, u, p, dt: float, horizon: float) -> np.ndarray:
    n = int(round(horizon / dt))
    out = np.empty(bundle.n_x)
    x = np.array(x0, dtype=float)
    step = bundle.functions["f"].bind([x, np.array(u, dtype=float), p, np.array([dt])], [out])
    for _ in range(n):
        step()
        x[:] = out
    return x


def _discretisation(bundle, ref, points: _Points) -> list[Check]:
    disc = bundle.manifest["discretisation"]
    x0, u = ref.cruise if ref.cruise is not None else (points.state(), points.inputs())
    p = bundle.params()
    one_step = relative_error(bundle.f(x0, u, p, ORDER_DT), _integrate(ref, x0, u, p, ORDER_DT))
    if ref.exact_flow:
        return [Check(bundle.name, f"f ({disc}) exact for held input vs solve_ivp", "scipy solve_ivp DOP853, rtol 1e-13",
                      one_step, TOL_EXACT_FLOW, f"dt = {ORDER_DT} s; flow polynomial of degree <= scheme order")]
    exact = _integrate(ref, x0, u, p, ORDER_HORIZON)
    coarse = relative_error(_repeated_steps(bundle, x0, u, p, ORDER_DT, ORDER_HORIZON), exact)
    fine = relative_error(_repeated_steps(bundle, x0, u, p, ORDER_DT / 2, ORDER_HORIZON), exact)
    ratio = coarse / fine if fine > 0 else float("inf")
    order = SCHEME_ORDER[disc]
    expected = 2.0 ** order
    return [
        Check(bundle.name, f"f ({disc}) one step vs solve_ivp", "scipy solve_ivp DOP853, rtol 1e-13", one_step,
              TOL_ONE_STEP, f"dt = {ORDER_DT} s on a cruise manoeuvre"),
        # The check's error is the distance of the ratio from 2^order.
        Check(bundle.name, f"f ({disc}) order {order}: |error ratio halving dt - {expected:g}|",
              f"scipy solve_ivp DOP853 (ratio {ratio:.2f})", abs(ratio - expected), ORDER_SLACK * expected,
              f"global error over {ORDER_HORIZON} s: {coarse:.3e} at dt = {ORDER_DT}, {fine:.3e} at dt = {ORDER_DT / 2}; "
              f"expected ratio in [{(1 - ORDER_SLACK) * expected:g}, {(1 + ORDER_SLACK) * expected:g}]"),
    ]


def _batches(bundle, ref, points: _Points) -> list[Check]:
    n = N_BATCH
    rng = points.rng
    if ref:
        X, U_cols = ref.sample_state(rng, n), ref.sample_input(rng, n)
    else:
        X, U_cols = rng.normal(size=(bundle.n_x, n)), rng.normal(size=(bundle.n_u, n))
    u_shared, p, dt = U_cols[:, 0].copy(), points.params(), 0.1
    one_at_a_time = {
        "shared": np.column_stack([bundle.f(X[:, j], u_shared, p, dt) for j in range(n)]),
        "per-column": np.column_stack([bundle.f(X[:, j], U_cols[:, j], p, dt) for j in range(n)]),
    }
    out = []
    for label, U in (("shared", u_shared), ("per-column", U_cols)):
        expected = one_at_a_time[label]
        simd = bundle.f_batch(X, U, p, dt)
        out.append(Check(bundle.name, f"f_batch (SIMD, U {label}) vs one-at-a-time f", "single f calls",
                         max(relative_error(simd[:, j], expected[:, j]) for j in range(n)), TOL_BATCH_SIMD,
                         f"N = {n}; libmvec sin/cos may differ in the last bit"))
        # the `_batch` entry point runs the same scalar C per slice: bitwise equal
        Y = np.zeros((bundle.n_x, n), order="F")
        U_buf = np.asfortranarray(U) if U.ndim == 2 else U
        bundle.functions["f"].bind_batch([np.asfortranarray(X), U_buf, p, np.array([dt])], [Y], capacity=n)(n)
        out.append(Check(bundle.name, f"f _batch entry (U {label}) vs one-at-a-time f", "single f calls",
                         float(np.max(np.abs(Y - expected))), 0.0, f"N = {n}; must be bitwise equal"))
    H_one = np.column_stack([bundle.h(X[:, j], p) for j in range(n)])
    out.append(Check(bundle.name, "h_batch (SIMD) vs one-at-a-time h", "single h calls",
                     max(relative_error(bundle.h_batch(X, p)[:, j], H_one[:, j]) for j in range(n)), TOL_BATCH_SIMD,
                     f"N = {n}"))
    return out


def compiled_twin(bundle) -> reference_models.ReferenceModel:
    """The bundle's own compiled xdot and h as a reference model (for a model without a NumPy twin)."""
    def xdot(x, u, p, w=None):
        return bundle.xdot(x, u, p, w)

    def sample(n_rows):
        return lambda rng, n=None: rng.normal(size=(n_rows, n) if n else n_rows)

    return reference_models.ReferenceModel(bundle.name, tuple(bundle.parameter_names), xdot, bundle.h,
                                           sample(bundle.n_x), sample(bundle.n_u))


def _compiled_checks(bundle, points: _Points) -> list[Check]:
    """The checks of a model without a NumPy twin, against its own compiled functions."""
    name = bundle.name
    if bundle.is_discrete:
        def x_next(x, u, p, dt, w=None):
            return bundle.x_next(x, u, p, w, dt)

        worst = 0.0
        for _ in range(N_POINTS):
            x, u, p, dt = points.state(), points.inputs(), points.params(), points.rng.uniform(0.01, 0.5)
            worst = max(worst, relative_error(bundle.f(x, u, p, dt), x_next(x, u, p, dt)))
        out = [Check(name, "f vs compiled x_next at w = 0", "compiled x_next", worst, TOL_SAME_SCHEME,
                     f"{N_POINTS} random points; two generated functions of the same step")]
        what = {"F": "compiled f in x", "G": "compiled x_next in w", "H": "compiled h"}
        out += _central_differences(bundle, points, lambda x, u, p, dt: bundle.f(x, u, p, dt), x_next, bundle.h,
                                    what, "central differences of the compiled functions")
        because = "the model is discrete (x_next given directly): there is no xdot to integrate"
        out += [Check.skip(name, "f one step vs solve_ivp", "scipy solve_ivp", because),
                Check.skip(name, "f order by halving dt", "scipy solve_ivp", because)]
        return out
    twin = compiled_twin(bundle)
    disc, substeps = bundle.manifest["discretisation"], bundle.manifest["substeps"]
    worst = 0.0
    for _ in range(N_POINTS):
        x, u, p, dt = points.state(), points.inputs(), points.params(), points.rng.uniform(0.01, 0.5)
        worst = max(worst, relative_error(bundle.f(x, u, p, dt), reference_models.step(twin, x, u, p, dt, disc, substeps)))
    out = [Check(name, f"f vs {disc} of compiled xdot", "NumPy scheme on the compiled xdot", worst, TOL_SAME_SCHEME,
                 f"{N_POINTS} random points")]
    step = lambda x, u, p, dt, w=None: reference_models.step(twin, x, u, p, dt, disc, substeps, w=w)  # noqa: E731
    what = {"F": "compiled f in x", "G": f"{disc} of compiled xdot in w", "H": "compiled h"}
    out += _central_differences(bundle, points, lambda x, u, p, dt: bundle.f(x, u, p, dt), step, bundle.h, what,
                                "central differences of the compiled functions")
    # Start the order check at rest with a random input: |v| v damping is then smooth along the
    # whole short horizon (velocities leave zero and keep their signs).
    start = (np.zeros(bundle.n_x), points.rng.normal(size=bundle.n_u))
    exact = _integrate(twin, *start, bundle.params(), ORDER_HORIZON)
    coarse = relative_error(_repeated_steps(bundle, *start, bundle.params(), ORDER_DT, ORDER_HORIZON), exact)
    twin = dataclasses.replace(twin, cruise=start, exact_flow=coarse <= TOL_EXACT_FLOW)
    return out + _discretisation(bundle, twin, points)


def _builtin_bundle(bundle) -> bool:
    from abyssal.generated import GENERATED_DIR

    folder = getattr(bundle, "folder", None)
    return folder is None or folder == GENERATED_DIR / bundle.name


def checks(bundle, reference=None, symbolic=None, target=None) -> list[Check]:
    """All model checks of one bundle. `reference` and `symbolic` override the oracles (for tests);
    `target` (verify.Target) says which oracles exist for it (default: the built-in's, by name)."""
    builtin = target.builtin if target is not None else _builtin_bundle(bundle)
    if reference is None:
        reference = target.reference if target is not None else (
            reference_models.REFERENCES.get(bundle.name) if builtin else None)
    ref = reference
    missing = ""
    if symbolic is None:
        if target is not None:
            symbolic = symbolic_functions(target.model) if target.model is not None else {}
            missing = target.model_missing
        else:
            symbolic = symbolic_functions(bundle.name) if builtin else {}
            missing = "" if symbolic else f"no registered Model named {bundle.name!r}"
    points = _Points(bundle, ref, np.random.default_rng(SEED))
    if symbolic:
        out = _c_vs_casadi(bundle, symbolic, points)
    else:
        out = [Check.skip(bundle.name, "compiled C vs CasADi", "CasADi SX evaluation",
                          f"there is no Model to evaluate in CasADi: {missing}")]
    if ref is None:  # its own compiled functions stand in for the twin (a user's model has none)
        # every continuous built-in has a hand-written twin; ReferenceModel has no x_next yet, so a discrete
        # built-in (tan3dof) is checked like a user's model here, and against an independent arc formula in
        # verify_tan
        if builtin and not bundle.is_discrete:
            out.append(Check(bundle.name, "independent NumPy model", "reference_models", float("nan"), 0.0,
                             f"no NumPy model of {bundle.name!r} in runtime/checks/reference_models.py: add one"))
        out += _compiled_checks(bundle, points)
    else:
        if tuple(ref.parameter_names) != tuple(bundle.parameter_names):
            out.append(Check(bundle.name, "parameter order vs NumPy model", "reference_models", float("inf"), 0.0,
                             f"manifest {bundle.parameter_names} != reference {ref.parameter_names}"))
            return out
        out += _vs_numpy(bundle, ref, points)
        out += _jacobians(bundle, ref, points)
        out += _discretisation(bundle, ref, points)
    out += _batches(bundle, ref, points)
    return out
