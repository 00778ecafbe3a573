"""A filter stepped beyond its model's declared max_dt warns once per filter object (contract.py's FilterBase), and
never for a model that declares none or for a refused call."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from abyssal.runtime.contract import LongStepWarning, declared_max_dt
from abyssal.runtime.filters.kalman import CKF
from abyssal.runtime.filters.particle import ParticleFilter
from abyssal.runtime.noise import GaussianMixture


def kalman(model):
    n, m = model.n_x, model.n_y
    return CKF(model, np.zeros(n), 0.1 * np.eye(n), 1e-4 * np.eye(n), 0.1 * np.eye(m))


def particles(model):
    n, m = model.n_x, model.n_y
    return ParticleFilter(model, np.zeros(n), 0.1 * np.eye(n), GaussianMixture.gaussian(np.zeros(n), 1e-4 * np.eye(n)),
                          GaussianMixture.gaussian(np.zeros(m), 0.1 * np.eye(m)), 50, 0)


def long_step_warnings(record) -> list:
    return [w for w in record if issubclass(w.category, LongStepWarning)]


@pytest.mark.parametrize("make", [kalman, particles], ids=["CKF", "ParticleFilter"])
def test_beyond_the_declared_max_dt_a_filter_warns_once(rov, make):
    assert declared_max_dt(rov) == 0.5  # rov4dof declares it (symbolic/models/rov4dof.py)
    flt, u = make(rov), np.zeros(rov.n_u)
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        flt.predict(u, 0.5)  # at the limit: fine
        with pytest.raises(ValueError, match="dt"):
            flt.predict(u, -1.0)  # refused: no warning either
        assert long_step_warnings(record) == []
        flt.step(u, 0.8)
        flt.predict(u, 2.0)
        flt.run(np.zeros((2, rov.n_u)), None, 1.0)
    (warning,) = long_step_warnings(record)
    text = str(warning.message)
    assert f"{type(flt).__name__}: dt = 0.8 s is beyond the longest step model 'rov4dof' declares, max_dt = 0.5 s" in text
    assert "Said once per filter" in text
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        make(rov).predict(u, 0.8)  # another filter object: its own warning
    assert len(long_step_warnings(record)) == 1


def test_a_model_without_a_declared_max_dt_never_warns():
    import abyssal

    cv = abyssal.load("linear_cv")
    assert cv.envelope["declared"] and declared_max_dt(cv) is None  # linear_cv: an envelope without max_dt
    flt = kalman(cv)
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        flt.step(np.zeros(cv.n_u), 5.0)
    assert long_step_warnings(record) == []


def test_one_warning_class_for_every_path_of_a_kalman_filter(rov):
    """predict_to, update_sensor ahead of the filter's time and run() warn too, with the same LongStepWarning, once
    per filter object; a late fix (behind the filter's time) and a refused call do not."""
    u = np.zeros(rov.n_u)
    assert issubclass(LongStepWarning, UserWarning)
    cases = {
        "predict_to": lambda f: f.predict_to(0.8, u),
        "update_sensor": lambda f: f.update_sensor(rov.sensor_names[0], np.asarray(f.model.h(f.x, f.p))[
            : len(rov.sensors[0]["outputs"])], 0.8),
        "run": lambda f: f.run(np.zeros((3, rov.n_u)), None, np.array([0.1, 0.9, 0.1])),
    }
    for name, call in cases.items():
        flt = kalman(rov)
        with warnings.catch_warnings(record=True) as record:
            warnings.simplefilter("always")
            flt.predict_to(0.3, u)  # within max_dt
            with pytest.raises(ValueError):
                flt.predict_to(-5.0, u)  # refused (back in time): no warning
            assert long_step_warnings(record) == [], name
            call(flt)
            flt.predict_to(float(flt.t) + 3.0, u)
            flt.step(u, 2.0)
        assert len(long_step_warnings(record)) == 1, name
        assert "max_dt = 0.5 s" in str(long_step_warnings(record)[0].message), name
        assert not [w for w in record if w.category is RuntimeWarning], name  # the engine's former warning is gone
