"""The one filter contract (runtime/contract.py), every rule against every registered filter class.

Filters are discovered from ``contract.registered_filters()``: a new filter decorated with
``@register(kind)`` is covered the day it is added. A class whose constructor fits none of the
kinds below provides a ``contract_example(model, *, x0=None, P0=None, n_particles=None, rng)`` classmethod
(None: its own choice); every rule runs on every class, with no skips.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import abyssal.generated
from abyssal.runtime import contract
from abyssal.runtime.compiled import kalman as kr
from abyssal.runtime.noise.mixtures import GaussianMixture

FILTERS = sorted(contract.registered_filters().items(), key=lambda item: item[0].__name__)
IDS = [cls.__name__ for cls, _ in FILTERS]
N_PARTICLES = 40
DT = 0.5


@pytest.fixture(scope="module")
def model():
    return abyssal.generated.load("linear_cv")


def problem(model):
    n, m = model.n_x, model.n_y
    Q = np.diag([0.02, 0.02, 0.05, 0.05])[:n, :n]
    R = np.diag([0.5, 0.8])[:m, :m]
    return np.array([0.0, 0.0, 1.0, -0.5])[:n], np.diag([1.0, 1.0, 0.2, 0.2])[:n, :n], Q, R


def build(cls, kind, model, *, x0=None, P0=None, n=N_PARTICLES, rng=7):
    if hasattr(cls, "contract_example"):
        return cls.contract_example(model, x0=x0, P0=P0, n_particles=n, rng=rng)
    x0_, P0_, Q, R = problem(model)
    x0 = x0_ if x0 is None else x0
    P0 = P0_ if P0 is None else P0
    if kind == "kalman":
        return cls(model, x0, P0, Q, R)
    noise_q, noise_r = GaussianMixture.gaussian(np.zeros(model.n_x), Q), GaussianMixture.gaussian(np.zeros(model.n_y), R)
    if kind in ("particle", "mixture"):
        return cls(model, x0, P0, noise_q, noise_r, n, rng)
    if kind == "gaussian-sum":
        return cls(model, x0, P0, noise_q, noise_r, n_components=2, rng=rng)
    raise AssertionError(f"{cls.__name__}: unknown contract kind {kind!r}; give the class a contract_example()")


def good_inputs(model, k=0):
    u = np.array([0.2 * math.sin(0.3 * k), 0.1])[: model.n_u]
    z = np.array([0.5 * k, -0.2 * k])[: model.n_y]
    return u, z


def report(filt):
    """Everything a filter holds or reports that a refused call must not change."""
    out = {"x": filt.x, "P": filt.P, "nis": filt.nis, "nis_dof": filt.nis_dof, "ess": filt.ess,
           "n_particles": filt.n_particles}
    for name in ("innovation", "S", "gated", "repairs", "inflations", "substeps", "particles", "weights",
                 "log_weights", "resamples", "uninformative", "last_Q", "xi", "lam", "recoveries", "em_iterations"):
        if hasattr(filt, name):
            value = getattr(filt, name)
            out[name] = None if value is None else np.array(value, copy=True)
    for owner, name in ((filt, "carried"), (getattr(filt, "proposal", None), "carried"), (filt, "streams")):
        value = getattr(owner, name, None)  # per-particle covariances, the compiled step's random streams
        if isinstance(value, np.ndarray):
            out[f"{name} of {type(owner).__name__}"] = value.copy()
    posterior = getattr(filt, "posterior", None)  # the Gaussian-sum filters' mixture
    if posterior is not None:
        out["posterior"] = np.concatenate([posterior.weights.ravel(), posterior.means.ravel(),
                                           posterior.covariances.ravel()])
    rng = getattr(filt, "rng", None)
    if rng is not None:
        out["rng"] = repr(rng.bit_generator.state)
    return out


def assert_identical(before, after):
    assert before.keys() == after.keys()
    for key in before:
        a, b = before[key], after[key]
        if isinstance(a, str) or a is None:
            assert a == b, key
        else:
            assert np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True), key


def warmed(cls, kind, model):
    """A filter after two accepted steps (so it has something to report)."""
    filt = build(cls, kind, model)
    for k in range(2):
        u, z = good_inputs(model, k)
        filt.step(u, DT, z)
    return filt


def bad_calls(model):
    """(description, call(filt), exception type, text the message must contain)."""
    u, z = good_inputs(model, 3)
    n_u, n_y, n_p = model.n_u, model.n_y, model.n_p
    nan_u, inf_u = u.copy(), u.copy()
    nan_u[0], inf_u[-1] = np.nan, np.inf
    inf_z = z.copy()
    inf_z[0] = np.inf
    return [
        ("short u", lambda f: f.step(np.zeros(n_u - 1), DT, z), ValueError, "u"),
        ("long z", lambda f: f.step(u, DT, np.zeros(n_y + 1)), ValueError, "z"),
        ("bad p shape", lambda f: f.step(u, DT, z, np.zeros(n_p + 1)), ValueError, "p"),
        ("NaN u", lambda f: f.step(nan_u, DT, z), ValueError, "u"),
        ("inf u", lambda f: f.predict(inf_u, DT), ValueError, "u"),
        ("inf z", lambda f: f.step(u, DT, inf_z), ValueError, "use NaN for a missing entry"),
        ("inf z update", lambda f: f.update(inf_z), ValueError, "use NaN for a missing entry"),
        ("NaN p", lambda f: f.step(u, DT, z, np.full(n_p, np.nan)), ValueError, "p"),
        ("dt = 0", lambda f: f.step(u, 0.0, z), ValueError, "dt"),
        ("dt < 0", lambda f: f.predict(u, -0.1), ValueError, "dt"),
        ("dt = inf", lambda f: f.step(u, math.inf, z), ValueError, "dt"),
        ("dt = NaN", lambda f: f.step(u, math.nan, z), ValueError, "dt"),
        ("dt a string", lambda f: f.step(u, "0.1", z), TypeError, "dt"),
        ("complex u", lambda f: f.step(u.astype(complex), DT, z), TypeError, "u"),
        ("complex z", lambda f: f.update(z.astype(complex)), TypeError, "z"),
        ("u None", lambda f: f.predict(None, DT), TypeError, "u"),
    ]


RULES = [d for d, *_ in bad_calls(abyssal.generated.load("linear_cv"))]


@pytest.mark.parametrize("rule", RULES)
@pytest.mark.parametrize("cls, kind", FILTERS, ids=IDS)
def test_refused_call_names_the_argument_and_changes_nothing(model, cls, kind, rule):
    description, call, error, text = next(c for c in bad_calls(model) if c[0] == rule)
    filt, twin = warmed(cls, kind, model), warmed(cls, kind, model)
    before = report(filt)
    with pytest.raises(error, match=text.replace("(", r"\(")):
        call(filt)
    assert_identical(before, report(filt))
    u, z = good_inputs(model, 4)  # and it goes on exactly as a filter that was never refused
    filt.step(u, DT, z)
    twin.step(u, DT, z)
    assert_identical(report(twin), report(filt))


@pytest.mark.parametrize("cls, kind", FILTERS, ids=IDS)
def test_missing_measurements(model, cls, kind):
    filt = warmed(cls, kind, model)
    u, z = good_inputs(model, 2)
    before = report(filt)
    assert filt.update(None) is False
    assert filt.update(np.full(model.n_y, np.nan)) is False
    assert_identical(before, report(filt))
    assert filt.step(u, DT) is False  # z = None: predict only
    assert filt.step(u, DT, np.full(model.n_y, np.nan)) is False
    partial = z.copy()
    partial[0] = np.nan
    assert filt.step(u, DT, partial) is True
    assert np.all(np.isfinite(filt.x)) and np.all(np.isfinite(filt.P))
    if kind == "kalman":
        assert filt.nis_dof == model.n_y - 1


@pytest.mark.parametrize("cls, kind", FILTERS, ids=IDS)
def test_parameters_change_every_step(model, cls, kind):
    a, b = build(cls, kind, model), build(cls, kind, model)
    u, z = good_inputs(model, 1)
    p_other = np.array(model.p_default) * 1.5 + 0.1
    a.step(u, DT, z, p_other)
    b.step(u, DT, z)
    assert not np.array_equal(a.x, b.x)  # p was used
    a.step(u, DT, z)  # and None goes back to the defaults
    b2 = build(cls, kind, model)
    b2.step(u, DT, z, p_other)
    b2.step(u, DT, z, np.array(model.p_default))
    assert np.array_equal(a.x, b2.x)


@pytest.mark.parametrize("cls, kind", FILTERS, ids=IDS)
def test_construction_rules(model, cls, kind):
    n = build(cls, kind, model).x.shape[0]  # a contract_example may run on its own model
    x0 = build(cls, kind, model).x
    with pytest.raises(ValueError, match="x0"):
        build(cls, kind, model, x0=np.full(n, np.nan))
    with pytest.raises(ValueError, match="x0"):
        build(cls, kind, model, x0=np.zeros(n - 1))
    with pytest.raises(ValueError, match="P0"):
        build(cls, kind, model, P0=-np.eye(n))
    with pytest.raises(TypeError, match="x0"):
        build(cls, kind, model, x0=x0.astype(complex))
    # huge finite entries: validated without overflow or LinAlgError (accepted here: they are valid)
    build(cls, kind, model, P0=1e300 * np.eye(n))
    if kind in ("particle", "mixture"):
        with pytest.raises(ValueError, match="n_particles"):
            build(cls, kind, model, n=0)
        with pytest.raises(TypeError, match="n_particles"):
            build(cls, kind, model, n=2.5)
        with pytest.raises(TypeError, match="rng"):
            build(cls, kind, model, rng="seed")
        one = build(cls, kind, model, n=1)  # N = 1 is allowed
        u, z = good_inputs(model, 1)
        one.step(u, DT, z)
        assert np.all(np.isfinite(one.x))
    # an int seed and the Generator it makes give the same filter
    a = build(cls, kind, model, rng=5)
    b = build(cls, kind, model, rng=np.random.default_rng(5))
    u, z = good_inputs(model, 1)
    a.step(u, DT, z)
    b.step(u, DT, z)
    assert np.array_equal(a.x, b.x)


@pytest.mark.parametrize("cls, kind", FILTERS, ids=IDS)
def test_singular_and_zero_P0_are_handled(model, cls, kind):
    n = build(cls, kind, model).x.shape[0]
    for P0 in (np.zeros((n, n)), np.diag([0.0, 0.0] + [0.2] * (n - 2))):
        filt = build(cls, kind, model, P0=P0)
        for k in range(3):
            u, z = good_inputs(model, k)
            filt.step(u, DT, z)
        assert np.all(np.isfinite(filt.x)) and np.all(np.isfinite(filt.P))


@pytest.mark.parametrize("cls, kind", FILTERS, ids=IDS)
def test_run_reports_and_is_all_or_nothing(model, cls, kind, monkeypatch):
    T = 6
    U = np.array([good_inputs(model, k)[0] for k in range(T)])
    Z = np.array([good_inputs(model, k)[1] for k in range(T)])
    Z[2] = np.nan
    Z[3, 0] = np.nan
    filt = build(cls, kind, model)
    n_x = filt.x.shape[0]  # a contract_example may run on its own model with the same u, z, p shapes
    truth = np.zeros((T, n_x))
    result = filt.run(U, Z, DT, truth=truth)
    assert result.x.shape == (T, n_x) and result.P.shape == (T, n_x, n_x)
    for name in ("nis", "nis_dof", "nees", "ess", "particles", "step_time"):
        assert getattr(result, name).shape == (T,), name
    assert result.nis_dof[2] == 0 and np.isnan(result.nis[2])
    assert np.all(result.step_time > 0) and np.all(np.isfinite(result.nees))
    if kind == "kalman":
        assert np.all(np.isnan(result.ess)) and np.all(np.isnan(result.particles))
        assert result.nis_dof[3] == model.n_y - 1
    elif kind in ("particle", "mixture"):  # an adaptive particle number (KLD) may change N after resampling
        fixed = result.particles == N_PARTICLES if not hasattr(cls, "contract_example") else result.particles >= 1
        assert np.all(fixed) and np.all((result.ess >= 1 - 1e-9) & (result.ess <= result.particles + 1e-9))
    # a refused row: the filter is restored to its state before run and the error names the row
    filt = build(cls, kind, model)
    before = report(filt)
    original, calls = filt.step, []

    def failing_step(*args):
        calls.append(1)
        if len(calls) == 4:
            raise ValueError("injected failure")
        return original(*args)

    monkeypatch.setattr(filt, "step", failing_step)
    if hasattr(filt, "_runtime"):  # run() is one call of the C runtime: it commits rows 0-2, then row 3 is refused
        runtime, run_rows = filt._runtime, filt._runtime.kalman_run

        def failing_run(memory, model, T, *args):
            *rest, row = args
            run_rows(memory, model, 3, *rest, row)
            row._obj.value = 3
            return kr.E_DIVERGED

        monkeypatch.setattr(runtime, "kalman_run", failing_run)
    with pytest.raises(ValueError, match="row 3"):
        filt.run(U, Z, DT)
    monkeypatch.undo()
    assert_identical(before, report(filt))
    # bad arguments of run are refused before the first step
    with pytest.raises(ValueError, match="Z"):
        filt.run(U, np.where(np.isnan(Z), np.inf, Z), DT)
    with pytest.raises(ValueError, match="U"):
        filt.run(U[:, :1], Z, DT)
    assert_identical(before, report(filt))


def extreme_calls(model):
    """(description, call(filt)): finite but absurd inputs that get past the input checks and may drive a step
    out of its finite range (an overflowing input, dt, parameter or measurement)."""
    u, z = good_inputs(model, 3)
    n_u, n_y, n_p = model.n_u, model.n_y, model.n_p
    return [
        ("u = 1e308", lambda f: f.step(np.full(n_u, 1e308), DT, z)),
        ("u = -1e308 predict, dt = 1e6", lambda f: f.predict(np.full(n_u, -1e308), 1e6)),
        ("dt = 1e300", lambda f: f.step(u, 1e300, z)),
        ("p = 1e308", lambda f: f.step(u, DT, z, np.full(n_p, 1e308))),
        ("z = 1e300", lambda f: f.step(u, DT, np.full(n_y, 1e300))),
        ("last z entry 1e300", lambda f: f.step(u, DT, np.concatenate([z[:-1], [1e300]]))),
        ("z = -1e308 update", lambda f: f.update(np.full(n_y, -1e308))),
        ("z outlier 1e4", lambda f: f.step(u, DT, z + 1e4)),
    ]


EXTREMES = [d for d, _ in extreme_calls(abyssal.generated.load("linear_cv"))]


def finite_report(filt) -> list[str]:
    """The reported quantities (x, P, particles, weights, carried covariances) that are not finite."""
    return [key for key, value in report(filt).items() if key in ("x", "P", "particles", "weights", "log_weights")
            or key.startswith("carried") if value is not None and not np.all(np.isfinite(value) | (
                np.isneginf(value) if key == "log_weights" else False))]


def assert_later_steps_finite(filt, model, ks) -> None:
    """Nominal steps k in ks are each accepted with a finite report or refused (ValueError), never a raw numerical error."""
    for k in ks:
        u, z = good_inputs(model, k)
        try:
            filt.step(u, DT, z)
        except ValueError:
            continue
        assert finite_report(filt) == [], f"step {k}: non-finite {finite_report(filt)}"


#: filters of other branches that fail a rule today: (class name, rule) -> the branch that fixes it
KNOWN_FAILURES: dict[tuple[str, str], str] = {}


def _known(name, rule):
    owner = KNOWN_FAILURES.get((name, rule))
    if owner is None:
        return []
    return [pytest.mark.xfail(strict=True, reason=f"{name}: fixed on branch {owner}")]


def variants():
    """Options of registered classes that change their numerics: (id, class, builder(model))."""
    from abyssal.runtime.filters.particle.sir import CubatureParticleFilter
    from abyssal.runtime.filters.particle.unscented import UnscentedParticleFilter

    def upf(update):
        def make(model):
            x0, P0, Q, R = problem(model)
            return UnscentedParticleFilter(model, x0, P0, Q, R, N_PARTICLES, 7, update=update)
        return make

    def cpf_optimal(model):
        x0, P0, Q, R = problem(model)
        return CubatureParticleFilter(model, x0, P0, GaussianMixture.gaussian(np.zeros(model.n_x), Q),
                                      GaussianMixture.gaussian(np.zeros(model.n_y), R), N_PARTICLES, 7, proposal="optimal")

    return [("UPF", UnscentedParticleFilter, upf("ukf")), ("HRUPF", UnscentedParticleFilter, upf("huber")),
            ("CPF-optimal", CubatureParticleFilter, cpf_optimal)]


SUBJECTS = [(cls.__name__, cls, lambda model, cls=cls, kind=kind: build(cls, kind, model)) for cls, kind in FILTERS]
SUBJECTS += variants()


def _warm(make, model):
    filt = make(model)
    for k in range(2):
        u, z = good_inputs(model, k)
        filt.step(u, DT, z)
    return filt


@pytest.mark.parametrize("subject, rule", [pytest.param(name, rule, marks=_known(name, rule), id=f"{name}-{rule}")
                                           for name, _, _ in SUBJECTS for rule in EXTREMES])
def test_an_extreme_call_is_refused_unchanged_or_accepted_finite(model, subject, rule):
    """Finite in, finite out: an absurd call is either refused with a ValueError -- and then the filter,
    per-particle covariances and random state included, goes on exactly as an untouched twin -- or accepted
    with a finite x, P (particles, weights); FloatingPointError/OverflowError never escape the contract."""
    make = next(m for name, _, m in SUBJECTS if name == subject)
    call = next(c for d, c in extreme_calls(model) if d == rule)
    filt, twin = _warm(make, model), _warm(make, model)
    before = report(filt)
    try:
        call(filt)
    except ValueError:
        refused = True
    else:
        refused = False
    if refused:
        assert_identical(before, report(filt))
        for k in (4, 5, 6):  # and it goes on exactly as a filter that was never refused
            u, z = good_inputs(model, k)
            filt.step(u, DT, z)
            twin.step(u, DT, z)
            assert_identical(report(twin), report(filt))
    else:
        assert finite_report(filt) == [], f"accepted with non-finite {finite_report(filt)}"
        assert_later_steps_finite(filt, model, (4, 5, 6))


@pytest.mark.parametrize("cls, kind", [pytest.param(cls, kind, marks=_known(cls.__name__, "x0 = 1e300"), id=cls.__name__)
                                       for cls, kind in FILTERS])
def test_an_extreme_start_is_refused_or_stays_finite(model, cls, kind):
    """x0 = 1e300: refused at construction naming x0, or accepted with a finite report at every later step (each
    step accepted finite or refused with a ValueError)."""
    n = build(cls, kind, model).x.shape[0]
    try:
        filt = build(cls, kind, model, x0=np.full(n, 1e300))
    except ValueError as error:
        assert "x0" in str(error)
        return
    assert finite_report(filt) == []
    assert_later_steps_finite(filt, model, (0, 1, 2))
