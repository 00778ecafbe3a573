"""Issue 33's smaller items on the Python side: a vanishing R (1e-200 R0) keeps P symmetric positive semi-definite
(the Joseph form), and after a reset to a finite but absurd state the refusal names the state given (x0 or reset),
not u, dt or z."""
from __future__ import annotations

import numpy as np
import pytest

from abyssal.runtime.filters.kalman import CKF, EKF, UKF


@pytest.mark.parametrize("cls", [EKF, UKF, CKF])
def test_a_vanishing_R_keeps_P_symmetric_positive_semidefinite(rov, cls):
    n, m = rov.n_x, rov.n_y
    flt = cls(rov, np.zeros(n), 0.1 * np.eye(n), 1e-4 * np.eye(n), 1e-200 * 0.1 * np.eye(m))
    for k in range(30):
        flt.step(0.1 * np.sin(k + np.arange(rov.n_u)), 0.1, 0.01 * np.cos(k + np.arange(m)))
        P = flt.P
        assert np.array_equal(P, P.T) and np.linalg.eigvalsh(P).min() >= -1e-15 * np.abs(P).max()
        assert np.all(np.diag(P) >= 0)


def test_after_an_absurd_reset_the_refusal_names_the_state(rov):
    n, m = rov.n_x, rov.n_y
    flt = CKF(rov, np.zeros(n), 0.1 * np.eye(n), 1e-4 * np.eye(n), 0.1 * np.eye(m))
    flt.reset(1e6 * np.ones(n), 1e6 * np.eye(n))  # finite: accepted
    for call in (lambda: flt.step(np.zeros(rov.n_u), 0.1, np.zeros(m)), lambda: flt.predict(np.zeros(rov.n_u), 0.1)):
        with pytest.raises(ValueError) as info:
            call()
        message = str(info.value)
        assert "the state given to the filter (x0 or reset: |x| up to 1e+06, largest variance 1e+06)" in message
    flt.reset(np.zeros(n), 0.1 * np.eye(n))  # a sane reset: it runs again
    flt.step(np.zeros(rov.n_u), 0.1, np.zeros(m))
