"""The innovation gate of every Kalman-type filter (runtime/filters/kalman/gate.py), on each registered one."""
from __future__ import annotations

import numpy as np
import pytest

import abyssal.generated
from abyssal.runtime import contract
from abyssal.runtime.filters.kalman.gate import InnovationGate

KALMAN = sorted((cls for cls, kind in contract.registered_filters().items() if kind == "kalman"), key=lambda c: c.__name__)


def build(cls, model):
    if hasattr(cls, "contract_example"):
        return cls.contract_example(model)
    n, m = model.n_x, model.n_y
    return cls(model, np.zeros(n), np.eye(n), 0.01 * np.eye(n), 0.5 * np.eye(m))


@pytest.mark.parametrize("cls", KALMAN, ids=[c.__name__ for c in KALMAN])
def test_an_outlier_entry_is_gated_and_the_rest_used(cls):
    model = abyssal.generated.load("linear_cv")
    filt, twin = build(cls, model), build(cls, model)
    u = np.zeros(model.n_u)
    dt = getattr(filt, "gp_dt", 0.5)
    for f in (filt, twin):
        f.step(u, dt, np.zeros(model.n_y))
    z = np.zeros(model.n_y)
    z[0] = 1e4  # ~1e4 standard deviations away: gated; the other entry is used
    only_rest = np.full(model.n_y, np.nan)
    only_rest[1:] = 0.0
    assert filt.step(u, dt, z) is True
    twin.step(u, dt, only_rest)
    if cls.__name__ == "MCUKF":  # the correntropy update absorbs the outlier itself (its S grows): nothing to gate
        assert filt.gated == 0 and np.abs(filt.x - twin.x).max() < 0.1
        return
    assert filt.gated == 1 and filt.nis_dof == model.n_y - 1
    np.testing.assert_allclose(filt.x, twin.x, rtol=0, atol=1e-9)  # as if the entry had been missing
    assert filt.step(u, dt, np.full(model.n_y, 1e4)) is False and filt.gated == 1 + model.n_y  # every entry gated
    twin.step(u, dt)
    np.testing.assert_allclose(filt.x, twin.x, rtol=0, atol=1e-9)  # the predict stands


def test_an_entry_gated_patience_times_in_a_row_inflates_and_is_reacquired():
    R = np.eye(2)
    gate = InnovationGate(R, probability=1e-10, patience=3, inflation=4.0)
    present, gated = np.ones(2, bool), np.array([True, False])
    assert [gate.note(gated, present) for _ in range(4)] == [False, False, True, True]
    assert gate.inflations == 2 and gate.gated == 4
    saved = gate.checkpoint()
    assert gate.note(np.zeros(2, bool), present) is False  # passed: the streak ends
    assert gate.note(gated, present) is False
    gate.restore(saved)  # the checkpoint holds the streak
    assert gate.note(gated, present) is True and gate.gated == 5


def test_gate_off_passes_everything_and_options_are_checked():
    gate = InnovationGate(np.eye(1), probability=0.0)
    assert gate.passes(np.array([1e150]), np.eye(1), 1)
    for options in ({"probability": 1.0}, {"patience": 0}, {"inflation": 0.5}):
        with pytest.raises(ValueError, match="gate_"):
            InnovationGate(np.eye(1), **options)
