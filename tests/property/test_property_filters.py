"""Property-based tests of every registered filter's predict / update / step / run.

The filters come from the contract's registry (``abyssal.runtime.contract.registered_filters``),
so a filter registered tomorrow is fuzzed the day it is added. For every call:

* arguments the contract refuses (non-finite u/p, inf in z, dt not a positive finite number,
  complex, wrong shape or type) give a ValueError/TypeError naming one of those arguments;
* acceptable arguments give a finite state (x, P) and finite reports, or a refusal
  (ValueError, e.g. a step beyond the model's range) whose message names an argument or says
  why (diverged / stable range);
* after any refusal the filter is bit-identical: x, P, what it reports (innovation, S, NIS,
  ESS, counters), its public arrays (particles, weights) and its random generator.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, strategies as st

import abyssal.generated
from abyssal.runtime.contract import registered_filters
from abyssal.runtime.noise.mixtures import GaussianMixture
from property_strategies import CLASS_BUGS, KNOWN_BUGS, Drawn, known_bug, named, seconds, vectors

N_PARTICLES = 16
REPORTS = ("x", "P", "nis", "nis_dof", "ess", "n_particles", "innovation", "S", "gated", "repairs", "inflations",
           "substeps")
#: public working buffers that are not state (the SIR engine's ``proposed``: x_k written by the proposal
#: before the weights are known; its contents after any call are scratch)
SCRATCH = {"proposed", "mean_pred", "cov_pred", "mean_post", "cov_post"}  # + the UPF's per-particle step outputs
#: words a refusal of acceptable arguments may give instead of an argument name
REASONS = ("diverg", "stable", "range", "not finite", "positive definite")

FILTERS = sorted(registered_filters().items(), key=lambda item: item[0].__name__)


@pytest.fixture(scope="module")
def rov():
    return abyssal.generated.load("rov4dof")


def build(cls, kind: str, model):
    """A fresh filter of a registered class on rov4dof (noise and P0 of the soak benchmark)."""
    n, m = model.n_x, model.n_y
    x0, P0 = np.zeros(n), 0.3 * np.eye(n)
    Q = np.diag([1e-4] * 4 + [1e-3] * 4 + [1e-5] * 4)
    R = np.diag([0.05, 0.05, 0.02, 0.01])
    if hasattr(cls, "contract_example"):  # a constructor outside the standard kinds
        filt = cls.contract_example(model, rng=0)
        if getattr(filt, "model", model) is not model or hasattr(filt, "gp_dt"):
            pytest.skip(f"{cls.__name__} runs on its own model or learned step; tests/runtime/test_contract.py covers it")
        return filt
    if kind == "kalman":
        return cls(model, x0, P0, Q, R)
    process = GaussianMixture.gaussian(np.zeros(n), Q)
    measurement = GaussianMixture(np.array([0.9, 0.1]), np.zeros((2, m)), np.array([R, 100 * R]))
    if kind in ("particle", "mixture"):
        return cls(model, x0, P0, process, measurement, N_PARTICLES, np.random.default_rng(0))
    if kind == "gaussian-sum":
        return cls(model, x0, P0, process, measurement, 2, np.random.default_rng(0))
    pytest.fail(f"no builder for filter kind {kind!r} ({cls.__name__}): add one to tests/property")


def _copy(value):
    if isinstance(value, np.ndarray):
        return value.copy()
    if isinstance(value, np.random.Generator):
        return repr(value.bit_generator.state)
    if isinstance(value, GaussianMixture):
        return (value.weights.copy(), value.means.copy(), value.covariances.copy())
    if value is None or isinstance(value, (bool, int, float, str, np.number)):
        return value
    return NotImplemented


def snapshot(filt) -> dict:
    """What a refusal must leave unchanged: the reports and every public array, mixture and generator."""
    out = {}
    for name in REPORTS:
        try:
            out["." + name] = _copy(getattr(filt, name))
        except AttributeError:
            pass
    for name, value in vars(filt).items():
        if (name.startswith("_") and not isinstance(value, np.random.Generator)) or name in SCRATCH:
            continue
        copied = _copy(value)
        if copied is not NotImplemented:
            out[name] = copied
    return out


def _same(a, b) -> bool:
    if isinstance(a, tuple) and isinstance(b, tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.shape == b.shape and np.array_equal(
            a, b, equal_nan=True)
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


def assert_unchanged(before: dict, after: dict, error):
    changed = [k for k in before if k not in after or not _same(before[k], after[k])]
    assert not changed, f"refused call ({error!r}) changed {changed}"


def assert_finite_state(filt):
    x, P = filt.x, filt.P
    assert np.all(np.isfinite(x)) and np.all(np.isfinite(P)), f"non-finite state after an accepted call: x = {x}"
    assert P.shape == (x.shape[0], x.shape[0])
    for name in ("nis", "ess"):
        value = getattr(filt, name, math.nan)
        assert not (isinstance(value, float) and math.isinf(value)), f"{name} = {value}"


def exercise(filt, call, args: dict[str, Drawn]):
    """Call with the drawn values and assert the contract (see the module docstring)."""
    faulty = [name for name, d in args.items() if d.problem]
    before = snapshot(filt)
    try:
        call(*[d.value for d in args.values()])
    except (ValueError, TypeError, FloatingPointError) as error:  # (numpy's LinAlgError is a ValueError)
        assert_unchanged(before, snapshot(filt), error)
        message = str(error)
        assert isinstance(error, (ValueError, TypeError)), f"refused with {error!r}, not ValueError/TypeError"
        assert not isinstance(error, np.linalg.LinAlgError), f"numpy's LinAlgError escaped: {error!r}"
        if faulty:  # (a step may also be refused first for a reason, e.g. dt beyond the stable range)
            assert named(message, faulty) or any(r in message for r in REASONS), (
                f"the error does not name any of {faulty}: {error!r}")
        else:
            assert isinstance(error, ValueError), f"TypeError for acceptable arguments {args}: {error!r}"
            assert named(message, list(args)) or any(r in message for r in REASONS), (
                f"refusal of acceptable arguments names no argument or reason: {error!r}")
        return False
    if faulty == ["dt"] and isinstance(args["dt"].value, bool) and known_bug("kalman_bool_dt_after_long_step"):
        return True
    assert not faulty, f"accepted faulty arguments {[(n, args[n]) for n in faulty]}"
    assert_finite_state(filt)
    return True


def parameters(model):
    """p: None (mostly), the defaults perturbed by a few percent, or anything `vectors` draws."""
    perturbed = st.lists(st.floats(0.95, 1.05), min_size=model.n_p, max_size=model.n_p).map(
        lambda f: Drawn(model.p_default * np.array(f)))
    return st.one_of(st.just(Drawn(None)), st.just(Drawn(None)), perturbed, vectors(model.n_p, none_ok=True))


def measurements(model):
    """z: near the measurement of the initial state (mostly), with gross outliers, NaN and inf entries."""
    return st.one_of(vectors(model.n_y, scale=1.0, nan_ok=True, none_ok=True),
                     vectors(model.n_y, scale=1e6, nan_ok=True, none_ok=True))


def inputs(model):
    return vectors(model.n_u, scale=30.0)


def _param(cls, kind):
    key = CLASS_BUGS.get(cls.__name__)
    marks = [pytest.mark.xfail(strict=True, reason=f"known bug [{key}]: {KNOWN_BUGS[key]}")] if key in KNOWN_BUGS else []
    return pytest.param(cls, kind, id=cls.__name__, marks=marks)


filter_classes = pytest.mark.parametrize("cls, kind", [_param(cls, kind) for cls, kind in FILTERS])


def test_registry_lists_every_family():
    kinds = {kind for _, kind in FILTERS}
    assert {"kalman", "particle"} <= kinds, f"registered filters: {FILTERS}"


@filter_classes
@given(data=st.data())
def test_predict(rov, cls, kind, data):
    filt = build(cls, kind, rov)
    args = {"u": data.draw(inputs(rov), "u"), "dt": data.draw(seconds(), "dt"), "p": data.draw(parameters(rov), "p")}
    exercise(filt, filt.predict, args)


@filter_classes
@given(data=st.data())
def test_update(rov, cls, kind, data):
    filt = build(cls, kind, rov)
    if data.draw(st.booleans(), "predict first"):
        filt.predict(np.zeros(rov.n_u), 0.1)
    args = {"z": data.draw(measurements(rov), "z"), "p": data.draw(parameters(rov), "p")}
    exercise(filt, filt.update, args)


@filter_classes
@given(data=st.data())
def test_step_sequence(rov, cls, kind, data):
    """A few steps in a row (state carried over), each with freshly drawn arguments."""
    filt = build(cls, kind, rov)
    for k in range(data.draw(st.integers(1, 3), "steps")):
        args = {"u": data.draw(inputs(rov), f"u{k}"), "dt": data.draw(seconds(), f"dt{k}"),
                "z": data.draw(measurements(rov), f"z{k}"), "p": data.draw(parameters(rov), f"p{k}")}
        exercise(filt, filt.step, args)


@st.composite
def sequences(draw, model):
    """(U, Z, dt, params) for run: T rows, each argument sometimes faulty."""
    T = draw(st.integers(1, 4))
    U = np.array(draw(st.lists(st.floats(-30, 30), min_size=T * model.n_u, max_size=T * model.n_u))).reshape(T, model.n_u)
    Z = np.array(draw(st.lists(st.floats(-2, 2), min_size=T * model.n_y, max_size=T * model.n_y))).reshape(T, model.n_y)
    U_problem = Z_problem = None
    fault = draw(st.sampled_from(["none"] * 4 + ["U nan", "Z nan", "Z inf", "Z outlier", "U shape", "Z shape",
                                                 "Z none", "U complex"]))
    if fault == "U nan":
        U[draw(st.integers(0, T - 1)), 0], U_problem = np.nan, "non-finite"
    elif fault == "Z nan":
        Z[draw(st.integers(0, T - 1)), draw(st.integers(0, model.n_y - 1))] = np.nan  # a missing entry: acceptable
    elif fault == "Z inf":
        Z[draw(st.integers(0, T - 1)), 0], Z_problem = np.inf, "inf"
    elif fault == "Z outlier":
        Z[draw(st.integers(0, T - 1)), 0] = draw(st.sampled_from([1e4, 1e6, -1e300]))
    elif fault == "U shape":
        U, U_problem = U[:, :-1], "wrong shape"
    elif fault == "Z shape":
        Z, Z_problem = Z[:, :-1], "wrong shape"
    elif fault == "U complex":
        U, U_problem = U + 0j, "complex"
    Zd = Drawn(None) if fault == "Z none" else Drawn(Z, Z_problem)
    params = draw(st.sampled_from([Drawn(None), Drawn(model.p_default.copy()), Drawn(np.tile(model.p_default, (T, 1))),
                                   Drawn(np.full(model.n_p, np.nan), "non-finite"), Drawn(np.zeros(3), "wrong shape")]))
    return Drawn(U, U_problem), Zd, draw(seconds()), params


@filter_classes
@given(data=st.data())
def test_run_is_all_or_nothing(rov, cls, kind, data):
    filt = build(cls, kind, rov)
    U, Z, dt, params = data.draw(sequences(rov), "sequence")
    args = {"U": U, "Z": Z, "dt": dt, "params": params}
    before = snapshot(filt)
    faulty = [name for name, d in args.items() if d.problem]
    try:
        result = filt.run(U.value, Z.value, dt.value, params.value)
    except (ValueError, TypeError, FloatingPointError) as error:
        assert_unchanged(before, snapshot(filt), error)
        message = str(error)
        if faulty:
            assert named(message, faulty), f"the error does not name any of {faulty}: {error!r}"
        else:
            assert "row" in message, f"a refused row is not named: {error!r}"
            cause = error.__cause__ or error
            assert isinstance(cause, (ValueError, TypeError)) and not isinstance(cause, np.linalg.LinAlgError), (
                f"refused row: {error!r}")
        return
    assert not faulty, f"accepted faulty arguments {[(n, args[n]) for n in faulty]}"
    assert np.all(np.isfinite(result.x)) and np.all(np.isfinite(result.P))
    assert result.x.shape == (U.value.shape[0], rov.n_x)
    assert_finite_state(filt)
