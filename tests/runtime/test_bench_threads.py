"""The OpenMP batch of the threads bench section (runtime/checks/bench_threads.py) computes what the
generated serial ``_batch`` and ParallelBatch compute, bit for bit, and reports the first failing slice."""
from __future__ import annotations

import ctypes

import numpy as np
import pytest

from abyssal.runtime.checks import bench_threads as bt
from abyssal.runtime.compiled.batches import ParallelBatch


@pytest.fixture(scope="module")
def omp(tmp_path_factory):
    try:
        path = bt.build_omp_library(tmp_path_factory.mktemp("omp"))
    except bt.OpenMPUnavailable as exc:
        pytest.skip(f"the C compiler does not build OpenMP: {exc}")
    return bt.load_omp_library(path)


def test_team_has_the_threads_asked_for(omp):
    assert omp.omp_team_size(1) == 1
    assert omp.omp_team_size(2) == 2


def _outputs(fn, n):
    return bt._zeros_like_outputs(fn, n)


@pytest.mark.parametrize("name", ["cn2d_ukf_predict", "cn2d_ukf_update"])
def test_openmp_batch_equals_serial_and_parallel_batch(omp, name):
    fn, inputs, batched = bt.cn_inputs(257)[name]
    n = 257
    serial, futures = _outputs(fn, n), _outputs(fn, n)
    fn.bind_batch(inputs, serial, n)(n)
    ParallelBatch(fn, inputs, batched, futures, n)(n)
    assert all(a.any() for a in serial[:2])  # a real result, not untouched zeros
    for threads in (1, 2, 3):
        got = _outputs(fn, n)
        bt.OmpBatch(omp, fn, fn.bind_batch(inputs, got, n), threads)(n)
        for a, b, c in zip(serial, futures, got):
            np.testing.assert_array_equal(c, a)
            np.testing.assert_array_equal(c, b)
    part = _outputs(fn, n)  # N below capacity: slices beyond it are left alone
    bt.OmpBatch(omp, fn, fn.bind_batch(inputs, part, n), 2)(100)
    np.testing.assert_array_equal(part[0][:, :100], serial[0][:, :100])
    assert not part[0][:, 100:].any()


def test_openmp_batch_equals_serial_on_the_cpf_step(omp):
    fn, inputs, batched = bt.rov_step_inputs(130, steps=5)
    row = bt.compare_batches(omp, fn, inputs, batched, 130)  # raises unless bit-identical
    assert row["identical"]


def test_first_failing_slice_is_reported(omp):
    n = 200
    x = np.arange(n, dtype=float)
    x[[37, 150]] = -1.0
    y = np.full(n, np.nan)
    fn = ctypes.cast(omp.omp_test_fail_if_negative, ctypes.c_void_p)
    arg, arg_step = (ctypes.c_void_p * 1)(x.ctypes.data), (ctypes.c_longlong * 1)(1)
    res, res_step = (ctypes.c_void_p * 1)(y.ctypes.data), (ctypes.c_longlong * 1)(1)
    sizes = [ctypes.c_longlong(v) for v in (1, 1, 0, 0, 1, 1)]
    for threads in (1, 2, 3):
        y[:] = np.nan
        status = omp.omp_batch(fn, *sizes, ctypes.c_longlong(n), arg, arg_step, res, res_step, ctypes.c_int(threads))
        assert status == 1 + 37
        np.testing.assert_array_equal(y, x)  # every slice evaluated, also after the failure
    x[[37, 150]] = 1.0
    assert omp.omp_batch(fn, *sizes, ctypes.c_longlong(n), arg, arg_step, res, res_step, ctypes.c_int(2)) == 0


def test_swapped_parallel_batch_gives_the_same_filter(omp, cn):
    from abyssal.runtime.experiments.cn import scenario
    from abyssal.runtime.filters.particle.unscented import UnscentedParticleFilter

    trial = scenario.simulate(scenario.CnScenario(), "gaussian", np.random.default_rng(11))
    Q, R = np.diag([100.0, 100.0]), np.array([[0.1]])
    init = ParallelBatch.__init__
    shipped = UnscentedParticleFilter(cn, trial.x0, trial.P0, Q, R, 150, 3)
    with bt.openmp_parallel_batch(omp):
        swapped = UnscentedParticleFilter(cn, trial.x0, trial.P0, Q, R, 150, 3)
    assert ParallelBatch.__init__ is init
    assert type(shipped._predict) is ParallelBatch
    assert isinstance(swapped._predict, bt.OpenMPParallelBatch) and isinstance(swapped._update, bt.OpenMPParallelBatch)
    for k in range(8):
        for f in (shipped, swapped):
            f.step(trial.U[k], trial.dt, trial.Z[k], trial.params[k])
        np.testing.assert_array_equal(swapped.mean, shipped.mean)
        np.testing.assert_array_equal(swapped.cov, shipped.cov)
