"""A sensor value in the wrong unit (a heading in degrees, a depth in millimetres, a range in feet) is named in one
warning during the first updates; values in the model's units never are. Truth from the model's own h on a simulated
run (rov4dof: x, y, depth in m, heading in rad), and a user's model with sensors of its own."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

import abyssal
from abyssal.runtime import CKF, EKF
from abyssal.runtime.filters.kalman.units import SAMPLES, UnitSlipWarning

from test_sensors_time import sensor_vehicle


@pytest.fixture(scope="module")
def rov():
    return abyssal.generated.load("rov4dof")


def rov_run(rov, steps=30, seed=0):
    rng = np.random.default_rng(seed)
    x, dt = np.zeros(rov.n_x), 0.1
    x[2] = 5.0  # at 5 m depth
    x[rov.state_names.index("psi")] = 2.5  # a heading of 143 degrees
    U, Z = [], []
    for k in range(steps):
        u = np.array([20.0, 5.0, 10.0, 0.5 * np.sin(0.2 * k * dt)])
        x = rov.f(x, u, None, dt)
        U.append(u)
        Z.append(rov.h(x) + rng.normal(0, [0.05, 0.05, 0.02, 0.01]))
    return np.array(U), np.array(Z), dt


def filter_on(rov, kind=EKF):
    x0 = np.zeros(rov.n_x)
    x0[rov.state_names.index("psi")], x0[2] = 2.5, 5.0
    return kind(rov, x0, 0.1 * np.eye(rov.n_x), np.diag([1e-4] * 8 + [1e-2] * 4),
                np.diag([0.05, 0.05, 0.02, 0.01]) ** 2)


def steps_warnings(flt, U, Z, dt):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for u, z in zip(U, Z):
            flt.step(u, dt, z)
    return [w for w in caught if issubclass(w.category, UnitSlipWarning)]


@pytest.mark.parametrize("kind", [EKF, CKF])
def test_a_heading_in_degrees_is_named_once(rov, kind):
    U, Z, dt = rov_run(rov)
    Z[:, 3] = np.degrees(Z[:, 3])
    caught = steps_warnings(filter_on(rov, kind), U, Z, dt)
    assert len(caught) == 1
    message = str(caught[0].message)
    assert "'psi' (rad)" in message and "degrees" in message
    assert caught[0].filename == __file__  # it points at the user's call


def test_a_depth_in_millimetres_is_named(rov):
    U, Z, dt = rov_run(rov)
    Z[:, 2] *= 1000.0
    caught = steps_warnings(filter_on(rov), U, Z, dt)
    assert len(caught) == 1 and "'z' (m)" in str(caught[0].message) and "millimetres" in str(caught[0].message)


def test_values_in_the_models_units_and_a_stuck_gauge_are_not_a_unit_slip(rov):
    U, Z, dt = rov_run(rov)
    assert steps_warnings(filter_on(rov), U, Z, dt) == []
    Z[:, 2] = 1e6  # stuck from the first step: an outlier, but no unit's factor
    flt = filter_on(rov)
    assert steps_warnings(flt, U, Z, dt) == []
    report = flt.sensor_report("measurement")  # and the stuck gauge is dropped, not re-acquired
    assert report["rejected"] and report["inflations"] == flt.options["gate_max_inflations"]
    assert abs(flt.x[2]) < 10.0


def test_the_watch_ends_after_its_samples(rov):
    U, Z, dt = rov_run(rov)
    flt = filter_on(rov)
    steps_warnings(flt, U[:SAMPLES], Z[:SAMPLES], dt)
    assert flt._unit_watch is None  # every output decided: the hot path no longer pays for it


def test_a_range_in_feet_through_update_sensor(tmp_path):
    model = abyssal.load(abyssal.generate(sensor_vehicle(), tmp_path / "gen"))
    rng = np.random.default_rng(1)
    flt = EKF(model, np.array([0.0, 0.0, 1.0, 0.5]), np.diag([1.0, 1.0, 0.1, 0.1]), 1e-4 * np.eye(model.n_w),
              noise="inputs")
    caught = []
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        for k in range(1, 12):
            t = 0.5 * k
            truth = np.array([1.0 * t, 0.5 * t])
            flt.predict_to(t, np.zeros(0))
            rng_m = np.hypot(truth[0] - 30.0, truth[1] + 20.0) + rng.normal(0, 0.3)
            flt.update("beacon", [rng_m / 0.3048], t)
            flt.update("gnss", truth + rng.normal(0, 0.5, 2), t)
        caught = [w for w in record if issubclass(w.category, UnitSlipWarning)]
    assert len(caught) == 1 and "'beacon' output 'range' (m)" in str(caught[0].message) and "feet" in str(caught[0].message)
