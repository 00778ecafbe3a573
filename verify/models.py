"""Model checks of `abyssal verify`: each generated model function against numerics it was not
produced by.

For a bundle, ``checks(bundle)`` returns, per generated model function (f, F, G, h, H, and xdot or
x_next):

    compiled C vs CasADi        the committed C, compiled, against CasADi's own evaluation of the
                                same symbolic Function (catches codegen, compiler and loader faults)
    vs NumPy model              xdot, h and f against the independent NumPy model
                                (verify/reference_models.py; catches equation errors)
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

A model without a twin is sampled inside its operating envelope (Model(envelope=Envelope(...)),
recorded in the manifest): states and inputs uniformly in their nominal ranges, dt in [min_dt, max_dt].
A model that declares none is sampled in [-1, 1] and dt in [0.01, 0.5] s, and the report says so once.
A step that leaves 10x the envelope (about its centre) or gives a non-finite value is reported as
diverged, distinctly from a disagreement; every check names its worst point (x, u, p, dt), the
entry that differs most (e.g. F[3,7]) and both values (Check.worst, printed on FAIL lines).

A discrete model (x_next given directly) has nothing to integrate: its solve_ivp checks are
reported as skipped, with that reason. Anything else that cannot run (no Model to evaluate
in CasADi, say) is reported as skipped with its reason.

Errors are relative in the max-norm: max|a - b| / max|b|, worst case over the sampled points.
Filter functions are verified by abyssal.verify.filters; names this module does not know are skipped.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.integrate import solve_ivp

from abyssal.runtime.numerics import relative_error

from . import reference_models
from .report import Check

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
DIVERGED_FACTOR = 10.0      # a step leaving this many times the envelope (about its centre) has diverged
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


class SamplingBox:
    """The sampling box of a bundle: per state and input (low, high) arrays and the dt range, from the
    manifest's "envelope" (the defaults when the model declared none or the manifest predates envelopes)."""

    def __init__(self, bundle):
        from abyssal.symbolic.model import DEFAULT_MAX_DT, DEFAULT_MIN_DT, DEFAULT_RANGE

        record = getattr(bundle, "envelope", None) or {}
        self.declared = bool(record.get("declared", False))
        self.recorded = bool(record)
        default = tuple(record.get("default_range", DEFAULT_RANGE))
        states, inputs = record.get("states", {}), record.get("inputs", {})
        x = np.array([states.get(n, default) for n in bundle.state_names], dtype=float).reshape(-1, 2)
        u = np.array([inputs.get(n, default) for n in bundle.input_names], dtype=float).reshape(-1, 2)
        self.x_low, self.x_high = x[:, 0], x[:, 1]
        self.u_low, self.u_high = u[:, 0], u[:, 1]
        self.state_names = tuple(bundle.state_names)
        self.min_dt = float(record.get("min_dt", DEFAULT_MIN_DT))
        self.max_dt = float(record.get("max_dt", DEFAULT_MAX_DT))
        self.default = default

    def note(self) -> str:
        """What a report says once about a model sampled in the default box ("" when it declares one)."""
        if self.declared:
            return ""
        why = "no envelope declared" if self.recorded else "no envelope declared (none recorded in its manifest)"
        lo, hi = self.default
        return (f"{why}: states and inputs in [{lo:g}, {hi:g}], dt in [{self.min_dt:g}, {self.max_dt:g}] s; declare "
                "where the model is meant to be used with Model(..., envelope=Envelope(states=..., inputs=..., max_dt=...))")

    def clip_dt(self, dt: float) -> float:
        return min(max(dt, self.min_dt), self.max_dt)

    def escaped(self, x) -> str:
        """Why the state x (n_x,) or (n_x, N) is outside DIVERGED_FACTOR x the envelope ("" when it is not)."""
        x = np.asarray(x, dtype=float)
        centre, half = (self.x_low + self.x_high) / 2, (self.x_high - self.x_low) / 2
        far = np.abs(x - (centre if x.ndim == 1 else centre[:, None])) > DIVERGED_FACTOR * (half if x.ndim == 1 else half[:, None])
        if not far.any():
            return ""
        i = np.unravel_index(np.argmax(far), far.shape)[0]
        return (f"state {self.state_names[i]!r} left {DIVERGED_FACTOR:g}x its envelope "
                f"[{self.x_low[i]:g}, {self.x_high[i]:g}]")


class _Points:
    """Random arguments of a model's functions, in the manifest's shapes.

    With a NumPy twin: its plausible states and inputs, dt in [0.01, 0.5] s. Without one: uniform inside
    the model's envelope (states, inputs and dt).
    """

    def __init__(self, bundle, ref, rng: np.random.Generator):
        self.bundle, self.ref, self.rng = bundle, ref, rng
        self.envelope = SamplingBox(bundle)
        #: steps are checked against the envelope (divergence) for a model sampled inside it
        self.bounds = None if ref else self.envelope

    def state(self, n: int | None = None):
        if self.ref:
            return self.ref.sample_state(self.rng, n) if n else self.ref.sample_state(self.rng)
        env = self.envelope
        return self.rng.uniform(env.x_low, env.x_high) if n is None else self.rng.uniform(
            env.x_low[:, None], env.x_high[:, None], (self.bundle.n_x, n))

    def inputs(self, n: int | None = None):
        if self.ref:
            return self.ref.sample_input(self.rng, n) if n else self.ref.sample_input(self.rng)
        env = self.envelope
        return self.rng.uniform(env.u_low, env.u_high) if n is None else self.rng.uniform(
            env.u_low[:, None], env.u_high[:, None], (self.bundle.n_u, n))

    def dt(self) -> float:
        if self.ref:
            from abyssal.symbolic.model import DEFAULT_MAX_DT, DEFAULT_MIN_DT

            return self.rng.uniform(DEFAULT_MIN_DT, DEFAULT_MAX_DT)
        return self.rng.uniform(self.envelope.min_dt, self.envelope.max_dt)

    @property
    def order_dt(self) -> float:
        """The step of the order check: ORDER_DT, inside the envelope's dt range for a model without a twin."""
        return ORDER_DT if self.ref else self.envelope.clip_dt(ORDER_DT)

    def params(self):
        """Defaults perturbed by up to 10 %: parameters are runtime inputs and must be honoured."""
        p = self.bundle.params()
        return p * self.rng.uniform(0.9, 1.1, p.shape)

    def args(self, fn) -> list[np.ndarray]:
        values = {"x": self.state, "u": self.inputs, "p": self.params,
                  "w": lambda: self.rng.normal(size=self.bundle.n_w),
                  "dt": lambda: np.array([self.dt()])}
        # a Model's further functions (Model.functions) take inputs of any name: standard normal entries
        return [values[s.name]() if s.name in values else self.rng.normal(size=s.shape).reshape(-1, order="F")
                for s in fn.inputs]


def _vector(v) -> str:
    v = np.ravel(np.asarray(v, dtype=float))
    return "[" + ", ".join(f"{e:.4g}" for e in v) + "]"


def point_text(**values) -> str:
    """A point compactly: x=[1.2, -0.3], u=[...], p=[...], dt=0.31 (4 significant digits)."""
    return ", ".join(f"{k}={_vector(v) if np.size(v) != 1 or k not in ('dt',) and np.ndim(v) else f'{float(np.ravel(v)[0]):.4g}'}"
                     for k, v in values.items() if v is not None)


def _entry(output: str, shape, flat_index: int, column: int | None = None) -> str:
    """F[3,7] for a matrix entry, f[3] for a vector (a column or a row) entry; f_batch[3,76] for entry 3 of column 76."""
    idx = np.unravel_index(flat_index, shape) if shape else ()
    idx = tuple(int(i) for i, n in zip(idx, shape) if n != 1 or len(shape) == 1) or (0,)
    return f"{output}[{','.join(map(str, idx + ((column,) if column is not None else ())))}]"


class Worst:
    """The worst comparison of one check over its points: the error, the point, the entry, both values.

    ``compare(output, got, expected, point)`` per point, ``guard(...)`` for a step that must stay finite
    and inside the envelope; ``check(...)`` makes the Check, whose ``worst`` names where it happened.
    The first divergence (a non-finite value, or a step leaving DIVERGED_FACTOR x the envelope) wins
    over any disagreement: its error is inf and its text starts with "diverged at".
    """

    def __init__(self, metric=relative_error, what: str = "disagrees"):
        self.metric, self.what = metric, what
        self.error = 0.0
        self.text = ""
        self.diverged = ""

    def guard(self, output: str, values, point: dict, bounds: "SamplingBox | None" = None, column: int | None = None) -> bool:
        """True (and recorded) when `values` of `output` diverged at `point`."""
        if self.diverged:
            return True
        values = np.asarray(values, dtype=float)
        bad = ~np.isfinite(values)
        if bad.any():
            k = int(np.argmax(bad.ravel()))
            why = f"{_entry(output, values.shape, k, column)} = {float(values.ravel()[k])!r} (non-finite)"
        elif bounds is not None and (escaped := bounds.escaped(values)):
            why = f"{output} {escaped} (max |{output}| = {np.max(np.abs(values)):.3g})"
        else:
            return False
        self.diverged = f"diverged at {point_text(**point)}: {why}"
        self.error = math.inf
        return True

    def compare(self, output: str, got, expected, point: dict, bounds: "SamplingBox | None" = None,
                column: int | None = None) -> float:
        got, expected = np.asarray(got, dtype=float), np.asarray(expected, dtype=float)
        if (self.guard(output, got, point, bounds, column)
                or self.guard(output + " (reference)", expected, point, bounds, column)):
            return math.inf
        error = self.metric(got, expected)
        if error > self.error or not self.text:
            diff = np.abs(got - expected)
            k = int(np.argmax(diff.ravel())) if diff.size else 0
            entry = _entry(output, got.shape, k, column)
            values = f"{float(got.ravel()[k])!r} vs {float(expected.ravel()[k])!r}" if got.size else "(empty)"
            self.error, self.text = max(self.error, error), f"at {point_text(**point)}: {entry} = {values}"
        return error

    def check(self, model: str, name: str, reference: str, tolerance: float, detail: str = "") -> Check:
        if self.diverged:
            worst = self.diverged
        else:
            worst = (f"{self.what} {self.text}, error {self.error:.3g}, tolerance {tolerance:.0e}" if self.text else "")
        return Check(model, name, reference, self.error, tolerance, detail, worst=worst)


def _c_vs_casadi(bundle, symbolic: dict, points: _Points) -> list[Check]:
    out = []
    further = [suffix for suffix in symbolic if suffix not in MODEL_FUNCTIONS and suffix in bundle.functions]
    for suffix in (*MODEL_FUNCTIONS, *further):
        if suffix not in bundle.functions or suffix not in symbolic:
            continue
        compiled, reference = bundle.functions[suffix], symbolic[suffix]
        worst = Worst()
        single = compiled.external.n_out() == 1
        for _ in range(N_POINTS):
            args = points.args(compiled)
            point = {sig.name: a for sig, a in zip(compiled.inputs, args)}
            expected = reference(*args)
            expected = [expected] if single else list(expected)
            got = compiled(*args)
            got = [got] if single else list(got)
            if points.bounds is not None and suffix in ("F", "G") and {"x", "u", "p", "dt"} <= set(point):
                # a Jacobian of a diverged step is not a disagreement: the step itself first
                worst.guard("f", bundle.f(point["x"], point["u"], point["p"], float(np.ravel(point["dt"])[0])), point,
                            points.bounds)
            for g, e, sig in zip(got, expected, compiled.outputs):
                step = suffix in ("f", "x_next")  # a state after one step: checked against the envelope
                worst.compare(suffix if single else f"{suffix}.{sig.name}",
                              np.asarray(g).reshape(sig.shape, order="F"),
                              np.array(e.full()).reshape(sig.shape, order="F"), point,
                              points.bounds if step else None)
        out.append(worst.check(bundle.name, f"{suffix}: compiled C vs CasADi", "CasADi SX evaluation",
                               TOL_C_VS_CASADI, f"{N_POINTS} random points"))
    return out


def _vs_numpy(bundle, ref, points: _Points) -> list[Check]:
    disc, substeps = bundle.manifest["discretisation"], bundle.manifest["substeps"]
    worst = {"xdot": Worst(), "h": Worst(), "f": Worst()}
    for _ in range(N_POINTS):
        x, u, p = points.state(), points.inputs(), points.params()
        w = points.rng.normal(size=bundle.n_w)
        dt = points.dt()
        worst["xdot"].compare("xdot", bundle.xdot(x, u, p, w), ref.xdot(x, u, p, w), dict(x=x, u=u, p=p, w=w))
        worst["h"].compare("h", bundle.h(x, p), ref.h(x, p), dict(x=x, p=p))
        worst["f"].compare("f", bundle.f(x, u, p, dt), reference_models.step(ref, x, u, p, dt, disc, substeps),
                           dict(x=x, u=u, p=p, dt=dt), points.bounds)
    label = {"xdot": "NumPy model", "h": "NumPy model", "f": f"NumPy {disc} step"}
    return [v.check(bundle.name, f"{k} vs {label[k]}", "reference_models (independent NumPy)", TOL_VS_NUMPY,
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
    worst = {"F": Worst(what="derivative disagrees"), "G": Worst(what="derivative disagrees"),
             "H": Worst(what="derivative disagrees")}
    for _ in range(N_POINTS):
        x, u, p = points.state(), points.inputs(), points.params()
        dt = points.dt()
        point = dict(x=x, u=u, p=p, dt=dt)
        # the step itself first: a derivative of a diverged step is not a disagreement
        diverged = points.bounds is not None and worst["F"].guard("f", step_x(x, u, p, dt), point, points.bounds)
        if not diverged:
            F_num = central_difference(lambda z: step_x(z, u, p, dt), x)
            worst["F"].compare("F", bundle.F(x, u, p, dt), F_num, point)
        if "G" in bundle.functions and bundle.n_w:
            if not (diverged and worst["G"].guard("f", step_x(x, u, p, dt), point, points.bounds)):
                G_num = central_difference(lambda z: step_w(x, u, p, dt, w=z), np.zeros(bundle.n_w))
                worst["G"].compare("G", bundle.G(x, u, p, dt), G_num, point)
        H_num = central_difference(lambda z: measure(z, p), x)
        worst["H"].compare("H", bundle.H(x, p), H_num, dict(x=x, p=p))
    return [v.check(bundle.name, f"{k} vs central differences ({what[k]})", reference,
                    TOL_JACOBIAN, f"{N_POINTS} random points, step 1e-5 relative")
            for k, v in worst.items() if k in bundle.functions]


def _integrate(ref, x0, u, p, horizon: float) -> np.ndarray:
    sol = solve_ivp(lambda t, z: ref.xdot(z, u, p), (0.0, horizon), x0, method="DOP853", rtol=1e-13, atol=1e-13)
    if not sol.success:
        raise RuntimeError(f"solve_ivp failed: {sol.message}")
    return sol.y[:, -1]


def _input_inside(twin, points: _Points, x0, p, halvings: int = 12) -> np.ndarray:
    """A random input in the envelope, halved until the held-input flow from x0 stays inside the
    envelope's states over ORDER_HORIZON (a vehicle at full thrust for seconds rolls over, beyond the
    ranges where its kinematics are regular: the order check would then judge the singularity)."""
    env = points.envelope
    u = points.inputs()
    for _ in range(halvings):
        sol = solve_ivp(lambda t, z: twin.xdot(z, u, p), (0.0, ORDER_HORIZON), x0, method="DOP853", rtol=1e-8, atol=1e-10)
        if sol.success and np.all(np.isfinite(sol.y)) and np.all(sol.y >= env.x_low[:, None]) \
                and np.all(sol.y <= env.x_high[:, None]):
            return u
        u = u / 2
    return u


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
    dt = points.order_dt
    start = dict(x=x0, u=u, p=p, dt=dt)
    one = Worst()
    one.compare("f", bundle.f(x0, u, p, dt), _integrate(ref, x0, u, p, dt), start, points.bounds)
    if ref.exact_flow:
        return [one.check(bundle.name, f"f ({disc}) exact for held input vs solve_ivp", "scipy solve_ivp DOP853, rtol 1e-13",
                          TOL_EXACT_FLOW, f"dt = {dt:g} s; flow polynomial of degree <= scheme order")]
    exact = _integrate(ref, x0, u, p, ORDER_HORIZON)
    coarse = relative_error(_repeated_steps(bundle, x0, u, p, dt, ORDER_HORIZON), exact)
    fine = relative_error(_repeated_steps(bundle, x0, u, p, dt / 2, ORDER_HORIZON), exact)
    ratio = coarse / fine if fine > 0 else float("inf")
    order = SCHEME_ORDER[disc]
    expected = 2.0 ** order
    return [
        one.check(bundle.name, f"f ({disc}) one step vs solve_ivp", "scipy solve_ivp DOP853, rtol 1e-13",
                  TOL_ONE_STEP, f"dt = {dt:g} s on a cruise manoeuvre"),
        # The check's error is the distance of the ratio from 2^order.
        Check(bundle.name, f"f ({disc}) order {order}: |error ratio halving dt - {expected:g}|",
              f"scipy solve_ivp DOP853 (ratio {ratio:.2f})", abs(ratio - expected), ORDER_SLACK * expected,
              f"global error over {ORDER_HORIZON} s: {coarse:.3e} at dt = {dt:g}, {fine:.3e} at dt = {dt / 2:g}; "
              f"expected ratio in [{(1 - ORDER_SLACK) * expected:g}, {(1 + ORDER_SLACK) * expected:g}]",
              worst=f"from {point_text(**start)} over {ORDER_HORIZON:g} s: error ratio {ratio:.4g}, expected "
                    f"{expected:g} +- {ORDER_SLACK * expected:g}"),
    ]


def _batches(bundle, ref, points: _Points) -> list[Check]:
    n = N_BATCH
    X, U_cols = points.state(n), points.inputs(n)
    u_shared, p = U_cols[:, 0].copy(), points.params()
    dt = 0.1 if ref else points.envelope.clip_dt(0.1)
    one_at_a_time = {
        "shared": np.column_stack([bundle.f(X[:, j], u_shared, p, dt) for j in range(n)]),
        "per-column": np.column_stack([bundle.f(X[:, j], U_cols[:, j], p, dt) for j in range(n)]),
    }

    def columns(output, got, expected, U, metric=relative_error, step=True) -> Worst:
        worst = Worst(metric)
        for j in range(n):
            u_j = U[:, j] if U.ndim == 2 else U
            worst.compare(output, got[:, j], expected[:, j], dict(x=X[:, j], u=u_j, p=p, dt=dt),
                          points.bounds if step else None, column=j)
        return worst

    absolute = lambda a, b: float(np.max(np.abs(a - b))) if np.size(a) else 0.0  # noqa: E731
    out = []
    for label, U in (("shared", u_shared), ("per-column", U_cols)):
        expected = one_at_a_time[label]
        simd = bundle.f_batch(X, U, p, dt)
        out.append(columns("f_batch", simd, expected, U).check(
            bundle.name, f"f_batch (SIMD, U {label}) vs one-at-a-time f", "single f calls", TOL_BATCH_SIMD,
            f"N = {n}; libmvec sin/cos may differ in the last bit"))
        # the `_batch` entry point runs the same scalar C per slice: bitwise equal
        Y = np.zeros((bundle.n_x, n), order="F")
        U_buf = np.asfortranarray(U) if U.ndim == 2 else U
        bundle.functions["f"].bind_batch([np.asfortranarray(X), U_buf, p, np.array([dt])], [Y], capacity=n)(n)
        out.append(columns("f _batch", Y, expected, U, absolute).check(
            bundle.name, f"f _batch entry (U {label}) vs one-at-a-time f", "single f calls", 0.0,
            f"N = {n}; must be bitwise equal"))
    H_one = np.column_stack([bundle.h(X[:, j], p) for j in range(n)])
    out.append(columns("h_batch", bundle.h_batch(X, p), H_one, u_shared, step=False).check(
        bundle.name, "h_batch (SIMD) vs one-at-a-time h", "single h calls", TOL_BATCH_SIMD, f"N = {n}"))
    return out


def compiled_twin(bundle) -> reference_models.ReferenceModel:
    """The bundle's own compiled xdot and h as a reference model (for a model without a NumPy twin);
    it samples states and inputs uniformly inside the bundle's envelope."""
    def xdot(x, u, p, w=None):
        return bundle.xdot(x, u, p, w)

    env = SamplingBox(bundle)

    def sample(low, high):
        return lambda rng, n=None: rng.uniform(low[:, None], high[:, None], (low.size, n)) if n else rng.uniform(low, high)

    return reference_models.ReferenceModel(bundle.name, tuple(bundle.parameter_names), xdot, bundle.h,
                                           sample(env.x_low, env.x_high), sample(env.u_low, env.u_high))


def _compiled_checks(bundle, points: _Points) -> list[Check]:
    """The checks of a model without a NumPy twin, against its own compiled functions."""
    name = bundle.name
    if bundle.is_discrete:
        def x_next(x, u, p, dt, w=None):
            return bundle.x_next(x, u, p, w, dt)

        worst = Worst()
        for _ in range(N_POINTS):
            x, u, p, dt = points.state(), points.inputs(), points.params(), points.dt()
            worst.compare("f", bundle.f(x, u, p, dt), x_next(x, u, p, dt), dict(x=x, u=u, p=p, dt=dt), points.bounds)
        out = [worst.check(name, "f vs compiled x_next at w = 0", "compiled x_next", TOL_SAME_SCHEME,
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
    worst = Worst()
    for _ in range(N_POINTS):
        x, u, p, dt = points.state(), points.inputs(), points.params(), points.dt()
        worst.compare("f", bundle.f(x, u, p, dt), reference_models.step(twin, x, u, p, dt, disc, substeps),
                      dict(x=x, u=u, p=p, dt=dt), points.bounds)
    out = [worst.check(name, f"f vs {disc} of compiled xdot", "NumPy scheme on the compiled xdot", TOL_SAME_SCHEME,
                       f"{N_POINTS} random points")]
    step = lambda x, u, p, dt, w=None: reference_models.step(twin, x, u, p, dt, disc, substeps, w=w)  # noqa: E731
    what = {"F": "compiled f in x", "G": f"{disc} of compiled xdot in w", "H": "compiled h"}
    out += _central_differences(bundle, points, lambda x, u, p, dt: bundle.f(x, u, p, dt), step, bundle.h, what,
                                "central differences of the compiled functions")
    # Start the order check at rest (the envelope's point nearest to it) with a random input: |v| v damping
    # is then smooth along the whole short horizon (velocities leave zero and keep their signs).
    env = points.envelope
    rest = np.clip(np.zeros(bundle.n_x), env.x_low, env.x_high)
    start = (rest, _input_inside(twin, points, rest, bundle.params()))
    exact = _integrate(twin, *start, bundle.params(), ORDER_HORIZON)
    coarse = relative_error(_repeated_steps(bundle, *start, bundle.params(), points.order_dt, ORDER_HORIZON), exact)
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
        # abyssal.verify.tan
        if builtin and not bundle.is_discrete:
            out.append(Check(bundle.name, "independent NumPy model", "reference_models", float("nan"), 0.0,
                             f"no NumPy model of {bundle.name!r} in verify/reference_models.py: add one"))
        model_checks = _compiled_checks(bundle, points)
        if points.envelope.note() and model_checks:  # said once per model, on its first check of this kind
            model_checks[0].note = points.envelope.note()
        out += model_checks
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
