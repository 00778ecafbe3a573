"""Sensors and time in the Kalman runtime (issue "Sensors and time"), against references not produced by it.

A user's model with three sensors of its own (a GNSS fix, a DVL velocity, a range to a beacon whose position is the
sensor's own parameter), generated into a folder of the test's. References: the exact Kalman filter and the exact
Rauch-Tung-Striebel smoother written here in NumPy from the textbook equations (the model is linear but for the
range), and the in-order run of the same calls (a late measurement must give what the in-order calls give).
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

import abyssal
from abyssal.runtime import CKF, EKF, UKF
from abyssal.symbolic import Model, Parameter, Quantity, Sensor, symbols

KINDS = [EKF, UKF, CKF]


def sensor_vehicle() -> Model:
    """A 2-D constant-velocity vehicle (NED-like x north, y east) with a GNSS fix, a DVL and a beacon range."""
    states = (Quantity("x", "m"), Quantity("y", "m"), Quantity("vx", "m/s"), Quantity("vy", "m/s"))
    noises = (Quantity("ax", "m/s^2", "acceleration noise"), Quantity("ay", "m/s^2"))
    x, w = symbols("x", states), symbols("w", noises)
    u = ca.SX(0, 1)
    beacon = (Parameter("north", "m", 30.0), Parameter("east", "m", -20.0))
    q = symbols("beacon", beacon)
    sensors = (
        Sensor(name="gnss", outputs=(Quantity("x", "m"), Quantity("y", "m")), y=x[0:2], noise=(0.5, 0.5), rate=1.0),
        Sensor(name="dvl", outputs=(Quantity("vx", "m/s"), Quantity("vy", "m/s")), y=x[2:4], noise=(0.05, 0.05), rate=5.0),
        Sensor(name="beacon", outputs=(Quantity("range", "m"),), y=ca.sqrt((x[0] - q[0]) ** 2 + (x[1] - q[1]) ** 2),
               parameters=beacon, q=q, noise=(0.3,), latency=(0.3, 1.0)),
    )
    return Model(name="cv_sensors", states=states, inputs=(), noises=noises, x=x, u=u, w=w,
                 xdot=ca.vertcat(x[2], x[3], w[0], w[1]), sensors=sensors)


@pytest.fixture(scope="module")
def vehicle(tmp_path_factory):
    folder = abyssal.generate(sensor_vehicle(), tmp_path_factory.mktemp("user") / "gen")
    return abyssal.load(folder)


def test_the_model_stacks_its_sensors_and_names_their_parameters(vehicle):
    assert vehicle.sensor_names == ("gnss", "dvl", "beacon")
    assert vehicle.output_names == ("gnss_x", "gnss_y", "dvl_vx", "dvl_vy", "beacon_range")
    assert vehicle.parameter_names == ("beacon_north", "beacon_east")
    beacon = vehicle.sensor("beacon")
    assert (beacon["offset"], beacon["p_offset"], beacon["latency"]) == (4, 0, [0.3, 1.0])
    assert beacon["noise"] == [[0.09]]
    x = np.array([3.0, 4.0, 0.5, -0.2])
    np.testing.assert_allclose(vehicle.h(x), [3.0, 4.0, 0.5, -0.2, np.hypot(3 - 30, 4 + 20)], rtol=1e-15)


def test_a_model_without_a_measurement_is_refused_with_one_line():
    states = (Quantity("x", "m"),)
    x = symbols("x", states)
    with pytest.raises(ValueError, match="no measurement: give y"):
        Model(name="mute", states=states, inputs=(), x=x, u=ca.SX(0, 1), xdot=-x)


# ------------------------------------------------------------------------------------ the exact references

def cv_matrices(dt):
    F = np.eye(4)
    F[0, 2] = F[1, 3] = dt
    G = np.zeros((4, 2))  # the noise held over the step (RK4 is exact on this model)
    G[0, 0] = G[1, 1] = dt ** 2 / 2
    G[2, 0] = G[3, 1] = dt
    return F, G


class ExactKF:
    """The Kalman filter and its RTS smoother, from the textbook equations (noise inputs: Q_k = G (Qw / dt) G^T)."""

    H = {"gnss": np.hstack([np.eye(2), np.zeros((2, 2))]), "dvl": np.hstack([np.zeros((2, 2)), np.eye(2)])}

    def __init__(self, x0, P0, Qw, R):
        self.x, self.P, self.Qw, self.R, self.t = x0.copy(), P0.copy(), Qw, R, 0.0
        self.steps = []  # (prior x, P, predicted x, P, F) of every predict

    def predict_to(self, t):
        dt = t - self.t
        F, G = cv_matrices(dt)
        x_pred, P_pred = F @ self.x, F @ self.P @ F.T + G @ (self.Qw / dt) @ G.T
        self.steps.append((self.x, self.P, x_pred, P_pred, F))
        self.x, self.P, self.t = x_pred, P_pred, t

    def update(self, sensor, z):
        H, R = self.H[sensor], self.R[sensor]
        S = H @ self.P @ H.T + R
        K = np.linalg.solve(S, H @ self.P).T
        self.x = self.x + K @ (z - H @ self.x)
        I_KH = np.eye(4) - K @ H
        self.P = I_KH @ self.P @ I_KH.T + K @ R @ K.T

    def smooth(self):
        xs, Ps = [self.x], [self.P]
        for x, P, x_pred, P_pred, F in reversed(self.steps):
            G = P @ F.T @ np.linalg.inv(P_pred)
            xs.append(x + G @ (xs[-1] - x_pred))
            Ps.append(P + G @ (Ps[-1] - P_pred) @ G.T)
        return np.array(xs[::-1]), np.array(Ps[::-1])


def events(seed=0, T=40.0, truth=False):
    """Irregular stamps: DVL at ~5 Hz with jitter, GNSS at 1 Hz, interleaved; (t, sensor, z[, the true state])."""
    rng = np.random.default_rng(seed)
    stamps = sorted([(t + rng.uniform(0, 0.02), "dvl") for t in np.arange(0.2, T, 0.2)] +
                    [(t + 0.05, "gnss") for t in np.arange(1.0, T, 1.0)])
    x, t, out = np.array([0.0, 0.0, 1.0, 0.5]), 0.0, []
    for stamp, sensor in stamps:
        F, _ = cv_matrices(stamp - t)
        x, t = F @ x + rng.normal(scale=[0.01, 0.01, 0.02, 0.02]), stamp
        z = (x[:2] + rng.normal(scale=0.5, size=2)) if sensor == "gnss" else (x[2:] + rng.normal(scale=0.05, size=2))
        out.append((stamp, sensor, z, x.copy()) if truth else (stamp, sensor, z))
    return out


FILTER = dict(noise="inputs", gate_probability=0.0)
X0, P0, QW = np.zeros(4), np.diag([4.0, 4.0, 1.0, 1.0]), np.diag([0.04, 0.04])
R_STACKED = np.diag(np.square([0.5, 0.5, 0.05, 0.05, 0.3]))  # the declared standard deviations
R_EXACT = {"gnss": np.eye(2) * 0.5 ** 2, "dvl": np.eye(2) * 0.05 ** 2}


@pytest.mark.parametrize("cls", [EKF, CKF])
def test_stamped_sensor_updates_equal_the_exact_kalman_filter(vehicle, cls):
    flt = cls(vehicle, X0, P0, QW, None, **FILTER)  # R: each sensor's declared noise
    np.testing.assert_array_equal(flt.R, R_STACKED)
    ref = ExactKF(X0, P0, QW, R_EXACT)
    for t, sensor, z in events():
        flt.predict_to(t, np.zeros(0))
        ref.predict_to(t)
        assert flt.update(sensor, z, t)
        ref.update(sensor, z)
        assert np.abs(flt.x - ref.x).max() <= 1e-11 * max(1.0, np.abs(ref.x).max())
        assert np.abs(flt.P - ref.P).max() <= 1e-11 * np.abs(ref.P).max()
    assert flt.t == events()[-1][0]
    assert flt.sensor_report("dvl")["used"] == sum(1 for e in events() if e[1] == "dvl")


@pytest.mark.parametrize("cls", KINDS)
def test_a_late_measurement_equals_the_in_order_run(vehicle, cls):
    """Beacon ranges stamped 0.3-1 s before they arrive: fused from the history at their stamp, they give exactly
    what the in-order calls of the same measurements give (a USBL fix, a CN range computed after the ping)."""
    rng = np.random.default_rng(3)
    stream = events(1, T=20.0)
    pings = [(t, np.array([np.hypot(1.0 * t - 30.0, 0.5 * t + 20.0) + rng.normal(scale=0.3)])) for t in np.arange(2.0, 19.0, 2.5)]
    delays = rng.uniform(0.3, 1.0, size=len(pings))
    in_order = cls(vehicle, X0, P0, QW, None, **FILTER)
    late = cls(vehicle, X0, P0, QW, None, history_seconds=2.0, **FILTER)
    merged = sorted([(t, "fast", s, z) for t, s, z in stream] + [(t, "ping", "beacon", z) for t, z in pings])
    for t, kind, sensor, z in merged:  # the in-order run: every measurement at its stamp, in time order
        in_order.predict_to(t, np.zeros(0))
        in_order.update(sensor, z, t)
    arrivals = sorted([(t, 0, s, z, t) for t, s, z in stream] + [(t + d, 1, "beacon", z, t) for (t, z), d in zip(pings, delays)])
    for arrival, _, sensor, z, stamp in arrivals:  # the late run: pings arrive after later DVL/GNSS measurements
        if sensor != "beacon":
            late.predict_to(stamp, np.zeros(0))
        late.update(sensor, z, stamp)
    final = stream[-1][0]
    in_order.predict_to(max(final, late.t), np.zeros(0))
    late.predict_to(max(final, late.t), np.zeros(0))
    assert late.late >= len(pings) - 1 and late.sensor_report("beacon")["late"] == late.late
    assert np.abs(late.x - in_order.x).max() <= 1e-12 * max(1.0, np.abs(in_order.x).max())
    assert np.abs(late.P - in_order.P).max() <= 1e-12 * np.abs(in_order.P).max()
    assert late.sensor_report("beacon")["used"] == in_order.sensor_report("beacon")["used"] == len(pings)


def test_too_late_backwards_and_non_finite_stamps_are_refused_and_change_nothing(vehicle):
    flt = CKF(vehicle, X0, P0, QW, None, history_seconds=1.0, **FILTER)
    for t, sensor, z in events(2, T=6.0):
        flt.predict_to(t, np.zeros(0))
        flt.update(sensor, z, t)
    saved = flt._committed.copy()
    with pytest.raises(ValueError, match="older than the history holds"):
        flt.update("beacon", np.array([30.0]), flt.t - 3.0)
    with pytest.raises(ValueError, match="not after this sensor's previous stamp"):
        flt.update("dvl", np.array([1.0, 0.5]), flt.sensor_report("dvl")["last_t"])
    with pytest.raises(ValueError, match="before the filter's time"):
        flt.predict_to(flt.t - 0.5, np.zeros(0))
    for bad in (np.nan, np.inf):
        with pytest.raises(ValueError, match="finite"):
            flt.update("gnss", np.array([1.0, 1.0]), bad)
    with pytest.raises(ValueError, match="use NaN"):
        flt.update("gnss", np.array([np.inf, 1.0]), flt.t + 0.1)
    with pytest.raises(ValueError, match="not one of model"):
        flt.update("sonar", np.array([1.0]), flt.t + 0.1)
    assert flt._committed.tobytes() == saved.tobytes()


def test_a_measurement_carries_its_own_R_and_parameters(vehicle):
    """A USBL-like fix with its own quality figure, a range to a beacon at the position given with the ping."""
    a = EKF(vehicle, np.array([10.0, 5.0, 0.0, 0.0]), P0, QW, None, **FILTER)
    b = EKF(vehicle, np.array([10.0, 5.0, 0.0, 0.0]), P0, QW, None, **FILTER)
    b.set_sensor_R("beacon", np.array([[4.0]]))
    a.update("beacon", np.array([12.0]), 0.0, R=np.array([[4.0]]), p=np.array([0.0, 0.0]))
    b_parameters = np.array([0.0, 0.0])
    b.update("beacon", np.array([12.0]), 0.0, p=b_parameters)
    np.testing.assert_array_equal(a.x, b.x)
    # the range to (0, 0) from (10, 5) is 11.18: a measurement of 12 m pulls the estimate away from the origin
    assert np.hypot(*a.x[:2]) > np.hypot(10.0, 5.0)
    assert a.S.shape == (1, 1) and a.innovation.shape == (1,)  # the report is the sensor's own rows
    assert a.reported_sensor == "beacon"


def test_a_measurements_own_R_holds_for_its_call_only_even_when_refused(vehicle):
    """The next fix without an R of its own is weighed with the filter's R, after an accepted call with R, a call
    refused for its p, and one refused by the runtime (too late); as a twin given the filter's R explicitly."""
    a = EKF(vehicle, np.array([10.0, 5.0, 0.0, 0.0]), P0, QW, None, **FILTER)
    b = EKF(vehicle, np.array([10.0, 5.0, 0.0, 0.0]), P0, QW, None, **FILTER)
    beacon = vehicle.sensor_names.index("beacon")
    at = vehicle.sensors[beacon]["offset"]
    filters_R = a.R[at:at + 1, at:at + 1]
    for flt in (a, b):
        flt.update("beacon", np.array([12.0]), 1.0, R=np.array([[400.0]]), p=np.array([0.0, 0.0]))
    with pytest.raises(ValueError, match="p"):
        a.update("beacon", np.array([12.0]), 1.5, R=np.array([[400.0]]), p=np.array([np.nan, 0.0]))
    with pytest.raises(ValueError):
        a.update("beacon", np.array([12.0]), -1e3, R=np.array([[400.0]]))
    a.update("beacon", np.array([11.0]), 2.0)
    b.update("beacon", np.array([11.0]), 2.0, R=filters_R)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.P, b.P)


def test_the_stacked_update_equals_sequential_sensor_updates_on_a_linear_model(vehicle):
    """With block-diagonal R, one joint update of every sensor equals their updates one after another (exact
    Kalman algebra; the range is left out as missing)."""
    joint = EKF(vehicle, X0, P0, QW, None, **FILTER)
    seq = EKF(vehicle, X0, P0, QW, None, **FILTER)
    z = np.array([1.0, -2.0, 0.3, 0.1, np.nan])
    joint.predict(np.zeros(0), 0.5)
    joint.update(z)
    seq.predict_to(0.5, np.zeros(0))
    seq.update("gnss", z[:2], 0.5)
    seq.update("dvl", z[2:4], 0.5)
    assert np.abs(joint.x - seq.x).max() <= 1e-12
    assert np.abs(joint.P - seq.P).max() <= 1e-12 * np.abs(joint.P).max()


@pytest.mark.parametrize("cls", KINDS)
def test_smoothing_over_the_history_equals_the_exact_rts_smoother(vehicle, cls):
    flt = cls(vehicle, X0, P0, QW, None, smoothing=True, history_entries=1000, history_seconds=1e9, **FILTER)
    ref = ExactKF(X0, P0, QW, R_EXACT)
    for t, sensor, z in events(4, T=15.0):
        flt.predict_to(t, np.zeros(0))
        ref.predict_to(t)
        flt.update(sensor, z, t)
        ref.update(sensor, z)
    t, xs, Ps = flt.smooth()
    x_ref, P_ref = ref.smooth()
    predicts = [k for k in range(1, len(t)) if t[k] > t[k - 1]] # the smoothed state at each predict's end ...
    starts = [0] + predicts
    assert len(starts) == len(x_ref)
    tol = 1e-12 if cls is EKF else 1e-10  # the sigma-point rules are exact on this linear model, to rounding
    assert np.abs(xs[starts] - x_ref).max() <= tol * max(1.0, np.abs(x_ref).max())
    assert np.abs(Ps[starts] - P_ref).max() <= tol * np.abs(P_ref).max()
    assert np.all(np.diagonal(P_ref, axis1=1, axis2=2) <= np.diagonal(np.array([r[1] for r in ref.steps] + [ref.P]),
                                                                       axis1=1, axis2=2) + 1e-12)


def test_smoothing_a_state_known_exactly_is_no_failure(vehicle):
    """y and vy known exactly (zero P0 and noise along them): P_pred is singular. Smoothing keeps the filter as it
    is without smoothing (bit for bit) and smooths the rest as the exact RTS smoother does (its gain by the
    pseudo-inverse: zero along the exact directions)."""
    P0_exact, QW_exact = np.diag([4.0, 0.0, 1.0, 0.0]), np.diag([0.04, 0.0])
    smoothed = EKF(vehicle, X0, P0_exact, QW_exact, None, smoothing=True, history_entries=1000, history_seconds=1e9,
                   repair_floor=1e-15, **FILTER)
    plain = EKF(vehicle, X0, P0_exact, QW_exact, None, repair_floor=1e-15, **FILTER)
    ref = ExactKF(X0, P0_exact, QW_exact, R_EXACT)
    for t, sensor, z in events(5, T=10.0):
        for flt in (smoothed, plain):
            flt.predict_to(t, np.zeros(0))
            flt.update(sensor, z, t)
        ref.predict_to(t)
        ref.update(sensor, z)
        assert np.array_equal(smoothed.x, plain.x) and np.array_equal(smoothed.P, plain.P)
    t, xs, Ps = smoothed.smooth()
    x_ref, P_ref = [ref.x], [ref.P]
    for x, P, x_pred, P_pred, F in reversed(ref.steps):
        G = P @ F.T @ np.linalg.pinv(P_pred)
        x_ref.append(x + G @ (x_ref[-1] - x_pred))
        P_ref.append(P + G @ (P_ref[-1] - P_pred) @ G.T)
    x_ref, P_ref = np.array(x_ref[::-1]), np.array(P_ref[::-1])
    starts = [0] + [k for k in range(1, len(t)) if t[k] > t[k - 1]]
    # (the runtime's posterior repair keeps P at least repair_floor x its largest eigenvalue along y, vy: so "known
    # exactly" is to that floor, and the smoothed y, vy move by as little)
    assert np.abs(xs[starts] - x_ref).max() <= 1e-6 * max(1.0, np.abs(x_ref).max())
    assert np.abs(Ps[starts] - P_ref).max() <= 1e-6 * np.abs(P_ref).max()


def test_a_stuck_sensor_is_dropped_and_the_others_carry_the_filter(vehicle):
    """The DVL reads +1e6 m/s from 10 s on; the GNSS keeps the position within 3x the error of an untouched twin,
    and the DVL is reported as rejected (gated, inflations bounded), never blamed on u."""
    good = CKF(vehicle, X0, P0, QW, None, noise="inputs")
    stuck = CKF(vehicle, X0, P0, QW, None, noise="inputs")
    fixes, err_good, err_stuck = 0, [], []
    for t, sensor, z, x in events(5, T=60.0, truth=True):
        for f in (good, stuck):
            f.predict_to(t, np.zeros(0))
        good.update(sensor, z, t)
        stuck.update(sensor, np.full(2, 1e6) if (sensor == "dvl" and t > 10.0) else z, t)
        fixes += sensor == "gnss"
        if t > 10.0:
            err_good.append(np.hypot(*(good.x[:2] - x[:2])))
            err_stuck.append(np.hypot(*(stuck.x[:2] - x[:2])))
    report = stuck.sensor_report("dvl")
    assert report["rejected"] and report["gated"] > 400
    assert stuck.inflations <= stuck.options["gate_max_inflations"]
    assert np.all(np.isfinite(stuck.P))
    assert np.sqrt(np.mean(np.square(err_stuck))) <= 3 * np.sqrt(np.mean(np.square(err_good)))
    assert stuck.sensor_report("gnss")["gated"] == 0 and stuck.sensor_report("gnss")["used"] == fixes


@pytest.mark.parametrize("cls, stuck", [(EKF, 1e6), (EKF, 1e300), (CKF, 1e6), (CKF, 1e100), (UKF, 1e100)])
def test_a_stuck_depth_gauge_leaves_x_y_and_heading_to_the_other_entries(cls, stuck):
    """The audit's case (issue 35): rov4dof, the depth entry reading +1e6 m (or 1e100, 1e300) from step 27 on while
    x, y and heading are fine. It used to inflate the whole P until every predict was refused (EKF 673 of 700
    steps; at 1e300 P = inf was committed). Now no step is refused, P stays finite, the inflations stop at their cap
    and x, y, heading stay within 3x the error of an untouched twin."""
    import abyssal.generated

    rov = abyssal.generated.load("rov4dof")
    rng = np.random.default_rng(5)
    dt, T = 0.1, 700
    Q, R = np.diag([1e-4] * 8 + [1e-2] * 4), np.diag([0.05, 0.05, 0.02, 0.01])
    U = np.tile([20.0, 5.0, 10.0, 0.5], (T, 1)) + rng.normal(size=(T, 4))
    X = [np.zeros(12)]
    for u in U:
        X.append(rov.f(X[-1], u, None, dt) + rng.multivariate_normal(np.zeros(12), Q))
    X = np.array(X[1:])
    Z = np.array([rov.h(x) for x in X]) + rng.multivariate_normal(np.zeros(4), R, size=T)
    bad_z = Z.copy()
    bad_z[27:, 2] = stuck
    twin, bad = cls(rov, np.zeros(12), 0.3 * np.eye(12), Q, R), cls(rov, np.zeros(12), 0.3 * np.eye(12), Q, R)
    result, reference = bad.run(U, bad_z, dt), twin.run(U, Z, dt)  # a refused step would raise

    def errors(r):
        return np.column_stack([r.x[:, :2] - X[:, :2], np.angle(np.exp(1j * (r.x[:, 3] - X[:, 3])))])
    ratio = np.sqrt(np.mean(errors(result) ** 2, axis=0)) / np.sqrt(np.mean(errors(reference) ** 2, axis=0))
    assert np.all(ratio <= 3.0), ratio
    assert np.all(np.isfinite(result.P)) and bad.gated >= T - 27 - 5
    assert bad.inflations == bad.options["gate_max_inflations"] and bad.sensor_report("measurement")["rejected"]


@pytest.mark.parametrize("cls", KINDS)
def test_the_one_call_update_equals_the_classs_update_in_every_case(vehicle, cls):
    """update(sensor, z, t) with a float64 z and a float t is one C call (runtime/c/abyssal_kalman_python.c, the
    filter's own update); against the class's update on a twin: the same outcomes (values, refusals and their
    messages), and the same filter object, call block and return code after every call of a mixed sequence."""
    import sys

    from abyssal.runtime.filters.kalman.engine import KalmanFilter

    fast, slow = (cls(vehicle, X0, P0, QW, history_seconds=2.0, **FILTER) for _ in range(2))
    slow.update = KalmanFilter.update.__get__(slow)
    assert type(fast.update).__name__ == "UpdateCall", "Python's headers are here: the plain update must be one C call"

    class Name(str):
        pass
    gnss, dvl = np.array([1.0, 0.5]), np.array([1.0, 0.45])
    for flt in (fast, slow):  # past the unit watch's first updates of every sensor (they take the class's update)
        for i in range(17):
            for j, (sensor, z) in enumerate((("gnss", 0.01 * i + np.zeros(2)), ("dvl", np.array([1.0, 0.5])),
                                             ("beacon", np.array([36.0])))):
                flt.update(sensor, z, 0.003 * (3 * i + j + 1))
    assert fast._unit_watch is None and slow._unit_watch is None
    calls = [("plain", ("dvl", dvl, 0.2)), ("plain", ("gnss", gnss, 1.05)), ("plain", ("dvl", dvl + 0.01, 1.2)),
             ("late", ("gnss", gnss + 0.1, 0.9)), ("too late", ("dvl", dvl, -5.0)), ("NaN t", ("dvl", dvl, np.nan)),
             ("inf z", ("dvl", np.array([np.inf, 0.0]), 1.4)), ("missing entry", ("gnss", np.array([np.nan, 0.4]), 1.5)),
             ("numpy t", ("dvl", dvl, np.float64(1.6))), ("int t", ("gnss", gnss, 2)), ("list z", ("dvl", [1.0, 0.4], 2.2)),
             ("short z", ("gnss", gnss[:1], 2.3)), ("unknown sensor", ("sonar", dvl, 2.4)), ("str subclass", (Name("dvl"), dvl, 2.5)),
             ("own R", ("gnss", gnss, 2.6, np.eye(2))), ("own p", ("beacon", np.array([30.0]), 2.7, None, np.array([31.0, -19.0]))),
             ("stacked", (np.array([1.0, 0.5, 1.0, 0.5, 30.0]),)), ("plain", ("beacon", np.array([36.0]), 3.0))]
    paths = {}
    for label, args in calls:
        seen = []
        sys.setprofile(lambda frame, event, arg: seen.append(frame.f_code) if event == "call" else None)
        try:
            got = fast.update(*args)
        except (ValueError, TypeError) as error:
            got = (type(error).__name__, str(error))
        finally:
            sys.setprofile(None)
        paths.setdefault(label, set()).add(KalmanFilter.update.__code__ in seen)
        try:
            want = slow.update(*args)
        except (ValueError, TypeError) as error:
            want = (type(error).__name__, str(error))
        assert got == want, label
        assert fast._committed.tobytes() == slow._committed.tobytes(), label
        assert fast._io.tobytes() == slow._io.tobytes() and fast.code == slow.code, label
    one_call = {label for label, ran in paths.items() if ran == {False}}
    assert one_call == {"plain", "late", "too late", "NaN t", "inf z", "missing entry", "numpy t"}
