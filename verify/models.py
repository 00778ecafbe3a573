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
A model that declares none is sampled in [-1, 1] about its rest state, and a model that declares no max_dt
with dt up to the longest step at which its discretisation is stable there (abyssal.verify.stability: at
rest and across the box, at most 0.5 s); the report says so once (a NOTE). A declared max_dt beyond that
step is a NOTE too: a finding about the model, never a failure of its code.

Verify judges the code. Two evaluations of the same function (compiled C and CasADi, f and the scheme
applied to the compiled xdot) are compared at any point where the reference is finite, however large its
values (a step at an unstable dt included): by the relative error, allowing for the reference's own rounding
noise at the point (its change when the inputs move by a few ulps). Non-finite entries must be non-finite on
both sides; a point where the reference is not finite at all is not judged, and counted. Central differences
are judged against their own truncation error (the change from step h to 2h). The discretisation is judged by
its own error order: one step against solve_ivp at most LOCAL_ERROR_SLACK x its step-doubling estimate, and the
order from halving dt, measured where it is asymptotic (dt halved until the ratio settles). Every check names
its worst point (x, u, p, dt), the entry that differs most (e.g. F[3,7]) and both values (Check.worst, printed
on FAIL lines).

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

TOL_C_VS_CASADI = 1e-12     # same SX graph; only rounding (operation order) differs
TOL_VS_NUMPY = 1e-12        # same equations, independently written
TOL_JACOBIAN = 1e-6         # central differences: truncation ~h^2, rounding ~eps/h
TOL_EXACT_FLOW = 1e-11      # discretisation that must be exact, vs DOP853 at rtol = atol = 1e-13
TOL_BATCH_SIMD = 1e-15      # libmvec's vector sin/cos may differ from scalar libm in the last bit
TOL_SAME_SCHEME = 1e-12     # f vs the same scheme applied to the compiled xdot: only rounding differs
NOISE_ULPS = 4              # the rounding noise of a reference: its change when its inputs move by this many ulps
NOISE_FACTOR = 10.0         # ... of which a point may differ this many times beyond the tolerance
LOCAL_ERROR_SLACK = 2.0     # one step's error against solve_ivp: at most this many times its step-doubling estimate
ORDER_DT = 0.1              # realistic filter step [s]
ORDER_HORIZON = 2.0         # global error over this horizon scales as dt^order
ORDER_HALVINGS = 4          # the order check halves dt until the error ratio settles, at most this many times
ORDER_FLOOR = 1e-10         # a global error below this is rounding and the reference's accuracy: no order to read
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
    manifest's "envelope" (the defaults when the model declared none or the manifest predates envelopes).

    A max_dt the model does not declare is derived from the model (``stability``: the longest step up to
    DEFAULT_MAX_DT at which its discretisation is stable at rest and across the box; DEFAULT_MAX_DT for a
    discrete model). ``stability`` is None for a discrete model."""

    def __init__(self, bundle):
        from abyssal.symbolic.model import DEFAULT_MAX_DT, DEFAULT_MIN_DT, DEFAULT_RANGE

        from .stability import largest_stable_dt

        record = getattr(bundle, "envelope", None) or {}
        self.declared = bool(record.get("declared", False))
        self.recorded = bool(record)
        default = tuple(record.get("default_range", DEFAULT_RANGE))
        states, inputs = (record.get("states", {}), record.get("inputs", {})) if self.declared else ({}, {})
        x = np.array([states.get(n, default) for n in bundle.state_names], dtype=float).reshape(-1, 2)
        u = np.array([inputs.get(n, default) for n in bundle.input_names], dtype=float).reshape(-1, 2)
        self.x_low, self.x_high = x[:, 0], x[:, 1]
        self.u_low, self.u_high = u[:, 0], u[:, 1]
        self.state_names = tuple(bundle.state_names)
        self.default = default
        #: the max_dt the model declares (None: not declared; a manifest written before max_dt could be left out
        #: records the old default 0.5 s for a model without an envelope, which it never declared)
        self.declared_max_dt = record.get("max_dt") if self.declared else None
        self.stability = largest_stable_dt(bundle, self.x_low, self.x_high, self.u_low, self.u_high,
                                           cap=max(DEFAULT_MAX_DT, self.declared_max_dt or 0.0))
        if self.declared_max_dt is not None:
            self.max_dt = float(self.declared_max_dt)
        elif self.stability is not None:
            self.max_dt = max(min(self.stability.dt, DEFAULT_MAX_DT), 1e-4 * DEFAULT_MAX_DT)
        else:
            self.max_dt = DEFAULT_MAX_DT
        self.min_dt = min(float(record.get("min_dt", DEFAULT_MIN_DT)), self.max_dt / 4)

    def note(self) -> str:
        """What a report says once about how the model was sampled and what was found about its step ("" when
        it declares an envelope with a max_dt its discretisation is stable at)."""
        stable = self.stability
        found = f": {stable.describe()}" if stable is not None else " (a discrete model: no stable step is derived)"
        dts = f"dt in [{self.min_dt:.3g}, {self.max_dt:.3g}] s"
        if not self.declared:
            why = "no envelope declared" if self.recorded else "no envelope declared (none recorded in its manifest)"
            lo, hi = self.default
            return (f"{why}: states and inputs sampled in [{lo:g}, {hi:g}] about the rest state, {dts}{found}; declare "
                    "where the model is meant to be used with Model(..., envelope=Envelope(states=..., inputs=..., "
                    "max_dt=...))")
        if self.declared_max_dt is None:
            return f"no max_dt declared: {dts}{found}; declare it with Envelope(..., max_dt=...)"
        if stable is not None and stable.limited and stable.dt < self.declared_max_dt:
            return (f"a finding about the model, not its code: {stable.describe()}, below its declared max_dt = "
                    f"{self.declared_max_dt:g} s (the Kalman filters split a longer step into substeps or refuse it, "
                    "the particle filters split it by step doubling)")
        return ""

    def clip_dt(self, dt: float) -> float:
        return min(max(dt, self.min_dt), self.max_dt)


class _Points:
    """Random arguments of a model's functions, in the manifest's shapes.

    With a NumPy twin: its plausible states and inputs, dt in [0.01, 0.5] s. Without one: uniform inside
    the model's sampling box (states, inputs and dt).
    """

    def __init__(self, bundle, ref, rng: np.random.Generator):
        self.bundle, self.ref, self.rng = bundle, ref, rng
        self.envelope = SamplingBox(bundle)

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
        """The step of the order check: ORDER_DT, inside the box's dt range for a model without a twin."""
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


def rounding_noise(fun, args, rng: np.random.Generator) -> float:
    """How far fun's value moves (relative_error) when every entry of its arguments moves by NOISE_ULPS ulps: the
    rounding noise of fun at this point, which no two correct evaluations of it can be asked to beat (0 where fun
    is not finite there)."""
    moved = [np.asarray(a, dtype=float) * (1.0 + NOISE_ULPS * np.finfo(float).eps * rng.choice((-1.0, 1.0), np.shape(a)))
             for a in args]
    with np.errstate(all="ignore"):
        here, there = np.asarray(fun(*args), dtype=float), np.asarray(fun(*moved), dtype=float)
        both = np.isfinite(here) & np.isfinite(there)
        return relative_error(there[both], here[both]) if both.any() else 0.0


class Worst:
    """The worst comparison of one check over its points: the error, the point, the entry, both values.

    ``compare(output, got, expected, point, allowance)`` per point; ``check(...)`` makes the Check, whose
    ``worst`` names where it happened. A point is judged where the reference (expected) is finite: an entry
    that is non-finite on one side only is a disagreement (error inf), one that is the same non-finite value on
    both sides agrees, and a point whose reference is nowhere finite is not judged (counted in the detail).
    ``allowance`` is the reference's own uncertainty at the point (relative, like the metric: its rounding
    noise, or a central difference's truncation error): the point's error is reported as
    error / (1 + allowance / tolerance), so it passes when error <= tolerance + allowance.
    """

    def __init__(self, tolerance: float, metric=relative_error, what: str = "disagrees"):
        self.tolerance, self.metric, self.what = tolerance, metric, what
        self.error = 0.0
        self.text = ""
        self.unjudged = 0
        self.points = 0

    def compare(self, output: str, got, expected, point: dict, allowance: float = 0.0, column: int | None = None) -> float:
        got, expected = np.asarray(got, dtype=float), np.asarray(expected, dtype=float)
        self.points += 1
        finite = np.isfinite(expected)
        if not finite.all() or not np.isfinite(got).all():
            same = (np.isnan(got) & np.isnan(expected)) | (got == expected)
            lone = ~finite & ~same | (finite & ~np.isfinite(got))
            if lone.any():
                k = int(np.argmax(lone.ravel()))
                self.error = math.inf
                self.text = (f"at {point_text(**point)}: {_entry(output, got.shape, k, column)} = "
                             f"{float(got.ravel()[k])!r} vs {float(expected.ravel()[k])!r} (non-finite on one side)")
                return math.inf
            if not finite.any():
                self.unjudged += 1
                return 0.0
            got, expected = np.where(finite, got, 0.0), np.where(finite, expected, 0.0)
        error = self.metric(got, expected) / (1.0 + allowance / self.tolerance) if self.tolerance > 0 else self.metric(
            got, expected)
        if error > self.error or not self.text:
            diff = np.abs(got - expected)
            k = int(np.argmax(diff.ravel())) if diff.size else 0
            entry = _entry(output, got.shape, k, column)
            values = f"{float(got.ravel()[k])!r} vs {float(expected.ravel()[k])!r}" if got.size else "(empty)"
            allowed = f" (allowing {allowance:.2g} for the reference at this point)" if allowance > 0 else ""
            self.error, self.text = max(self.error, error), f"at {point_text(**point)}: {entry} = {values}{allowed}"
        return error

    def check(self, model: str, name: str, reference: str, detail: str = "") -> Check:
        if self.unjudged:
            detail += (f"; {self.unjudged} of {self.points} points not judged (the reference is not finite there: "
                       "beyond the model's finite range)")
        worst = (f"{self.what} {self.text}, error {self.error:.3g}, tolerance {self.tolerance:.0e}" if self.text else "")
        return Check(model, name, reference, self.error, self.tolerance, detail, worst=worst)


def _c_vs_casadi(bundle, symbolic: dict, points: _Points) -> list[Check]:
    out = []
    further = [suffix for suffix in symbolic if suffix not in MODEL_FUNCTIONS and suffix in bundle.functions]
    for suffix in (*MODEL_FUNCTIONS, *further):
        if suffix not in bundle.functions or suffix not in symbolic:
            continue
        compiled, reference = bundle.functions[suffix], symbolic[suffix]
        worst = Worst(TOL_C_VS_CASADI)
        single = compiled.external.n_out() == 1
        for _ in range(N_POINTS):
            args = points.args(compiled)
            point = {sig.name: a for sig, a in zip(compiled.inputs, args)}
            expected = reference(*args)
            expected = [expected] if single else list(expected)
            got = compiled(*args)
            got = [got] if single else list(got)
            for i, (g, e, sig) in enumerate(zip(got, expected, compiled.outputs)):
                def output(*a, i=i):
                    result = reference(*a)
                    return np.array((result if single else result[i]).full())

                worst.compare(suffix if single else f"{suffix}.{sig.name}", np.asarray(g).reshape(sig.shape, order="F"),
                              np.array(e.full()).reshape(sig.shape, order="F"), point,
                              NOISE_FACTOR * rounding_noise(output, args, points.rng))
        out.append(worst.check(bundle.name, f"{suffix}: compiled C vs CasADi", "CasADi SX evaluation",
                               f"{N_POINTS} random points"))
    return out


def _vs_numpy(bundle, ref, points: _Points) -> list[Check]:
    disc, substeps = bundle.manifest["discretisation"], bundle.manifest["substeps"]
    worst = {"xdot": Worst(TOL_VS_NUMPY), "h": Worst(TOL_VS_NUMPY), "f": Worst(TOL_VS_NUMPY)}
    for _ in range(N_POINTS):
        x, u, p = points.state(), points.inputs(), points.params()
        w = points.rng.normal(size=bundle.n_w)
        dt = points.dt()
        worst["xdot"].compare("xdot", bundle.xdot(x, u, p, w), ref.xdot(x, u, p, w), dict(x=x, u=u, p=p, w=w))
        worst["h"].compare("h", bundle.h(x, p), ref.h(x, p), dict(x=x, p=p))
        worst["f"].compare("f", bundle.f(x, u, p, dt), reference_models.step(ref, x, u, p, dt, disc, substeps),
                           dict(x=x, u=u, p=p, dt=dt))
    label = {"xdot": "NumPy model", "h": "NumPy model", "f": f"NumPy {disc} step"}
    return [v.check(bundle.name, f"{k} vs {label[k]}", "reference_models (independent NumPy)", f"{N_POINTS} random points")
            for k, v in worst.items()]


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


def central_difference_with_error(fun, z: np.ndarray, rel_step: float = 1e-5, jacobian=None, along=None,
                                  columns: bool = True) -> tuple[np.ndarray, float]:
    """(d fun / d z by central differences of step h, an estimate of how far they may be from the derivative at z,
    relative like relative_error): the largest of their change to step 2h (three times their truncation error,
    where it dominates), to step h / 2 (at least their rounding error, where that dominates) and the curvature of
    the Jacobian under test over the step, J(a + h e_i) + J(a - h e_i) - 2 J(a) (at a = along, default z; six times
    the gap between a derivative and its mean over a +- h e_i, which a central difference is, for a smooth one): where
    the derivative varies on a scale below h (a pole of tan or 1 / cos reached inside an unstable step) the
    differences are no reference, and the estimate says so. ``columns``: the curvature of column i along e_i only (J
    is d fun / d z itself), else of all of J along every e_i (J is a derivative in other variables than z)."""
    J = central_difference(fun, z, rel_step)
    error = max(relative_error(central_difference(fun, z, 2 * rel_step), J),
                relative_error(central_difference(fun, z, rel_step / 2), J))
    if jacobian is not None:
        a = np.asarray(z if along is None else along, dtype=float)
        here = jacobian(a)
        curvature = 0.0
        for i in range(a.size):
            h = rel_step * max(1.0, abs(a[i]))
            up, down = a.copy(), a.copy()
            up[i] += h
            down[i] -= h
            second = jacobian(up) + jacobian(down) - 2 * here
            curvature = max(curvature, float(np.max(np.abs(second[:, i] if columns else second), initial=0.0)))
        error = max(error, curvature / max(1.0, float(np.max(np.abs(J), initial=0.0))))
    return J, error


def _jacobians(bundle, ref, points: _Points) -> list[Check]:
    """F, G, H against central differences of the NumPy twin's step and measurement."""
    disc, substeps = bundle.manifest["discretisation"], bundle.manifest["substeps"]
    step = lambda x, u, p, dt, w=None: reference_models.step(ref, x, u, p, dt, disc, substeps, w=w)  # noqa: E731
    what = {"F": "NumPy step in x", "G": "NumPy step in w", "H": "NumPy measurement"}
    return _central_differences(bundle, points, step, step, ref.h, what, "central differences of reference_models")


def _central_differences(bundle, points: _Points, step_x, step_w, measure, what: dict, reference: str) -> list[Check]:
    """F = d step_x / dx, G = d step_w / dw at w = 0, H = d measure / dx, by central differences (each point
    allowing for the differences' own error, central_difference_with_error)."""
    worst = {k: Worst(TOL_JACOBIAN, what="derivative disagrees") for k in ("F", "G", "H")}
    for _ in range(N_POINTS):
        x, u, p = points.state(), points.inputs(), points.params()
        dt = points.dt()
        point = dict(x=x, u=u, p=p, dt=dt)
        F_num, error = central_difference_with_error(lambda z: step_x(z, u, p, dt), x,
                                                     jacobian=lambda z: bundle.F(z, u, p, dt))
        worst["F"].compare("F", bundle.F(x, u, p, dt), F_num, point, error)
        if "G" in bundle.functions and bundle.n_w:
            G_num, error = central_difference_with_error(lambda z: step_w(x, u, p, dt, w=z), np.zeros(bundle.n_w),
                                                         jacobian=lambda z: bundle.G(z, u, p, dt), along=x, columns=False)
            worst["G"].compare("G", bundle.G(x, u, p, dt), G_num, point, error)
        H_num, error = central_difference_with_error(lambda z: measure(z, p), x, jacobian=lambda z: bundle.H(z, p))
        worst["H"].compare("H", bundle.H(x, p), H_num, dict(x=x, p=p), error)
    return [v.check(bundle.name, f"{k} vs central differences ({what[k]})", reference,
                    f"{N_POINTS} random points, step 1e-5 relative, allowing for the differences' own error (steps 2h, "
                    "h / 2) and the Jacobian's curvature over the step")
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


def _repeated_steps(bundle, x0, u, p, dt: float, n: int) -> np.ndarray:
    """n steps of the compiled f of length dt from x0, u and p held."""
    out = np.empty(bundle.n_x)
    x = np.array(x0, dtype=float)
    step = bundle.functions["f"].bind([x, np.array(u, dtype=float), p, np.array([dt])], [out])
    for _ in range(n):
        step()
        x[:] = out
    return x


def _discretisation(bundle, ref, points: _Points) -> list[Check]:
    """One step against solve_ivp, bounded by its own step-doubling estimate, and the scheme's order from halving
    dt where the error ratio has settled (the module docstring)."""
    disc = bundle.manifest["discretisation"]
    x0, u = ref.cruise if ref.cruise is not None else (points.state(), points.inputs())
    p = bundle.params()
    dt = points.order_dt
    start = dict(x=x0, u=u, p=p, dt=dt)
    one_step = bundle.f(x0, u, p, dt)
    error = relative_error(one_step, _integrate(ref, x0, u, p, dt))
    if ref.exact_flow:
        one = Worst(TOL_EXACT_FLOW)
        one.compare("f", one_step, _integrate(ref, x0, u, p, dt), start)
        return [one.check(bundle.name, f"f ({disc}) exact for held input vs solve_ivp", "scipy solve_ivp DOP853, rtol 1e-13",
                          f"dt = {dt:g} s; flow polynomial of degree <= scheme order")]
    order = SCHEME_ORDER[disc]
    expected = 2.0 ** order
    # Richardson: two half steps err by ~2^-order of one step's local error, so their difference is
    # (1 - 2^-order) of it
    halves = bundle.f(bundle.f(x0, u, p, dt / 2), u, p, dt / 2)
    estimate = relative_error(one_step, halves) * expected / (expected - 1)
    bound = LOCAL_ERROR_SLACK * estimate + TOL_EXACT_FLOW
    one_step_check = Check(
        bundle.name, f"f ({disc}) one step vs solve_ivp, within its own error estimate", "scipy solve_ivp DOP853, rtol 1e-13",
        error, bound, f"dt = {dt:g} s: its error {error:.3g} against its step-doubling estimate {estimate:.3g} (bound "
                      f"{LOCAL_ERROR_SLACK:g}x the estimate + {TOL_EXACT_FLOW:g})",
        worst=f"from {point_text(**start)}: one step errs by {error:.3g}, {error / max(estimate, 1e-300):.3g}x its "
              f"step-doubling estimate {estimate:.3g}; allowed {bound:.3g}")
    steps = max(1, int(round(ORDER_HORIZON / dt)))
    horizon = steps * dt
    exact = _integrate(ref, x0, u, p, horizon)
    errors = [relative_error(_repeated_steps(bundle, x0, u, p, dt, steps), exact)]
    ladder, ratio = [], math.nan
    for level in range(1, ORDER_HALVINGS + 1):
        errors.append(relative_error(_repeated_steps(bundle, x0, u, p, dt / 2**level, steps * 2**level), exact))
        coarse, fine = errors[-2], errors[-1]
        if fine <= ORDER_FLOOR:
            break  # rounding and the reference's accuracy from here on: nothing more to read
        ratio = coarse / fine
        ladder.append(f"{ratio:.3g} at dt = {dt / 2**(level - 1):.3g}/{dt / 2**level:.3g}")
        if abs(ratio - expected) <= ORDER_SLACK * expected:
            break
    trail = "; ".join(ladder) if ladder else "none (the error is at rounding level already)"
    if not ladder:  # integrated to rounding at the first step: exact for this held input, no order to read
        settled = 0.0
    else:
        settled = abs(ratio - expected)
    return [
        one_step_check,
        # The check's error is the distance of the settled ratio from 2^order.
        Check(bundle.name, f"f ({disc}) order {order}: |error ratio halving dt - {expected:g}|",
              f"scipy solve_ivp DOP853 (ratio {ratio:.2f})", settled, ORDER_SLACK * expected,
              f"global error over {horizon:g} s: {errors[0]:.3e} at dt = {dt:g}; ratios halving dt: {trail}; expected a "
              f"ratio in [{(1 - ORDER_SLACK) * expected:g}, {(1 + ORDER_SLACK) * expected:g}]",
              worst=f"from {point_text(**start)} over {horizon:g} s: error ratios {trail}, expected {expected:g} +- "
                    f"{ORDER_SLACK * expected:g}"),
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

    single = {"f": lambda x, u, p, dt: bundle.f(x, u, p, float(dt)), "h": bundle.h}

    def columns(output, got, expected, U, tolerance, metric=relative_error, of=None) -> Worst:
        """Column j against the single call; libmvec's last bit allowed for as the single call's rounding noise."""
        worst = Worst(tolerance, metric)
        for j in range(n):
            u_j = U[:, j] if U.ndim == 2 else U
            args = (X[:, j], u_j, p, dt) if of == "f" else (X[:, j], p)
            noise = NOISE_FACTOR * rounding_noise(single[of], args, points.rng) if of is not None else 0.0
            worst.compare(output, got[:, j], expected[:, j], dict(x=X[:, j], u=u_j, p=p, dt=dt), noise, column=j)
        return worst

    absolute = lambda a, b: float(np.max(np.abs(a - b))) if np.size(a) else 0.0  # noqa: E731
    out = []
    for label, U in (("shared", u_shared), ("per-column", U_cols)):
        expected = one_at_a_time[label]
        simd = bundle.f_batch(X, U, p, dt)
        out.append(columns("f_batch", simd, expected, U, TOL_BATCH_SIMD, of="f").check(
            bundle.name, f"f_batch (SIMD, U {label}) vs one-at-a-time f", "single f calls",
            f"N = {n}; libmvec sin/cos may differ in the last bit (allowed for as f's rounding noise at the point)"))
        # the `_batch` entry point runs the same scalar C per slice: bitwise equal
        Y = np.zeros((bundle.n_x, n), order="F")
        U_buf = np.asfortranarray(U) if U.ndim == 2 else U
        bundle.functions["f"].bind_batch([np.asfortranarray(X), U_buf, p, np.array([dt])], [Y], capacity=n)(n)
        out.append(columns("f _batch", Y, expected, U, 0.0, absolute).check(
            bundle.name, f"f _batch entry (U {label}) vs one-at-a-time f", "single f calls",
            f"N = {n}; must be bitwise equal"))
    H_one = np.column_stack([bundle.h(X[:, j], p) for j in range(n)])
    out.append(columns("h_batch", bundle.h_batch(X, p), H_one, u_shared, TOL_BATCH_SIMD, of="h").check(
        bundle.name, "h_batch (SIMD) vs one-at-a-time h", "single h calls", f"N = {n}"))
    return out


def compiled_twin(bundle, box: SamplingBox | None = None) -> reference_models.ReferenceModel:
    """The bundle's own compiled xdot and h as a reference model (for a model without a NumPy twin);
    it samples states and inputs uniformly inside the bundle's sampling box."""
    def xdot(x, u, p, w=None):
        return bundle.xdot(x, u, p, w)

    env = box or SamplingBox(bundle)

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

        worst = Worst(TOL_SAME_SCHEME)
        for _ in range(N_POINTS):
            x, u, p, dt = points.state(), points.inputs(), points.params(), points.dt()
            worst.compare("f", bundle.f(x, u, p, dt), x_next(x, u, p, dt), dict(x=x, u=u, p=p, dt=dt),
                          NOISE_FACTOR * rounding_noise(x_next, (x, u, p, dt), points.rng))
        out = [worst.check(name, "f vs compiled x_next at w = 0", "compiled x_next",
                           f"{N_POINTS} random points; two generated functions of the same step")]
        what = {"F": "compiled f in x", "G": "compiled x_next in w", "H": "compiled h"}
        out += _central_differences(bundle, points, lambda x, u, p, dt: bundle.f(x, u, p, dt), x_next, bundle.h,
                                    what, "central differences of the compiled functions")
        because = "the model is discrete (x_next given directly): there is no xdot to integrate"
        out += [Check.skip(name, "f one step vs solve_ivp", "scipy solve_ivp", because),
                Check.skip(name, "f order by halving dt", "scipy solve_ivp", because)]
        return out
    twin = compiled_twin(bundle, points.envelope)
    disc, substeps = bundle.manifest["discretisation"], bundle.manifest["substeps"]
    worst = Worst(TOL_SAME_SCHEME)

    def scheme(x, u, p, dt):
        return reference_models.step(twin, x, u, p, dt, disc, substeps)

    for _ in range(N_POINTS):
        x, u, p, dt = points.state(), points.inputs(), points.params(), points.dt()
        worst.compare("f", bundle.f(x, u, p, dt), scheme(x, u, p, dt), dict(x=x, u=u, p=p, dt=dt),
                      NOISE_FACTOR * rounding_noise(scheme, (x, u, p, dt), points.rng))
    out = [worst.check(name, f"f vs {disc} of compiled xdot", "NumPy scheme on the compiled xdot", f"{N_POINTS} random points")]
    step = lambda x, u, p, dt, w=None: reference_models.step(twin, x, u, p, dt, disc, substeps, w=w)  # noqa: E731
    what = {"F": "compiled f in x", "G": f"{disc} of compiled xdot in w", "H": "compiled h"}
    out += _central_differences(bundle, points, lambda x, u, p, dt: bundle.f(x, u, p, dt), step, bundle.h, what,
                                "central differences of the compiled functions")
    # Start the order check at rest (the envelope's point nearest to it) with a random input: |v| v damping
    # is then smooth along the whole short horizon (velocities leave zero and keep their signs).
    env = points.envelope
    rest = np.clip(np.zeros(bundle.n_x), env.x_low, env.x_high)
    start = (rest, _input_inside(twin, points, rest, bundle.params()))
    exact = _integrate(twin, *start, bundle.params(), points.order_dt)
    one = relative_error(bundle.f(*start, bundle.params(), points.order_dt), exact)
    twin = dataclasses.replace(twin, cruise=start, exact_flow=one <= TOL_EXACT_FLOW)
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
        out += _compiled_checks(bundle, points)
    else:
        if tuple(ref.parameter_names) != tuple(bundle.parameter_names):
            out.append(Check(bundle.name, "parameter order vs NumPy model", "reference_models", float("inf"), 0.0,
                             f"manifest {bundle.parameter_names} != reference {ref.parameter_names}"))
            return out
        out += _vs_numpy(bundle, ref, points)
        out += _jacobians(bundle, ref, points)
        out += _discretisation(bundle, ref, points)
    note = points.envelope.note()
    if note and out:  # said once per model, on its first check
        out[0].note = note
    out += _batches(bundle, ref, points)
    return out
