"""The loader (generated/bundle.py): shapes, defaults, argument errors, the fast path and batches."""
from __future__ import annotations

import numpy as np
import pytest

import abyssal.generated
from abyssal.verify.reference_models import REFERENCES


@pytest.fixture
def rng():
    return np.random.default_rng(3)


@pytest.fixture
def rov_point(rng):
    ref = REFERENCES["rov4dof"]
    return ref.sample_state(rng), ref.sample_input(rng)


def test_shapes_and_names(rov, cn):
    assert (rov.n_x, rov.n_u, rov.n_p, rov.n_w, rov.n_y) == (12, 4, 17, 8, 4)
    assert rov.state_names[:4] == ("x", "y", "z", "psi") and rov.angle_outputs == (3,)
    x, u = np.zeros(12), np.array([20.0, 0.0, 5.0, 0.0])
    assert rov.f(x, u, None, 0.1).shape == (12,)
    assert rov.F(x, u, None, 0.1).shape == (12, 12)
    assert rov.G(x, u, None, 0.1).shape == (12, 8)
    assert rov.h(x).shape == (4,)
    assert rov.H(x).shape == (4, 12)
    assert rov.xdot(x, u).shape == (12,)
    assert cn.h(np.array([3.0, 4.0])).shape == (2,)  # one range per leader sensor
    assert cn.H(np.array([3.0, 4.0])).shape == (2, 2)


def test_p_none_means_defaults(rov, rov_point):
    x, u = rov_point
    np.testing.assert_array_equal(rov.f(x, u, None, 0.1), rov.f(x, u, rov.p_default, 0.1))
    assert not rov.p_default.flags.writeable
    p = rov.params()
    p[0] = 30.0  # a copy: the defaults stay put
    assert rov.p_default[0] == 26.0
    assert not np.array_equal(rov.f(x, u, p, 0.1), rov.f(x, u, None, 0.1))  # parameters are honoured


def test_matrix_outputs_are_column_major_correct(cn):
    """H of the range is the unit vector from the leader: catches a transposed/reshaped output."""
    H = cn.H(np.array([3.0, 4.0]), np.array([0.0, 0.0, 6.0, 8.0]))
    np.testing.assert_allclose(H, [[0.6, 0.8], [-0.6, -0.8]], rtol=1e-15)
    F = cn.F(np.array([1.0, 2.0]), np.array([1.0, 0.0, 0.3]), None, 0.5)
    np.testing.assert_array_equal(F, np.eye(2))


@pytest.mark.parametrize("call, error, message", [
    (lambda b, x, u: b.f(x[:5], u, None, 0.1), ValueError, r"'x' must have shape \(12,\)"),
    (lambda b, x, u: b.f(x, u[:3], None, 0.1), ValueError, r"'u' must have shape \(4,\)"),
    (lambda b, x, u: b.f(x, u, np.ones(3), 0.1), ValueError, r"p must have shape \(17,\)"),
    (lambda b, x, u: b.f(np.where(np.arange(12) == 2, np.nan, x), u, None, 0.1), ValueError, "'x' has non-finite"),
    (lambda b, x, u: b.f(x, u, np.full(17, np.inf), 0.1), ValueError, "p has non-finite"),
    (lambda b, x, u: b.f(x, u), TypeError, "dt .* is required"),
    (lambda b, x, u: b.f(x, u, None, -0.1), ValueError, "dt must be a positive finite"),
    (lambda b, x, u: b.f(x, u, None, float("nan")), ValueError, "dt must be a positive finite"),
    (lambda b, x, u: b.functions["f"](x, u), TypeError, r"takes 4 arguments \(x, u, p, dt\)"),
    (lambda b, x, u: b.function("no_such"), KeyError, "has no generated function 'no_such'"),
    (lambda b, x, u: b.f_batch(x, u, None, 0.1), ValueError, r"X must have shape \(12, N\)"),
    (lambda b, x, u: b.f_batch(np.zeros((12, 5)), np.zeros((4, 4)), None, 0.1), ValueError, "U must have shape"),
])
def test_bad_arguments_give_clear_errors(rov, rov_point, call, error, message):
    x, u = rov_point
    with pytest.raises(error, match=message):
        call(rov, x, u)


def test_unknown_model_name():
    with pytest.raises(KeyError, match="no generated model 'no_such_vehicle'.*available"):
        abyssal.generated.load("no_such_vehicle")


def fast_buffers(bundle, x, u, dt=0.1):
    return [np.array(x, dtype=float), np.array(u, dtype=float), bundle.params(), np.array([dt])]


@pytest.mark.parametrize("bad, message", [
    (lambda ins: [ins[0].astype(np.float32), *ins[1:]], "float64"),
    (lambda ins: [ins[0].tolist(), *ins[1:]], "float64 numpy array"),
    (lambda ins: [ins[0][:11].copy(), *ins[1:]], "expected 12 elements"),
    (lambda ins: [np.zeros(24)[::2], *ins[1:]], "contiguous"),
])
def test_bind_rejects_bad_input_buffers(rov, rov_point, bad, message):
    ins = fast_buffers(rov, *rov_point)
    with pytest.raises((TypeError, ValueError), match=message):
        rov.functions["f"].bind(bad(ins), [np.zeros(12)])


def test_bind_rejects_c_ordered_matrix_output(rov, rov_point):
    ins = fast_buffers(rov, *rov_point)
    with pytest.raises(ValueError, match="Fortran-ordered array of shape \\(12, 12\\)"):
        rov.functions["F"].bind(ins, [np.zeros((12, 12))])
    with pytest.raises(ValueError, match="expected 1 outputs|expected 4 inputs"):
        rov.functions["F"].bind(ins[:3], [np.zeros((12, 12), order="F")])


def test_fast_path_equals_convenience_path(rov, rov_point):
    x, u = rov_point
    ins = fast_buffers(rov, x, u)
    for name, expected in (("f", rov.f(x, u, None, 0.1)), ("F", rov.F(x, u, None, 0.1)),
                           ("G", rov.G(x, u, None, 0.1))):
        out = np.zeros(expected.shape, order="F")
        binding = rov.functions[name].bind(ins, [out])
        binding()
        np.testing.assert_array_equal(out, expected)
    out = np.zeros((4, 12), order="F")
    binding = rov.functions["H"].bind([ins[0], ins[2]], [out])
    binding.eval()
    np.testing.assert_array_equal(out, rov.H(x))


def test_fast_path_reads_buffers_in_place(rov, rov_point):
    """Changing a bound input buffer changes the next evaluation: no copies are taken."""
    x, u = rov_point
    ins, out = fast_buffers(rov, x, u), np.zeros(12)
    binding = rov.functions["f"].bind(ins, [out])
    binding()
    first = out.copy()
    ins[0][:] = rov.f(x, u, None, 0.1)
    binding()
    np.testing.assert_array_equal(first, ins[0])
    np.testing.assert_array_equal(out, rov.f(first, u, None, 0.1))


@pytest.mark.parametrize("per_column_u", [False, True], ids=["u shared", "u per column"])
def test_batches_equal_single_calls(rov, rng, per_column_u):
    ref, n = REFERENCES["rov4dof"], 37
    X = ref.sample_state(rng, n)
    U = ref.sample_input(rng, n) if per_column_u else ref.sample_input(rng)
    single = np.column_stack([rov.f(X[:, j], U[:, j] if per_column_u else U, None, 0.1) for j in range(n)])
    # _batch entry point: the same scalar C per column, bitwise equal
    Y = np.zeros((12, n), order="F")
    rov.functions["f"].bind_batch([np.asfortranarray(X), np.asfortranarray(U), rov.params(), np.array([0.1])], [Y],
                                  capacity=n)(n)
    np.testing.assert_array_equal(Y, single)
    # SIMD kernel: libmvec sin/cos may differ in the last bit
    np.testing.assert_allclose(rov.f_batch(X, U, None, 0.1), single, rtol=0, atol=1e-13)
    np.testing.assert_allclose(rov.functions["f"].batch(n, X, U, rov.params(), 0.1), single, rtol=0, atol=0)
    np.testing.assert_allclose(rov.h_batch(X), X[:4], rtol=0, atol=0)


def test_bind_batch_rejects_bad_layouts_and_sizes(rov, rng):
    n = 8
    X = np.asfortranarray(REFERENCES["rov4dof"].sample_state(rng, n))
    args = [X, np.zeros(4), rov.params(), np.array([0.1])]
    with pytest.raises(ValueError, match="Fortran-ordered"):
        rov.functions["f"].bind_batch([np.ascontiguousarray(X), *args[1:]], [np.zeros((12, n), order="F")], capacity=n)
    with pytest.raises(ValueError, match="N >= 8"):
        rov.functions["f"].bind_batch([X[:, :4].copy(order="F"), *args[1:]], [np.zeros((12, n), order="F")], capacity=n)
    with pytest.raises(ValueError, match="one slice per column"):
        rov.functions["f"].bind_batch(args, [np.zeros(12)], capacity=n)
    binding = rov.functions["f"].bind_batch(args, [np.zeros((12, n), order="F")], capacity=n)
    with pytest.raises(ValueError, match="outside 0..8"):
        binding(n + 1)


def test_bind_soa_rejects_fortran_batches(rov, rng):
    X = np.asfortranarray(REFERENCES["rov4dof"].sample_state(rng, 8))
    with pytest.raises(ValueError, match="C-ordered"):
        rov.functions["f"].bind_soa([X, np.zeros((4, 8)), rov.params(), np.array([0.1])], [np.zeros((12, 8))])
    with pytest.raises(ValueError, match="no structure-of-arrays kernel"):
        rov.functions["F"].bind_soa([], [])


def test_eval_outlives_its_binding():
    """`fn.bind(...).eval` kept alone must stay valid (it once pointed at a freed buffer: a segfault).
    Run in a child process so a crash is a test failure, not the end of the session."""
    import subprocess
    import sys
    import textwrap

    script = textwrap.dedent("""
        import gc
        import numpy as np
        import abyssal.generated
        cn = abyssal.generated.load("cn2d")
        x, u, out = np.array([1.0, 2.0]), np.array([1.0, 0.0, 0.0]), np.zeros(2)
        step = cn.functions["f"].bind([x, u, cn.params(), np.array([0.5])], [out]).eval
        gc.collect()
        for _ in range(1000):
            np.zeros(64)  # churn the allocator
        step()
        assert np.array_equal(out, [1.5, 2.0]), out
        print("ok")
    """)
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0 and res.stdout.strip() == "ok", res.stderr[-2000:]


# ------------------------------------------------------------------ batch outputs, complex, buffers
def overflowing_batch(rov, rng, n=6, bad=(1, 4)):
    """States whose step overflows at the columns `bad` (a surge speed of 1e200: quadratic damping)."""
    X = REFERENCES["rov4dof"].sample_state(rng, n)
    X[4, list(bad)] = 1e200
    return X


def test_batch_outputs_are_checked_like_single_calls(rov, rng):
    X, u = overflowing_batch(rov, rng), np.array([20.0, 0.0, 5.0, 0.0])
    with pytest.raises(FloatingPointError, match="output 'x_next' is not finite"):
        rov.f(X[:, 1], u, None, 0.1)
    with pytest.raises(FloatingPointError, match=r"f_batch: output 'x_next' is not finite in column\(s\) 1, 4 of 6"):
        rov.f_batch(X, u, None, 0.1)
    with pytest.raises(FloatingPointError, match=r"rov4dof_f batch: output 'x_next' is not finite in column\(s\) 1, 4 of 6"):
        rov.functions["f"].batch(6, X, u, rov.params(), 0.1)
    with pytest.raises(FloatingPointError, match=r"rov4dof_F batch: output .* column\(s\) 1, 4 of 6"):
        rov.functions["F"].batch(6, X, u, rov.params(), 0.1)  # a matrix output: (12, 12, N)
    good = np.delete(X, [1, 4], axis=1)
    np.testing.assert_array_equal(rov.f_batch(good, u, None, 0.1)[:, 0], rov.f_batch(X[:, [0]], u, None, 0.1)[:, 0])


def test_h_batch_output_check_names_columns(cn):
    """cn2d's range Jacobian divides by the range: the leader's own position gives NaN in H."""
    leader = np.array([3.0, 4.0, 10.0, 10.0])  # leader0 at (3, 4), leader1 at (10, 10)
    X = np.array([[0.0, 3.0, 1.0], [0.0, 4.0, 1.0]])
    with pytest.raises(FloatingPointError, match=r"output .* not finite in column\(s\) 1 of 3"):
        cn.functions["H"].batch(3, X, leader)
    with pytest.raises(FloatingPointError, match="not finite at the given arguments"):
        cn.H(X[:, 1], leader)
    np.testing.assert_allclose(cn.h_batch(X, leader), [[5.0, 0.0, np.hypot(2.0, 3.0)],  # h itself is finite there
                                                       [np.hypot(10.0, 10.0), np.hypot(7.0, 6.0), np.hypot(9.0, 9.0)]])


def test_an_overflowing_sum_of_finite_outputs_is_not_an_error(rov):
    """The check's fast path sums the outputs; a sum that overflows must fall back to the exact check."""
    from abyssal.generated.bundle import _finite_columns

    n = 1 << 15  # large enough for the summing fast path
    huge = np.full((4, n), 1e308)
    _finite_columns("test", [huge], rov.functions["h"].outputs, n)  # no error
    huge[2, 3] = np.inf
    huge[0, 7] = -np.inf  # inf - inf: the sum is NaN
    with pytest.raises(FloatingPointError, match=rf"column\(s\) 3, 7 of {n}"):
        _finite_columns("test", [huge], rov.functions["h"].outputs, n)


@pytest.mark.parametrize("call", [
    lambda b, x, u: b.f(x.astype(complex), u, None, 0.1),
    lambda b, x, u: b.f(x, list(u + 0j), None, 0.1),
    lambda b, x, u: b.f(x, u, b.params() + 0j, 0.1),
    lambda b, x, u: b.f(x, u, None, np.complex128(0.1)),
    lambda b, x, u: b.h(np.array(list(x + 1j), dtype=object)),
    lambda b, x, u: b.xdot(x, u, None, np.zeros(b.n_w, dtype=complex)),
    lambda b, x, u: b.f_batch(np.tile(x, (3, 1)).T.astype(complex), u, None, 0.1),
    lambda b, x, u: b.f_batch(np.tile(x, (3, 1)).T, u.astype(np.complex64), None, 0.1),
    lambda b, x, u: b.h_batch(np.tile(x, (3, 1)).T + 0j),
    lambda b, x, u: b.functions["f"].batch(3, np.tile(x, (3, 1)).T + 0j, u, b.params(), 0.1),
    lambda b, x, u: b.functions["h"](x.astype(np.complex64), b.params()),
], ids=["f x", "f u list", "f p", "f dt", "h object", "xdot w", "f_batch X", "f_batch U", "h_batch", "fn.batch", "fn()"])
def test_complex_arrays_are_refused(rov, rov_point, call):
    import warnings

    x, u = rov_point
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no ComplexWarning: refused before any cast
        with pytest.raises(TypeError, match="complex|real"):
            call(rov, x, u)


def test_bind_batch_refuses_a_non_contiguous_shared_input(rov, rng):
    """A private copy would never see later writes to the caller's array: refuse it like bind does."""
    n = 4
    X = np.asfortranarray(REFERENCES["rov4dof"].sample_state(rng, n))
    strided_u = np.zeros(8)[::2]
    with pytest.raises(ValueError, match="'u': buffer must be contiguous"):
        rov.functions["f"].bind_batch([X, strided_u, rov.params(), np.array([0.1])], [np.zeros((12, n), order="F")],
                                      capacity=n)
    # a contiguous shared input is bound in place: writes are seen by the next evaluation
    u, Y = np.zeros(4), np.zeros((12, n), order="F")
    binding = rov.functions["f"].bind_batch([X, u, rov.params(), np.array([0.1])], [Y], capacity=n)
    u[:] = [20.0, 0.0, 5.0, 0.0]
    binding(n)
    np.testing.assert_array_equal(Y[:, 0], rov.f(X[:, 0], u, None, 0.1))


def test_read_only_outputs_are_refused_naming_the_output(rov):
    f = rov.functions["f"]
    ins = [np.zeros(12), np.zeros(4), rov.params(), np.array([0.1])]

    def read_only(shape, order="C"):
        arr = np.zeros(shape, order=order)
        arr.setflags(write=False)
        return arr

    for bind in (lambda: f.bind(ins, [read_only(12)]),
                 lambda: f.bind_batch([np.zeros((12, 3), order="F"), *ins[1:]], [read_only((12, 3), "F")], capacity=3),
                 lambda: f.bind_soa([np.zeros((12, 3)), np.zeros((4, 3)), *ins[2:]], [read_only((12, 3))])):
        with pytest.raises(ValueError, match="output 'x_next': buffer is read-only"):
            bind()
    f.bind(ins[:2] + [rov.p_default, ins[3]], [np.zeros(12)])()  # read-only inputs are fine
