"""Property-based tests of the model bundle's entry points.

For every call: a refusal is a ValueError/TypeError naming an argument that is at fault; a call
whose arguments are all acceptable returns finite arrays of the documented shape or raises
FloatingPointError (the model is not finite there); it never returns NaN/inf silently.
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, strategies as st

import abyssal.generated
from property_strategies import Drawn, all_finite, known_bug, named, seconds, vectors

MODELS = ("rov4dof", "cn2d", "linear_cv")


@pytest.fixture(scope="module", params=MODELS)
def bundle(request):
    return abyssal.generated.load(request.param)


def parameters(bundle):
    """p: None, the defaults perturbed (mostly), or anything `vectors` draws."""
    perturbed = st.lists(st.floats(0.5, 2.0), min_size=bundle.n_p, max_size=bundle.n_p).map(
        lambda f: Drawn(bundle.p_default * np.array(f)))
    return st.one_of(perturbed, perturbed, st.just(Drawn(None)), vectors(bundle.n_p, none_ok=True))


def outcome(call, args: dict[str, Drawn], check=None):
    """Call with the drawn values and assert the contract; returns the result (or None if refused)."""
    faulty = [name for name, d in args.items() if d.problem]
    try:
        result = call(*[d.value for d in args.values()])
    except (ValueError, TypeError) as error:
        assert faulty, f"refused acceptable arguments {args}: {error!r}"
        assert named(str(error), faulty), f"the error does not name any of {faulty}: {error!r}"
        return None
    except FloatingPointError as error:
        assert not faulty, f"evaluated with faulty arguments {faulty} (should be refused first): {error!r}"
        return None
    assert not faulty, f"accepted faulty arguments {[(n, args[n]) for n in faulty]}"
    results = result if isinstance(result, tuple) else (result,)
    assert all_finite(*results), f"non-finite output returned silently for {args}"
    if check is not None:
        check(result)
    return result


@given(data=st.data())
def test_f_F_G(bundle, data):
    x = data.draw(vectors(bundle.n_x), "x")
    u = data.draw(vectors(bundle.n_u), "u")
    p = data.draw(parameters(bundle), "p")
    dt = data.draw(seconds(), "dt")
    n = bundle.n_x
    outcome(bundle.f, {"x": x, "u": u, "p": p, "dt": dt}, lambda r: r.shape == (n,) or pytest.fail(r.shape))
    outcome(bundle.F, {"x": x, "u": u, "p": p, "dt": dt}, lambda r: r.shape == (n, n) or pytest.fail(r.shape))
    outcome(bundle.G, {"x": x, "u": u, "p": p, "dt": dt}, lambda r: r.shape == (n, bundle.n_w) or pytest.fail(r.shape))


@given(data=st.data())
def test_h_H_xdot_params(bundle, data):
    x = data.draw(vectors(bundle.n_x), "x")
    p = data.draw(parameters(bundle), "p")
    outcome(bundle.h, {"x": x, "p": p}, lambda r: r.shape == (bundle.n_y,) or pytest.fail(r.shape))
    outcome(bundle.H, {"x": x, "p": p}, lambda r: r.shape == (bundle.n_y, bundle.n_x) or pytest.fail(r.shape))
    u = data.draw(vectors(bundle.n_u), "u")
    w = data.draw(vectors(bundle.n_w, none_ok=True), "w")
    outcome(bundle.xdot, {"x": x, "u": u, "p": p, "w": w})
    outcome(bundle.params, {"p": p}, lambda r: r.shape == (bundle.n_p,) or pytest.fail(r.shape))


@st.composite
def state_batches(draw, bundle, rows: int, name: str):
    """(rows, N) batches: moderate entries, sometimes one awkward finite or non-finite entry, or a bad shape."""
    N = draw(st.integers(1, 5))
    A = np.array(draw(st.lists(st.floats(-10, 10), min_size=rows * N, max_size=rows * N))).reshape(rows, N)
    kind = draw(st.sampled_from(["plain", "plain", "huge", "nonfinite", "shape", "complex", "fortran"]))
    if kind == "huge":  # finite: the model may overflow there (X[4, 1] = 1e200)
        A[draw(st.integers(0, rows - 1)), draw(st.integers(0, N - 1))] = draw(st.sampled_from([1e200, -1e300, 1e308]))
    elif kind == "nonfinite":
        A[draw(st.integers(0, rows - 1)), draw(st.integers(0, N - 1))] = draw(st.sampled_from([np.nan, np.inf]))
        return Drawn(A, "non-finite entry")
    elif kind == "shape":
        return Drawn(A[:-1] if rows > 1 else A[None], "wrong shape")
    elif kind == "complex":
        return Drawn(A + 0j, "complex")
    elif kind == "fortran":
        A = np.asfortranarray(A)
    return Drawn(A)


@given(data=st.data())
def test_f_batch_h_batch(bundle, data):
    X = data.draw(state_batches(bundle, bundle.n_x, "X"), "X")
    N = np.shape(X.value)[-1]
    U = data.draw(st.one_of(vectors(bundle.n_u), st.just(Drawn(np.ones((bundle.n_u, N))))), "U")
    p = data.draw(parameters(bundle), "p")
    dt = data.draw(seconds(), "dt")
    outcome(bundle.f_batch, {"X": X, "U": U, "p": p, "dt": dt},
            lambda r: r.shape == (bundle.n_x, N) or pytest.fail(r.shape))
    outcome(bundle.h_batch, {"X": X, "p": p}, lambda r: r.shape == (bundle.n_y, N) or pytest.fail(r.shape))


def _argument(sig, data, label):
    rows, cols = sig.shape
    if cols == 1:
        value = data.draw(vectors(rows), label)
        if value.problem == "2-D" and rows == 1:
            return Drawn(value.value)  # (1, 1): the declared shape of a scalar input
        return value
    value = data.draw(vectors(rows * cols), label)
    if isinstance(value.value, np.ndarray) and value.value.size == rows * cols:
        # a flat or (1, r c) draw reshaped to the matrix: acceptable unless its entries are not
        problem = None if value.problem in (None, "2-D") else value.problem
        return Drawn(value.value.reshape(rows, cols), problem)
    return value


@given(data=st.data())
def test_every_generated_function_called_directly(bundle, data):
    name = data.draw(st.sampled_from(sorted(bundle.functions)), "function")
    fn = bundle.functions[name]
    args = {s.name: _argument(s, data, s.name) for s in fn.inputs}
    outcome(fn, args)


@given(data=st.data())
def test_every_generated_function_in_batch(bundle, data):
    name = data.draw(st.sampled_from(sorted(bundle.functions)), "function")
    fn = bundle.functions[name]
    n = data.draw(st.integers(1, 3), "n")
    args = {}
    for s in fn.inputs:
        if data.draw(st.booleans(), f"{s.name} batched"):
            rows, cols = s.shape
            shape = (rows, n) if cols == 1 else (rows, cols, n)
            A = np.array(data.draw(st.lists(st.floats(-10, 10), min_size=int(np.prod(shape)),
                                            max_size=int(np.prod(shape))), s.name)).reshape(shape)
            bad = data.draw(st.sampled_from([None] * 5 + ["nan", "huge"]), f"{s.name} fault")
            if bad == "nan":
                A.reshape(-1)[0] = np.nan
            elif bad == "huge":
                A.reshape(-1)[-1] = 1e200
            args[s.name] = Drawn(A, "non-finite entry" if bad == "nan" else None)
        else:
            shared = _argument(s, data, s.name)
            value = shared.value
            if (known_bug("batch_shared_column_refused") and isinstance(value, np.ndarray) and s.shape[1] == 1
                    and value.shape == s.shape and n > 1):
                shared = Drawn(value.reshape(-1), shared.problem)
            args[s.name] = shared
    outcome(lambda *a: fn.batch(n, *a), args)
