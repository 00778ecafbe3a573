"""Property-based tests of the stamped calls (predict_to, update(sensor, z, t, R, p)) of every registered filter
that has them, on a user's model with inputs and three sensors (a GNSS fix, a DVL, a beacon range whose position
is the sensor's own parameter).

A drawn sequence mixes predicts to a stamp and sensor updates stamped ahead of, at, or behind the filter's time
(late: fused from the history, or refused when older than it holds), with R and p given or not, sometimes faulty
(non-finite, wrong shape, not positive definite, a time stamp that is not a finite number, backwards per sensor,
an unknown sensor). The contract:

* a refusal is a ValueError/TypeError naming the faulty argument (or, for acceptable arguments, why: a stamp older
  than the history, or not after the sensor's previous one), and leaves the filter bit-identical: x, P, t, every
  report and every sensor's report;
* an accepted call gives a finite state;
* hidden state too (the held input, the history): a twin that is given only the accepted calls ends bit-identical.
"""
from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, strategies as st

import abyssal
from abyssal.runtime.contract import registered_filters
from abyssal.symbolic import Model, Parameter, Quantity, Sensor, symbols
from property_strategies import Drawn, named, vectors
from test_property_filters import REPORTS, _same

STAMPED = sorted((cls for cls in registered_filters() if hasattr(cls, "update_sensor")), key=lambda c: c.__name__)
SENSORS = ("gnss", "dvl", "beacon")
#: why a stamped call with acceptable arguments may be refused (the history's lag, a sensor's order, a step beyond
#: the model's range)
REASONS = ("older than the history", "not after this sensor's previous stamp", "diverg", "stable", "range")


def driven_vehicle() -> Model:
    """A 2-D vehicle driven by accelerations (inputs held between their stamps) with three sensors."""
    states = (Quantity("x", "m"), Quantity("y", "m"), Quantity("vx", "m/s"), Quantity("vy", "m/s"))
    inputs = (Quantity("ax", "m/s^2"), Quantity("ay", "m/s^2"))
    noises = (Quantity("wx", "m/s^2"), Quantity("wy", "m/s^2"))
    x, u, w = symbols("x", states), symbols("u", inputs), symbols("w", noises)
    beacon = (Parameter("north", "m", 30.0), Parameter("east", "m", -20.0))
    q = symbols("beacon", beacon)
    sensors = (
        Sensor(name="gnss", outputs=(Quantity("x", "m"), Quantity("y", "m")), y=x[0:2], noise=(0.5, 0.5)),
        Sensor(name="dvl", outputs=(Quantity("vx", "m/s"), Quantity("vy", "m/s")), y=x[2:4], noise=(0.05, 0.05)),
        Sensor(name="beacon", outputs=(Quantity("range", "m"),), y=ca.sqrt((x[0] - q[0]) ** 2 + (x[1] - q[1]) ** 2),
               parameters=beacon, q=q, noise=(0.3,), latency=(0.3, 1.0)),
    )
    return Model(name="driven_sensors", states=states, inputs=inputs, noises=noises, x=x, u=u, w=w,
                 xdot=ca.vertcat(x[2], x[3], u[0] - 0.1 * x[2] + w[0], u[1] - 0.1 * x[3] + w[1]), sensors=sensors)


@pytest.fixture(scope="module")
def vehicle(tmp_path_factory):
    return abyssal.load(abyssal.generate(driven_vehicle(), tmp_path_factory.mktemp("stamped") / "gen"))


def build(cls, model):
    return cls(model, np.zeros(4), np.diag([4.0, 4.0, 1.0, 1.0]), np.diag([0.04, 0.04]), None, noise="inputs",
               history_seconds=2.0, history_entries=24)


def snapshot(filt) -> dict:
    out = {name: getattr(filt, name) for name in REPORTS + ("t", "late", "history", "reported_sensor")
           if hasattr(filt, name)}
    out = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in out.items()}
    for sensor in SENSORS:
        out[sensor] = filt.sensor_report(sensor)
    return out


def unchanged(before: dict, after: dict) -> list[str]:
    def same(a, b):
        if isinstance(a, dict):
            return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
        return _same(a, b)
    return [k for k in before if not same(before[k], after[k])]


@st.composite
def stamps(draw, now: float, backwards: str | None = None):
    """t relative to the filter's time: ahead, at it, a little behind (late), far behind, or not a finite number
    (backwards: the problem of a stamp behind the filter's time, None when it is acceptable)."""
    kind = draw(st.sampled_from(["ahead"] * 5 + ["now", "late", "late", "ancient", "bad"]))
    if kind == "ahead":
        return Drawn(now + draw(st.floats(1e-3, 1.5)))
    if kind == "now":
        return Drawn(now)
    if kind == "late":
        return Drawn(now - draw(st.floats(1e-3, 1.5)), backwards)
    if kind == "ancient":
        return Drawn(now - 1e3, backwards)
    return draw(st.sampled_from([Drawn(math.nan, "not finite"), Drawn(math.inf, "not finite"),
                                 Drawn("1.0", "not a number"), Drawn(None, "not a number")]))


@st.composite
def covariances(draw, rows: int):
    kind = draw(st.sampled_from(["none"] * 3 + ["good", "good", "nan", "negative", "asymmetric", "shape"]))
    good = np.diag(draw(st.lists(st.floats(1e-4, 10.0), min_size=rows, max_size=rows)))
    if kind == "none":
        return Drawn(None)
    if kind == "good":
        return Drawn(good)
    if kind == "nan":
        good[0, 0] = np.nan
        return Drawn(good, "non-finite")
    if kind == "negative":
        good[0, 0] = -1.0
        return Drawn(good, "not positive definite")
    if kind == "asymmetric":
        good = good + np.triu(np.ones((rows, rows)), 1)
        return Drawn(good, "not symmetric") if rows > 1 else Drawn(good)
    return Drawn(np.eye(rows + 1), "wrong shape")


def call_predict(filt, args):
    return filt.predict_to(args["t"].value, args["u"].value)


def call_update(filt, args):
    return filt.update(args["sensor"].value, args["z"].value, args["t"].value, R=args["R"].value, p=args["p"].value)


@pytest.mark.parametrize("cls", STAMPED, ids=lambda c: c.__name__)
@given(data=st.data())
def test_stamped_calls_keep_the_contract(vehicle, cls, data):
    filt, twin = build(cls, vehicle), build(cls, vehicle)
    filt.predict_to(0.0, np.zeros(2))
    twin.predict_to(0.0, np.zeros(2))
    for k in range(data.draw(st.integers(1, 8), "calls")):
        if data.draw(st.booleans(), f"predict {k}"):
            call = call_predict
            args = {"t": data.draw(stamps(filt.t, "backwards"), f"t{k}"), "u": data.draw(vectors(2, scale=3.0), f"u{k}")}
        else:
            call = call_update
            sensor = data.draw(st.sampled_from(SENSORS + ("sonar",)), f"sensor{k}")
            rows = {"gnss": 2, "dvl": 2, "beacon": 1}.get(sensor, 1)
            p = data.draw(vectors(2, scale=50.0, none_ok=True), f"p{k}") if sensor == "beacon" else Drawn(None)
            args = {"sensor": Drawn(sensor, None if sensor in SENSORS else "unknown"),
                    "z": data.draw(vectors(rows, scale=3.0, nan_ok=True), f"z{k}"),
                    "t": data.draw(stamps(filt.t), f"t{k}"), "R": data.draw(covariances(rows), f"R{k}"), "p": p}
        faulty = [name for name, d in args.items() if d.problem]
        before = snapshot(filt)
        try:
            call(filt, args)
        except (ValueError, TypeError) as error:
            changed = unchanged(before, snapshot(filt))
            assert not changed, f"refused call ({error!r}) changed {changed}"
            assert not isinstance(error, np.linalg.LinAlgError), f"numpy's LinAlgError escaped: {error!r}"
            message = str(error)
            if faulty:
                assert named(message, faulty + (["sensors"] if "sensor" in faulty else [])) or any(
                    r in message for r in REASONS), f"the error does not name any of {faulty}: {error!r}"
            else:
                assert isinstance(error, ValueError), f"TypeError for acceptable arguments {args}: {error!r}"
                assert any(r in message for r in REASONS), f"refusal of acceptable arguments says no reason: {error!r}"
            continue
        assert not faulty, f"accepted faulty arguments {[(n, args[n]) for n in faulty]}"
        assert np.all(np.isfinite(filt.x)) and np.all(np.isfinite(filt.P)), f"non-finite state after {args}"
        call(twin, args)  # the twin sees only the accepted calls
    assert _same(filt.x, twin.x) and _same(filt.P, twin.P) and filt.t == twin.t, (
        "a refused call changed hidden state (the held input or the history)")
