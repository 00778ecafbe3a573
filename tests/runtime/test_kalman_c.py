"""Python's Kalman filters and innovation gate over the C runtime (runtime/c): options refused with a message
naming them, no NumPy warnings on extreme inputs, and the gate's rule equal to a NumPy transcription of it."""
from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.stats import chi2

import abyssal.generated
from abyssal.runtime import CKF, EKF, MCUKF, UKF, HuberUKF
from abyssal.runtime.filters.kalman.gate import InnovationGate


@pytest.fixture(scope="module")
def rov():
    return abyssal.generated.load("rov4dof")


def make(cls, rov, **options):
    n = rov.n_x
    return cls(rov, np.full(n, 0.5), 0.2 * np.eye(n), 1e-3 * np.eye(n), np.diag([0.1, 0.1, 0.05, 0.01]), **options)


@pytest.mark.parametrize("options, name", [({"alpha": 1e200}, "alpha"), ({"alpha": float("nan")}, "alpha"),
                                           ({"kappa": -12.0}, "kappa"), ({"beta": float("inf")}, "beta")])
def test_sigma_point_options_are_refused_naming_them(rov, options, name):
    with pytest.raises(ValueError, match=name):
        make(UKF, rov, **options)


@pytest.mark.parametrize("cls, options, name", [
    (MCUKF, {"sigma": 0.0}, "sigma"), (HuberUKF, {"gamma": -1.0}, "gamma"), (CKF, {"gate_probability": 1.0}, "gate_"),
    (EKF, {"gate_inflation": 0.5}, "gate_"), (CKF, {"growth_limit": 0.5}, "growth_limit"),
    (CKF, {"max_substeps": 0}, "max_substeps"),
])
def test_options_are_refused_naming_them(rov, cls, options, name):
    with pytest.raises(ValueError, match=name):
        make(cls, rov, **options)


@pytest.mark.parametrize("cls", [EKF, UKF, CKF, MCUKF, HuberUKF])
def test_extreme_innovations_raise_no_numpy_warning(rov, cls):
    """Gross outliers up to 1e300 and huge states: gated or refused, never an overflow warning (the gate's
    arithmetic is C; a NumPy dot product overflowed here before)."""
    flt = make(cls, rov)
    tau = np.array([5.0, 1.0, 2.0, 0.1])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for size in (1e6, 1e150, 1e300):
            flt.step(tau, 0.1, np.array([size, 0.5, -size, 0.5]))
            assert np.all(np.isfinite(flt.x)) and np.all(np.isfinite(flt.P))
        assert flt.gated >= 4
        huge = make(cls, rov)
        huge.reset(np.full(rov.n_x, 1e150), 1e290 * np.eye(rov.n_x))
        try:
            huge.step(tau, 0.1, np.full(4, 1e150))
        except ValueError:
            pass


# ------------------------------------------------------------------ the gate against a NumPy transcription
class NumpyGate:
    """The gate's rule written with NumPy (the oracle of this test): chi-square quantiles from scipy, the NIS by
    a linear solve."""

    def __init__(self, m, probability, patience, inflation):
        self.thresholds = np.concatenate([[np.inf], chi2.isf(probability, np.arange(1, m + 1))])
        self.patience, self.inflation = patience, inflation
        self.gated = self.inflations = 0
        self.streak = np.zeros(m, dtype=int)

    def passes(self, nu, S, dof):
        with np.errstate(all="ignore"):
            nis = float(nu @ np.linalg.solve(S, nu))
        return bool(np.isfinite(nis) and nis <= self.thresholds[dof])

    def select(self, evaluate, present):
        gated = np.zeros_like(present)
        for _ in range(2):
            nu, S = evaluate(present)
            if self.passes(nu, S, int(present.sum())):
                return present, gated
            with np.errstate(all="ignore"):
                outliers = present & ~(nu * nu <= self.thresholds[1] * np.diag(S))
            if not outliers.any() or outliers.sum() == present.sum():
                break
            gated, present = gated | outliers, present & ~outliers
        return None, gated | present

    def note(self, gated, present):
        self.gated += int(gated.sum())
        self.streak[present & ~gated] = 0
        self.streak[gated] += 1
        if gated.any() and self.streak.max() >= self.patience:
            self.inflations += 1
            return True
        return False


def test_the_gate_equals_its_numpy_transcription():
    rng = np.random.default_rng(4)
    m = 5
    ours, theirs = InnovationGate(np.eye(m), patience=3), NumpyGate(m, 1e-10, 3, 4.0)
    np.testing.assert_allclose(ours.thresholds, theirs.thresholds, rtol=1e-12)
    for trial in range(300):
        B = rng.normal(size=(m, m))
        S0 = B @ B.T + np.eye(m)
        nu0 = rng.normal(size=m) * np.where(rng.random(m) < 0.3, 10.0 ** rng.uniform(0, 8, m), 1.0)
        present = rng.random(m) < 0.85

        def evaluate(entries, nu0=nu0, S0=S0):  # an "update" over the entries: unused rows as the generated code has
            nu = np.where(entries, nu0, 0.0)
            S = np.where(np.outer(entries, entries), S0, 0.0) + np.diag(~entries * 1.0)
            return nu, S

        a, b = ours.select(evaluate, present.copy()), theirs.select(evaluate, present.copy())
        assert (a[0] is None) == (b[0] is None), trial
        if a[0] is not None:
            assert np.array_equal(a[0], b[0]), trial
        assert np.array_equal(a[1], b[1]), trial
        assert ours.note(a[1], present) == theirs.note(b[1], present), trial
        assert (ours.gated, ours.inflations) == (theirs.gated, theirs.inflations), trial
        assert ours.streaking == bool(theirs.streak.any())
    assert ours.inflations > 0 and ours.gated > 0  # the trials exercised both


def test_a_gate_checkpoint_holds_its_streaks():
    gate = InnovationGate(np.eye(2), patience=2)
    present, gated = np.ones(2, bool), np.array([True, False])
    gate.note(gated, present)
    saved = gate.checkpoint()
    assert gate.note(gated, present) is True
    gate.restore(saved)
    assert gate.inflations == 0 and gate.gated == 1 and gate.streaking
    assert gate.note(gated, present) is True
