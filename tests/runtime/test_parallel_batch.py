"""ParallelBatch (runtime/compiled/batches.py): a split over the pool and one serial call give the same
bits, and a batch whose serial work is estimated below SPLIT_MIN_SECONDS never touches the pool."""
from __future__ import annotations

import numpy as np
import pytest

from abyssal.generated import load
from abyssal.runtime.compiled import batches
from abyssal.runtime.compiled.batches import ParallelBatch
from abyssal.runtime.compiled.kalman import BatchStep


def _batch(n=300):
    """cn2d's ukf_predict over a cloud of n particle states and covariances (the UPF's batch)."""
    fn = BatchStep(load("cn2d"), "ukf_predict")
    rng = np.random.default_rng(0)
    x = np.asfortranarray(rng.normal([100.0, -50.0], 20.0, (n, 2)).T)
    A = rng.normal(0, 3.0, (n, 2, 2))
    P = np.asfortranarray(np.moveaxis(A @ np.swapaxes(A, 1, 2) + np.eye(2), 0, -1))
    inputs = [x, P, np.array([1.5, 0.1, 0.3]), np.array([400.0, 300.0, -200.0, 100.0]), np.array([5.0]),
              np.diag([100.0, 100.0]).reshape(-1, order="F"), np.array([1.0, 0.0, 1.0])]
    outputs = [np.zeros((s.shape[0], n) if s.shape[1] == 1 else (*s.shape, n), order="F") for s in fn.outputs]
    return ParallelBatch(fn, inputs, [True, True] + [False] * 5, outputs, n), outputs


def test_split_and_serial_evaluations_are_bit_identical(monkeypatch):
    split, split_out = _batch()
    serial, serial_out = _batch()
    if len(split._chunks) < 2:
        pytest.skip("one core: ParallelBatch never splits")
    submitted = []
    real_pool = batches._pool()
    monkeypatch.setattr(batches, "_pool", lambda: submitted.append(1) or real_pool)
    split.slice_seconds = 1.0        # estimated expensive: split
    serial.slice_seconds = 0.0       # estimated free: one serial call
    split(300)
    assert submitted, "an expensive batch was not split"
    submitted.clear()
    serial(300)
    assert not submitted, "a cheap batch went through the thread pool"
    for a, b in zip(split_out, serial_out):
        assert a.any()
        np.testing.assert_array_equal(a, b)


def test_the_first_call_measures_the_serial_cost(monkeypatch):
    batch, _ = _batch()
    if len(batch._chunks) < 2:
        pytest.skip("one core: ParallelBatch never splits")
    monkeypatch.setattr(batches, "_pool", lambda: pytest.fail("the first call must run serially"))
    assert batch.slice_seconds is None
    batch(300)
    assert batch.slice_seconds is not None and batch.slice_seconds > 0
