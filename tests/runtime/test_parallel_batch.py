"""ParallelBatch (runtime/compiled/batches.py): a split over the pool and one serial call give the same
bits, and a batch whose serial work is estimated below SPLIT_MIN_SECONDS never touches the pool."""
from __future__ import annotations

import numpy as np
import pytest

from abyssal.runtime.checks import bench_threads as bt
from abyssal.runtime.compiled import batches
from abyssal.runtime.compiled.batches import ParallelBatch


def _batch(n=300):
    fn, inputs, batched = bt.cn_inputs(n)["cn2d_ukf_predict"]
    outputs = bt._zeros_like_outputs(fn, n)
    return ParallelBatch(fn, inputs, batched, outputs, n), outputs


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
