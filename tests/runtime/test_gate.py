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
    for options in ({"probability": 1.0}, {"patience": 0}, {"inflation": 0.5}, {"max_inflations": -1},
                    {"max_inflations": 2.5}):
        with pytest.raises(ValueError, match="gate_"):
            InnovationGate(np.eye(1), **options)


def test_the_inflation_is_along_a_stuck_entry_while_others_pass_whole_when_none_does_and_capped():
    """InnovationGate.inflated, the Kalman runtime's rule: the reduction's direction while another entry is accepted
    in the streak, the whole P when none is, at most max_inflations per streak (then held), the count ending with the
    streak; a checkpoint holds it."""
    gate = InnovationGate(np.eye(2), probability=1e-10, patience=2, inflation=4.0, max_inflations=3)
    P = np.diag([1.0, 2.0, 3.0])
    along = np.zeros((3, 3))
    along[0, 0] = 0.5
    present, stuck, accepted = np.ones(2, bool), np.array([True, False]), np.array([False, True])
    asked = []
    out = [gate.inflated(P, stuck, present, accepted, lambda e: asked.append(e.copy()) or along) for _ in range(6)]
    assert out[0] is P  # streak 1 < patience
    for k in range(1, 4):  # inflated along entry 0: P + 3 x its reduction
        np.testing.assert_array_equal(out[k], P + 3.0 * along)
    assert out[4] is P and out[5] is P and gate.held == 2 and gate.inflations == 3  # capped: held
    assert all(e.tolist() == [True, False] for e in asked)
    saved = gate.checkpoint()
    gate.inflated(P, np.zeros(2, bool), present, present, None)  # both pass: the streak and its count end
    assert gate.inflated(P, np.ones(2, bool), present, None, None) is P  # a new streak, nothing accepted ...
    np.testing.assert_array_equal(gate.inflated(P, np.ones(2, bool), present, None, None), 4.0 * P)  # ... whole P
    gate.restore(saved)
    assert gate.held == 2 and gate.inflated(P, stuck, present, accepted, lambda e: along) is P  # still capped
    assert gate.inflated(np.full((3, 3), 1e308), np.ones(2, bool), present, None, None)[0, 0] == 1e308  # not finite: kept
    whole = InnovationGate(np.eye(2), patience=1, along=False)  # a filter whose predict forgets P: always whole
    np.testing.assert_array_equal(whole.inflated(P, stuck, present, accepted, None), 4.0 * P)


@pytest.mark.parametrize("cls", KALMAN, ids=[c.__name__ for c in KALMAN])
def test_an_entry_stuck_far_out_leaves_the_others_states_alone_and_is_held_after_the_cap(cls):
    """linear_cv (positions measured, x y axes independent): z[0] stuck 1e6 m off for 40 updates (beyond what 10
    inflations by 4 can re-acquire). Every filter keeps
    the y axis's states as a twin that never sees z[0] (the inflation is along x only), and inflates at most
    gate_max_inflations (10) times in the streak."""
    model = abyssal.generated.load("linear_cv")
    filt, twin = build(cls, model), build(cls, model)
    u = np.zeros(model.n_u)
    dt = getattr(filt, "gp_dt", 0.5)
    rng = np.random.default_rng(3)
    for k in range(40):
        z = 0.3 * rng.standard_normal(model.n_y)
        twin_z = z.copy()
        twin_z[0] = np.nan
        z[0] = 1e6
        filt.step(u, dt, z)
        twin.step(u, dt, twin_z)
    if cls.__name__ == "MCUKF":  # the correntropy update absorbs the outlier itself: nothing to gate
        return
    gate = getattr(filt, "gate", None)
    inflations = gate.inflations if isinstance(gate, InnovationGate) and not hasattr(filt, "inflations") else filt.inflations
    assert filt.gated == 40 and inflations == 10
    if cls.__name__ == "GPUKF":  # its predict forgets P: it inflates the whole P (gate.py)
        assert filt.gate.along is False
        return
    y_axis = [1, 3]  # (px, py, vx, vy)
    np.testing.assert_allclose(filt.x[y_axis], twin.x[y_axis], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(filt.P[np.ix_(y_axis, y_axis)], twin.P[np.ix_(y_axis, y_axis)], rtol=1e-9, atol=1e-12)
