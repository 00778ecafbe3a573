"""The shared numerical helpers (runtime/numerics.py) against direct computations."""
from __future__ import annotations

import numpy as np

from abyssal.runtime.numerics import NEES_FLOOR, nees


def test_nees_equals_the_quadratic_form_on_well_conditioned_covariances():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(20, 5, 5))
    P = A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(5)
    e = rng.normal(size=(20, 5))
    direct = np.array([e[t] @ np.linalg.solve(P[t], e[t]) for t in range(20)])
    np.testing.assert_allclose(nees(e, P), direct, rtol=1e-10)


def test_nees_of_a_collapsed_particle_covariance_is_never_negative_and_counts_the_collapse():
    rng = np.random.default_rng(2)
    # a particle cloud that collapsed onto 2 of 6 dimensions: rank 2, rounding noise elsewhere
    cloud = np.zeros((6, 50))
    cloud[:2] = rng.normal(size=(2, 50))
    P = np.cov(cloud) + 1e-19 * rng.normal(size=(6, 6))
    e_inside = np.r_[0.3, -0.2, 1e-9, 1e-9, 1e-9, 1e-9]  # rounding-size errors off the cloud's plane
    e_outside = np.r_[0.0, 0.0, 1e-3, 0.0, 0.0, 0.0]
    values = nees(np.stack([e_inside, e_outside]), np.stack([P, P]))
    assert np.all(values >= 0) and np.all(np.isfinite(values))
    np.testing.assert_allclose(values[0], e_inside[:2] @ np.linalg.solve(P[:2, :2], e_inside[:2]), rtol=1e-4)
    largest = np.linalg.eigvalsh(P).max()
    assert values[1] > 0.5 * 1e-6 / (NEES_FLOOR * largest)  # an error where the filter claims certainty is huge
    # np.linalg.solve on the same matrix (the former definition): negative here (-21), what the floor replaces
    raw = e_inside @ np.linalg.solve(P, e_inside)
    assert raw < 0 or raw > 1e6 * values[0]


def test_nees_of_a_zero_covariance_is_inf_where_the_error_is_not_zero_and_warns_nothing():
    import warnings

    P = np.zeros((2, 2, 2))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no RuntimeWarning (overflow) escapes
        values = nees(np.array([[10.0, 0.0], [0.0, 0.0]]), P)
    assert values[0] == np.inf and values[1] == 0.0


def test_nees_of_a_non_finite_step_is_nan_and_leaves_the_others():
    P = np.stack([np.eye(3), np.full((3, 3), np.nan), np.eye(3)])
    e = np.array([[1.0, 0, 0], [1.0, 0, 0], [np.inf, 0, 0]])
    values = nees(e, P)
    assert values[0] == 1.0 and np.isnan(values[1]) and np.isnan(values[2])
