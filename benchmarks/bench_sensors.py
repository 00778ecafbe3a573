"""Sensors section of `abyssal bench`: what named sensors and time stamps cost (issue 35, deliverables 2 and 7).

Models (built here with abyssal's Model API, generated into a temporary folder and compiled through the cache):
* ``rov4dof_sensors``: rov4dof's dynamics (12 states, RK4 with 2 substeps, 8 noise inputs) with its measurement
  split into three sensors: ``usbl`` (x, y), ``depth`` (z), ``ahrs`` (heading, an angle), with rov4dof's R
  (0.05, 0.05, 0.02, 0.01). Stacked, its h and R are rov4dof's.
* ``remus100_sensors`` (not in quick mode): REMUS 100 (12 states, 10 outputs) split into ``dvl`` (u, v, w), ``gyro``
  (p, q, r), ``depth`` and ``ahrs`` (roll, pitch, heading): a vehicle with more rows to stack.
* ``linear_cv_sensors``: linear_cv's constant-velocity dynamics (exactly linear, RK4 exact) with a ``dvl`` (velocity)
  and a ``usbl`` (position relative to the sensor parameter): the model on which every exact method must agree.
* ``cloned(model, "usbl")``: the delayed-state (stochastic cloning) augmentation of a model, [x; x_c] with
  f_aug = [f(x, u, p, w); x_c] (the clone is held exactly: RK4 of a zero derivative), the model's sensors on x and
  ``usbl_clone``, the delayed sensor's h on x_c; noise inputs drive x only (G_aug = [G; 0]).

Every filter here runs with noise="inputs" (Q is the noise inputs' density: a split interval accrues exactly what
the whole one does) and the gate off (gate_probability=0: the comparisons are of algebra, not of gating), and is
timed in its steady state: without the unit watch of its first updates (``steady``; the watch evaluates h from
Python for every update until each output has given 8 values, so a filter whose other sensors never report pays it
on every update: measured on its own beside (a)).

Measured (times in one run; rounds interleave the things compared and each keeps its minimum over rounds):

(a) One sensor's update vs the stacked update it replaces. Per sensor k of the multi-sensor models, along a simulated
    run, three filters each get one update per step after an untimed predict: ``update(k, z_k, t)`` at the filter's
    time (after ``predict_to(t, u)``), the stacked ``update(z)`` with only k's rows present (NaN elsewhere: what a
    caller of the stacked API did when sensor k alone reported), and the full stacked ``update(z)``. Each call is
    timed alone (perf_counter around it, the timer's own cost subtracted); per round the median per call, then the
    minimum over rounds; from Python (what a caller pays) and as the runtime's entry point alone (the filter's bound
    call on its call block, as the Python methods fill it: the algebra's share). Targets: one sensor's update < the
    stacked update with its rows, each sensor of rov4dof_sensors, from Python and in C.
(b) Replaying 1 s of history at 20 Hz after a delayed fix. ``rov4dof_sensors`` with history_seconds = 1.5 is stepped
    at 20 Hz (a step: ``predict_to(t, u)``, ``update("depth")``, ``update("ahrs")``); a USBL fix stamped 0.02 s after
    a step arrives 1 s later, after the 20th following step, and is fused at its stamp (the filter rewinds to the
    stamp and replays the 20 steps in C). Ratio: the late ``update("usbl", z, t_s)`` call / one in-order step (the
    same filter's median step in the same rounds). Target <= 25.
(c) The stamped call's overhead from Python. rov4dof (its one sensor, ``measurement``), no history, a constant input:
    ``step(u, dt, z)`` against ``update("measurement", z, t)`` with t one dt ahead, which predicts to t with the held
    input and updates, in one call: the same C work (the same predict and the same update, checked equal to the
    last bit), so their difference is what the stamped path adds (the time and sensor arguments, their checks,
    the lookups). Passes of 300 calls, process CPU time, the minimum over rounds. Target: <= 0.3 µs per call.
    The two-call form (``predict_to`` then ``update(sensor, z, t)``) is reported beside it.
(d) History replay vs an exact delayed-state method (stochastic cloning), on linear_cv_sensors (20 Hz DVL) and
    rov4dof_sensors (20 Hz depth and AHRS), USBL fixes every 2 s stamped 0.02 s after a step, arriving 1 s late:
    * in order: every fix fused at its stamp as if it had arrived on time (predict_to(t_s), update("usbl", z, t_s));
      the reference;
    * replay: the fixes fused late from the history (history_seconds = 1.5);
    * cloning: at a fix's stamp the EKF's state is cloned, x_aug = [x; x], P_aug = [[P, P], [P, P]] (reset of an EKF
      on the cloned model), stepped with the augmented model until the fix arrives, updated with usbl_clone (the
      measurement of the state at its stamp), and marginalised back (reset of the model's EKF with the x block);
      stacked calls with the same dt as the in-order run's stamps give; the cloned EKF with repair_floor = 1e-15
      (CLONE_REPAIR_FLOOR says why; the default floor's agreement is reported too).
    Targets: on linear_cv_sensors both equal the in-order run to 1e-12 (relative to max |x|); on rov4dof_sensors the
    replay does (the cloning's distance is reported, not held to a target: it linearises elsewhere).
    Reported: the agreement of replay and cloning with the in-order run (max over the steps where no fix is pending,
    of |x - x_in_order| and |P - P_in_order| relative to max |x_in_order|, max |P_in_order|; on rov4dof also the
    position difference over the in-order run's own standard deviation), and the cost per delayed fix: (CPU of a
    whole run - CPU of the same run without fixes) / fixes, for each method, from interleaved rounds (60 s runs, 29
    fixes: on a loaded machine a run's minimum CPU moves by a few %, so these differences resolve tens of µs per fix,
    not single µs); beside them, measured call by call: the in-order fix's two calls, the replay's late update, the
    cloning run's two resets per fix (which check P in Python).

    python benchmarks/bench_sensors.py [--quick]            # this section alone: its tables and targets
    python benchmarks/bench_sensors.py [--quick] --json     # the same as JSON on stdout
"""
from __future__ import annotations

import atexit
import dataclasses
import math
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from bench import paired_ratio, target

DT = 0.05            # 20 Hz
LAG = 1.0            # a fix arrives 1 s after its stamp
FIX_EVERY = 2.0      # a USBL fix every 2 s
FIX_OFFSET = 0.02    # stamped 0.02 s after a step (between steps: no question of order among equal stamps)
HISTORY_SECONDS = 1.5
OPTIONS = dict(noise="inputs", gate_probability=0.0)


# ------------------------------------------------------------------------------------------- models
def split_sensors(model, name: str, groups):
    """`model` (one stacked measurement y) with its rows split into named sensors: groups = ((sensor, rows, sigmas),
    ...), rows indices into the model's outputs, sigmas their standard deviations (the sensor's declared noise)."""
    import casadi as ca

    from abyssal.symbolic import Sensor

    y, outputs, angles = ca.SX(model.y), model.outputs, set(model.angle_outputs)
    sensors = []
    for sensor, rows, sigmas in groups:
        sensors.append(Sensor(name=sensor, outputs=tuple(outputs[r] for r in rows), y=ca.vertcat(*[y[r] for r in rows]),
                              noise=tuple(sigmas), angle_outputs=tuple(i for i, r in enumerate(rows) if r in angles)))
    return dataclasses.replace(model, name=name, outputs=(), y=None, angle_outputs=(), sensors=tuple(sensors))


def rov4dof_sensors():
    from abyssal.symbolic.models.rov4dof import rov4dof

    return split_sensors(rov4dof(), "rov4dof_sensors", (("usbl", (0, 1), (0.05 ** 0.5, 0.05 ** 0.5)),
                                                        ("depth", (2,), (0.02 ** 0.5,)), ("ahrs", (3,), (0.1,))))


def remus100_sensors():
    from abyssal.symbolic.models.remus100 import remus100

    return split_sensors(remus100(), "remus100_sensors", (("dvl", (0, 1, 2), (0.01,) * 3), ("gyro", (3, 4, 5), (0.002,) * 3),
                                                          ("depth", (6,), (0.05,)), ("ahrs", (7, 8, 9), (0.01,) * 3)))


def linear_cv_sensors():
    import casadi as ca

    from abyssal.symbolic import Sensor
    from abyssal.symbolic.models.linear_cv import linear_cv

    base = linear_cv()
    x = base.x
    sensors = (Sensor(name="dvl", outputs=(base.states[2], base.states[3]), y=ca.vertcat(x[2], x[3]), noise=(0.05, 0.05)),
               Sensor(name="usbl", outputs=base.outputs, y=ca.SX(base.y), noise=(0.5, 0.5)))
    return dataclasses.replace(base, name="linear_cv_sensors", outputs=(), y=None, angle_outputs=(), sensors=sensors)


def cloned(model, delayed: str):
    """The delayed-state augmentation of `model` for its sensor `delayed`: states [x; x_c], f_aug = [f; x_c] (the
    clone held exactly), noise inputs on x only, the model's sensors on x and ``<delayed>_clone`` (the delayed
    sensor's h, own parameters included, on x_c)."""
    import casadi as ca

    from abyssal.symbolic import Quantity, Sensor, symbols

    n = model.n_x
    clone_states = tuple(Quantity(f"{q.name}_c", q.unit, f"clone of {q.name} at a delayed measurement's stamp")
                         for q in model.states)
    xc = symbols("xc", clone_states)
    x_aug = ca.vertcat(model.x, xc)
    own = {f"{s.name}_{q.name}" for s in model.sensors for q in s.parameters}
    parameters = tuple(q for q in model.parameters if q.name not in own)
    p = ca.SX(model.p)[: len(parameters)]
    sensor = next(s for s in model.sensors if s.name == delayed)
    q_clone = symbols(f"{delayed}_clone", sensor.parameters) if sensor.parameters else None
    y = ca.substitute(sensor.y, model.x, xc)
    if q_clone is not None:
        y = ca.substitute(y, sensor.q, q_clone)
    clone = Sensor(name=f"{delayed}_clone", outputs=sensor.outputs, y=y, parameters=sensor.parameters, q=q_clone,
                   noise=sensor.noise, angle_outputs=sensor.angle_outputs,
                   description=f"{delayed} measured on the clone (the state at the measurement's stamp)")
    fields = dict(name=f"{model.name}_clone", states=tuple(model.states) + clone_states, x=x_aug, parameters=parameters,
                  p=p, outputs=(), y=None, angle_outputs=(), sensors=tuple(model.sensors) + (clone,), envelope=None,
                  angle_states=tuple(model.angle_states) + tuple(n + i for i in model.angle_states))
    if model.x_next is not None:
        fields["x_next"] = ca.vertcat(model.x_next, xc)
    else:
        fields["xdot"] = ca.vertcat(model.xdot, ca.SX.zeros(n))
    return dataclasses.replace(model, **fields)


def steady(flt):
    """`flt` without its unit watch (the engine's ``_unit_watch``: the first 8 values of each output are compared with
    h(x) evaluated from Python, to catch a unit slip): the timings here are of a filter's steady state, and the
    watch is timed on its own (``unit_watch_cost``). The numbers a filter computes are the same either way."""
    if hasattr(flt, "_unit_watch"):
        flt._unit_watch = None
    return flt


_LOADED: dict = {}


def load(build, folder: Path | None = None):
    """The compiled bundle of the model build() returns, generated into `folder` (default: a temporary folder kept
    for the process and removed when it exits) and loaded through the compile cache."""
    import abyssal

    model = build()
    if model.name not in _LOADED:
        if folder is None:
            folder = Path(tempfile.mkdtemp(prefix="abyssal-bench-sensors-"))
            atexit.register(shutil.rmtree, folder, True)
        _LOADED[model.name] = abyssal.load(abyssal.generate(model, folder))
    return _LOADED[model.name]


def rows_of(bundle, sensor: str) -> slice:
    spec = bundle.sensor(sensor)
    return slice(spec["offset"], spec["offset"] + len(spec["outputs"]))


# ------------------------------------------------------------------------------------------- scenario
@dataclasses.dataclass
class Scenario:
    """A 20 Hz run: step k (1..K) at t[k] with input U[k] held over (t[k-1], t[k]] and the tick sensors' measurements;
    the delayed fixes: (stamp, step before it j (t[j] < stamp < t[j+1]), the step after which it arrives, z)."""

    t: np.ndarray
    U: np.ndarray
    Z: dict
    fixes: list
    x0: np.ndarray
    P0: np.ndarray
    Qw: np.ndarray
    ticks: tuple
    delayed: str


def inputs_of(bundle, t, rng):
    n_u = bundle.n_u
    if bundle.name.startswith("rov4dof"):  # surge, sway, heave thrust, a yaw moment swinging the heading
        U = np.column_stack([np.full(len(t), 20.0), np.full(len(t), 5.0), np.full(len(t), 10.0), 0.5 * np.sin(0.2 * t)])
        return U + 0.5 * rng.normal(size=U.shape)
    if bundle.name.startswith("remus100"):  # propeller speed, small pitch and yaw moments
        return np.column_stack([np.full(len(t), 1200.0), 2.0 * np.sin(0.1 * t), 3.0 * np.sin(0.05 * t)])
    return 0.3 * np.column_stack([np.sin(0.2 * t + k) for k in range(n_u)]) if n_u else np.zeros((len(t), 0))


def scenario(bundle, ticks, delayed, seconds: float, seed: int = 0) -> Scenario:
    """A simulated run of `seconds` at 20 Hz on the compiled model: truth by f with the noise inputs drawn, the tick
    sensors every step, the delayed sensor every FIX_EVERY s (stamped FIX_OFFSET after a step, arriving LAG later)."""
    rng = np.random.default_rng(seed)
    n, K = bundle.n_x, int(round(seconds / DT))
    t = DT * np.arange(K + 1)
    U = inputs_of(bundle, t, rng)
    Qw = np.eye(bundle.n_w) * (1e-2 if bundle.name.startswith("linear_cv") else 1.0)
    if bundle.name.startswith("remus100"):
        Qw = np.eye(bundle.n_w) * 0.1
    x = np.zeros(n)
    if bundle.name.startswith("remus100"):
        x[0], x[8] = 1.5, 5.0
    x0 = x.copy()
    R = {s["name"]: np.array(s["noise"]) for s in bundle.sensors}
    Z = {s: np.full((K + 1, rows_of(bundle, s).stop - rows_of(bundle, s).start), np.nan) for s in ticks}
    fixes, stamps = [], [j * DT + FIX_OFFSET for j in range(int(round(FIX_EVERY / DT)), K - int(round(LAG / DT)) - 1,
                                                                int(round(FIX_EVERY / DT)))]
    for k in range(1, K + 1):
        G = bundle.G(x, U[k], None, DT)
        drift = bundle.f(x, U[k], None, DT)
        for stamp in stamps:
            if t[k - 1] < stamp < t[k]:  # the truth at the stamp (the noise of the step left out)
                xs = bundle.f(x, U[k], None, stamp - t[k - 1])
                h = bundle.h(xs)[rows_of(bundle, delayed)]
                z = h + rng.multivariate_normal(np.zeros(len(h)), R[delayed])
                fixes.append((stamp, k - 1, k - 1 + int(round(LAG / DT)), z))
        x = drift + G @ rng.multivariate_normal(np.zeros(bundle.n_w), Qw / DT)  # w of density Qw held over the step
        y = bundle.h(x)
        for s in ticks:
            rows = rows_of(bundle, s)
            Z[s][k] = y[rows] + rng.multivariate_normal(np.zeros(rows.stop - rows.start), R[s])
    P0 = np.eye(n) * 0.1
    return Scenario(t=t, U=U, Z=Z, fixes=fixes, x0=x0, P0=P0, Qw=Qw, ticks=tuple(ticks), delayed=delayed)


# ------------------------------------------------------------------------------------------- the three ways
def run_in_order(bundle, sc: Scenario, fixes: bool = True, history_seconds: float = 0.0, timer=None):
    """Every fix at its stamp, in time order (the reference); x, P after every step (and the filter). With `timer` (a
    dict), the perf_counter seconds of each fix's two calls are appended to timer["fix"]."""
    from abyssal import EKF

    flt = steady(EKF(bundle, sc.x0, sc.P0, sc.Qw, None, history_seconds=history_seconds, **OPTIONS))
    at = {j: (stamp, z) for stamp, j, _, z in sc.fixes} if fixes else {}
    xs, Ps = [], []
    clock = time.perf_counter
    for k in range(1, len(sc.t)):
        if k - 1 in at:
            stamp, z = at[k - 1]
            t0 = clock()
            flt.predict_to(stamp, sc.U[k])
            flt.update(sc.delayed, z, stamp)
            if timer is not None:
                timer["fix"].append(clock() - t0)
        flt.predict_to(sc.t[k], sc.U[k])
        for s in sc.ticks:
            flt.update(s, sc.Z[s][k], sc.t[k])
        xs.append(flt.x)
        Ps.append(flt.P)
    return np.array(xs), np.array(Ps), flt


def run_replay(bundle, sc: Scenario, timer=None):
    """The fixes arrive LAG late and are fused at their stamps from the history. With `timer` (a dict), the
    perf_counter seconds of every step and of every late update are appended to timer["step"], timer["late"]."""
    from abyssal import EKF

    flt = steady(EKF(bundle, sc.x0, sc.P0, sc.Qw, None, history_seconds=HISTORY_SECONDS, **OPTIONS))
    arrive: dict = {}
    for stamp, _, k_arrival, z in sc.fixes:
        arrive.setdefault(k_arrival, []).append((stamp, z))
    xs, Ps = [], []
    clock = time.perf_counter
    for k in range(1, len(sc.t)):
        t0 = clock()
        flt.predict_to(sc.t[k], sc.U[k])
        for s in sc.ticks:
            flt.update(s, sc.Z[s][k], sc.t[k])
        t1 = clock()
        for stamp, z in arrive.get(k, ()):
            flt.update(sc.delayed, z, stamp)
            if timer is not None:
                timer["late"].append(clock() - t1)
        if timer is not None:
            timer["step"].append(t1 - t0)
            continue
        xs.append(flt.x)
        Ps.append(flt.P)
    return np.array(xs), np.array(Ps), flt


#: the cloned EKF's repair_floor. P_aug = [[P, P], [P, P]] is singular by construction (rank n) and stays so until
#: the noise has reached every direction; the runtime checks P by a Cholesky factor after every update and repairs
#: one that fails by clipping its eigenvalues at repair_floor x the largest (default 1e-10): a change of 1e-10
#: relative to P. At 1e-15 the repair changes P at rounding level only.
CLONE_REPAIR_FLOOR = 1e-15


def run_cloning(bundle, aug, sc: Scenario, resets=None, repair_floor: float = CLONE_REPAIR_FLOOR):
    """The fixes arrive LAG late and are fused by stochastic cloning: an EKF on the cloned model carries [x; x_c]
    from the stamp to the arrival, then the model's EKF takes the x block back. Stacked calls (predict(u, dt),
    update(z) with one sensor's rows present, in the in-order run's order) with the dt the stamps give."""
    from abyssal import EKF

    n = bundle.n_x
    base = steady(EKF(bundle, sc.x0, sc.P0, sc.Qw, None, **OPTIONS))
    big = steady(EKF(aug, np.concatenate([sc.x0, sc.x0]), np.kron(np.ones((2, 2)), sc.P0), sc.Qw, None,
                     repair_floor=repair_floor, **OPTIONS))
    tick_rows = {m: {s: rows_of(m, s) for s in sc.ticks} for m in (bundle, aug)}
    zs = {m: np.full(m.n_y, np.nan) for m in (bundle, aug)}
    clone_rows = rows_of(aug, f"{sc.delayed}_clone")
    stamps = {j: (stamp, k_arrival, z) for stamp, j, k_arrival, z in sc.fixes}
    flt, model, arrival, pending = base, bundle, None, None
    t_prev = sc.t[0]
    xs, Ps = [], []
    clock = time.perf_counter
    for k in range(1, len(sc.t)):
        if k - 1 in stamps:
            stamp, arrival, pending = stamps[k - 1]
            base.predict(sc.U[k], stamp - t_prev)
            t_prev = stamp
            x, P = base.x, base.P
            t0 = clock()
            big.reset(np.concatenate([x, x]), np.block([[P, P], [P, P]]))
            if resets is not None:
                resets.append(clock() - t0)
            flt, model = big, aug
        flt.predict(sc.U[k], sc.t[k] - t_prev)
        t_prev = sc.t[k]
        z = zs[model]
        for s in sc.ticks:
            rows = tick_rows[model][s]
            z[:] = np.nan
            z[rows] = sc.Z[s][k]
            flt.update(z)
        if arrival == k:
            z = zs[aug]
            z[:] = np.nan
            z[clone_rows] = pending
            big.update(z)
            x, P = big.x, big.P
            t0 = clock()
            base.reset(x[:n], P[:n, :n])
            if resets is not None:
                resets.append(clock() - t0)
            flt, model, arrival = base, bundle, None
        x = flt.x
        xs.append(x[:n])
        Ps.append(flt.P[:n, :n])
    return np.array(xs), np.array(Ps), big


def settled(sc: Scenario) -> np.ndarray:
    """Indices (into the per-step records, step k at k - 1) of the steps where no fix is pending: every method has
    fused the same measurements there."""
    pending = np.zeros(len(sc.t) - 1, dtype=bool)
    for _, j, k_arrival, _ in sc.fixes:
        pending[j: k_arrival - 1] = True  # steps j+1 .. k_arrival-1 (records j .. k_arrival-2)
    return np.flatnonzero(~pending)


def agreement(reference, other, sc: Scenario, bundle=None) -> dict:
    (xr, Pr), (xo, Po) = reference[:2], other[:2]
    keep = settled(sc)
    dx, dP = np.abs(xo[keep] - xr[keep]), np.abs(Po[keep] - Pr[keep])
    out = {"x_rel": float(dx.max() / max(1.0, np.abs(xr[keep]).max())), "P_rel": float(dP.max() / np.abs(Pr[keep]).max()),
           "steps_compared": int(len(keep))}
    if bundle is not None and bundle.name.startswith("rov4dof"):
        sigma = np.sqrt(np.maximum(np.diagonal(Pr[keep], axis1=1, axis2=2)[:, :2], 1e-300))
        out["position_m"] = float(np.hypot(*(xo[keep, :2] - xr[keep, :2]).T).max())
        out["position_over_sigma"] = float((np.abs(xo[keep, :2] - xr[keep, :2]) / sigma).max())
        out["heading_rad"] = float(np.abs(np.angle(np.exp(1j * (xo[keep, 3] - xr[keep, 3])))).max())
    return out


def delayed_fix_runs(bundle, aug, sc: Scenario) -> dict:
    """The three ways on one scenario: their per-step x, P and their agreement with the in-order run."""
    reference = run_in_order(bundle, sc)
    replay = run_replay(bundle, sc)
    clone = run_cloning(bundle, aug, sc)
    from abyssal.runtime.numerics import REPAIR_FLOOR

    default_floor = run_cloning(bundle, aug, sc, repair_floor=REPAIR_FLOOR)
    return {"in_order": reference, "replay": replay, "cloning": clone,
            "replay_vs_in_order": agreement(reference, replay, sc, bundle),
            "cloning_vs_in_order": agreement(reference, clone, sc, bundle),
            "cloning_default_repair_floor_vs_in_order": agreement(reference, default_floor, sc, bundle),
            "late": replay[2].late, "clone_repairs": clone[2].repairs}


# ------------------------------------------------------------------------------------------- timing helpers
def timer_overhead(samples: int = 20000) -> float:
    clock = time.perf_counter
    best = []
    for _ in range(5):
        durations = []
        for _ in range(samples // 5):
            t0 = clock()
            durations.append(clock() - t0)
        best.append(statistics.median(durations))
    return min(best)


def cpu(fn) -> float:
    c0 = time.process_time()
    fn()
    return time.process_time() - c0


# ------------------------------------------------------------------------------------------- (a)
KINDS = ("sensor", "stacked, its rows", "stacked, all rows")


def one_sensor_vs_stacked(bundle, sc: Scenario, rounds: int, overhead: float) -> dict:
    """Per sensor: µs of update(sensor, z_k, t), of the stacked update(z) with only k's rows, of the full stacked
    update(z), from Python and as the C call alone; median per call in a round, minimum over rounds (the timer's cost
    subtracted); and per sensor and side the ratio of update(sensor, z, t) to the stacked update with its rows, the
    median over rounds of each round's own ratio (its two measurements adjacent in time)."""
    from abyssal import EKF
    from abyssal.runtime.compiled import kalman as kr

    clock = time.perf_counter
    sensors = list(bundle.sensor_names)
    Zfull = np.column_stack([sc.Z[s] for s in sensors])  # the sensors' rows in the stacked order
    keys = [(s, kind, side) for s in sensors for kind in KINDS for side in ("python", "c")]
    rounds_of = {key: [] for key in keys}
    steps = len(sc.t) - 1
    for _ in range(rounds):
        for s in sensors:
            rows = rows_of(bundle, s)
            masked = np.full_like(Zfull, np.nan)
            masked[:, rows] = Zfull[:, rows]
            for kind in KINDS:
                for side in ("python", "c"):
                    flt = steady(EKF(bundle, sc.x0, sc.P0, sc.Qw, None, **OPTIONS))
                    durations = []
                    if side == "c":  # the runtime's entry point alone, through the filter's bound call (what the
                        io = flt._io  # Python methods fill and call: the engine's private call block)
                        call = flt._call_update_sensor if kind == "sensor" else flt._call_update
                        io[kr.BLOCK_SENSOR], io[kr.BLOCK_HAS_R], io[kr.BLOCK_HAS_Q] = bundle.sensor_names.index(s), 0, 0
                    for k in range(1, steps + 1):
                        if kind == "sensor":
                            flt.predict_to(sc.t[k], sc.U[k])
                            z = sc.Z[s][k]
                            if side == "c":
                                flt._z[: len(z)] = z
                                io[kr.BLOCK_TIME] = sc.t[k]
                                t0 = clock()
                                call()
                                durations.append(clock() - t0)
                                assert flt.code >= 0, flt.code
                                continue
                            t0 = clock()
                            flt.update(s, z, sc.t[k])
                            durations.append(clock() - t0)
                        else:
                            flt.predict(sc.U[k], DT)
                            z = masked[k] if kind == "stacked, its rows" else Zfull[k]
                            if side == "c":
                                flt._z[:] = z
                                t0 = clock()
                                call()
                                durations.append(clock() - t0)
                                assert flt.code >= 0, flt.code
                                continue
                            t0 = clock()
                            flt.update(z)
                            durations.append(clock() - t0)
                    rounds_of[(s, kind, side)].append(statistics.median(durations) - overhead)
    table = {s: {side: {kind: 1e6 * min(rounds_of[(s, kind, side)]) for kind in KINDS} for side in ("python", "c")}
             for s in sensors}
    for s in sensors:
        for side in ("python", "c"):
            table[s][side]["ratio"] = paired_ratio(rounds_of[(s, "sensor", side)], rounds_of[(s, "stacked, its rows", side)])
    return table


def unit_watch_cost(bundle, sc: Scenario, sensor: str, rounds: int, overhead: float) -> dict:
    """µs of update(sensor, z, t) with the unit watch as the engine leaves it and without it, when only `sensor`
    reports: the watch over the other sensors' outputs never collects its samples, so it never ends (median per
    call after the sensor's own 8 samples, minimum over rounds)."""
    from abyssal import EKF

    clock = time.perf_counter
    best = {"watch on": math.inf, "watch off": math.inf}
    still = False
    for _ in range(rounds):
        for label in ("watch on", "watch off"):
            flt = EKF(bundle, sc.x0, sc.P0, sc.Qw, None, **OPTIONS)
            if label == "watch off":
                steady(flt)
            durations = []
            for k in range(1, len(sc.t)):
                flt.predict_to(sc.t[k], sc.U[k])
                t0 = clock()
                flt.update(sensor, sc.Z[sensor][k], sc.t[k])
                durations.append(clock() - t0)
            best[label] = min(best[label], statistics.median(durations[20:]) - overhead)
            if label == "watch on":
                still = getattr(flt, "_unit_watch", None) is not None
    return {"watch_on_us": 1e6 * best["watch on"], "watch_off_us": 1e6 * best["watch off"],
            "still_watching_at_the_end": still}


# ------------------------------------------------------------------------------------------- (c)
def stamped_overhead(rov, rounds: int, steps: int = 300) -> dict:
    """rov4dof, constant input: step(u, dt, z) vs update("measurement", z, t) one dt ahead (the same predict and
    update in one call) vs predict_to + update; µs per call (process CPU of passes, minimum over rounds)."""
    from abyssal import EKF

    rng = np.random.default_rng(1)
    u = np.array([20.0, 5.0, 10.0, 0.2])
    x = np.zeros(12)
    Z = np.empty((steps, 4))
    for k in range(steps):
        x = rov.f(x, u, None, 0.1)
        Z[k] = rov.h(x) + rng.normal(scale=[0.2, 0.2, 0.1, 0.05])
    Q, R = np.diag([1e-4] * 8 + [1e-2] * 4), np.diag([0.05, 0.05, 0.02, 0.01])
    x0, P0 = np.zeros(12), 0.3 * np.eye(12)
    stamps = [0.1 * (k + 1) for k in range(steps)]
    dts = [b - a for a, b in zip([0.0] + stamps, stamps)]  # the runtime's t - t_prev: the same bits for both
    checked = {}

    def make():
        flt = steady(EKF(rov, x0, P0, Q, R, gate_probability=0.0))
        flt.predict_to(0.0, u)  # the held input (t equal to the filter's time: no integration)
        return flt

    def stepped():
        flt = make()
        c0 = time.process_time()
        for k in range(steps):
            flt.step(u, dts[k], Z[k])
        checked["step"] = flt
        return time.process_time() - c0

    def stamped():
        flt = make()
        c0 = time.process_time()
        for k in range(steps):
            flt.update("measurement", Z[k], stamps[k])
        checked["stamped"] = flt
        return time.process_time() - c0

    def two_calls():
        flt = make()
        c0 = time.process_time()
        for k in range(steps):
            flt.predict_to(stamps[k], u)
            flt.update("measurement", Z[k], stamps[k])
        return time.process_time() - c0

    best = {"step": math.inf, "stamped": math.inf, "two_calls": math.inf}
    for round_ in range(rounds + 1):
        for name, fn in (("step", stepped), ("stamped", stamped), ("two_calls", two_calls))[:: 1 if round_ % 2 else -1]:
            value = fn()
            if round_:
                best[name] = min(best[name], value)
    a, b = checked["step"], checked["stamped"]
    return {"step_us": 1e6 * best["step"] / steps, "stamped_us": 1e6 * best["stamped"] / steps,
            "predict_to_plus_update_us": 1e6 * best["two_calls"] / steps,
            "same_work": bool(np.array_equal(a.x, b.x) and np.array_equal(a.P, b.P)),
            "max_abs_difference": float(max(np.abs(a.x - b.x).max(), np.abs(a.P - b.P).max()))}


# ------------------------------------------------------------------------------------------- (b) and (d)
def delayed_costs(bundle, aug, sc: Scenario, rounds: int) -> dict:
    """CPU per whole run of each way (minimum over interleaved rounds), the per-fix costs by difference with the run
    without fixes, and the per-call medians of the replay run (steps, late updates) for (b)."""
    none = dataclasses.replace(sc, fixes=[])
    runs = {
        "without fixes": lambda: run_in_order(bundle, none),
        "without fixes, history kept": lambda: run_replay(bundle, none),
        "in order": lambda: run_in_order(bundle, sc),
        "replay": lambda: run_replay(bundle, sc),
        "cloning": lambda: run_cloning(bundle, aug, sc),
    }
    best = {name: math.inf for name in runs}
    step_median, late_median, reset_median, fix_median = math.inf, math.inf, math.inf, math.inf
    for round_ in range(rounds + 1):
        names = list(runs) if round_ % 2 else list(runs)[::-1]
        for name in names:
            value = cpu(runs[name])
            if round_:
                best[name] = min(best[name], value)
        timer = {"step": [], "late": []}
        run_replay(bundle, sc, timer)
        resets: list = []
        run_cloning(bundle, aug, sc, resets)
        in_order = {"fix": []}
        run_in_order(bundle, sc, timer=in_order)
        if round_:
            fix_median = min(fix_median, statistics.median(in_order["fix"]))
            step_median = min(step_median, statistics.median(timer["step"]))
            late_median = min(late_median, statistics.median(timer["late"]))
            reset_median = min(reset_median, statistics.median(resets))
    fixes = len(sc.fixes)
    per_fix = {name: 1e6 * (best[name] - best["without fixes"]) / fixes for name in ("in order", "replay", "cloning")}
    per_fix["replay, beyond the history's upkeep"] = 1e6 * (best["replay"] - best["without fixes, history kept"]) / fixes
    return {"fixes": fixes, "steps": len(sc.t) - 1, "run_cpu_ms": {k: 1e3 * v for k, v in best.items()},
            "per_fix_us": per_fix, "cloning_resets_per_fix_us": 2e6 * reset_median,
            "history_upkeep_per_step_us": 1e6 * (best["without fixes, history kept"] - best["without fixes"]) / (len(sc.t) - 1),
            "replay_step_us": 1e6 * step_median, "late_update_us": 1e6 * late_median,
            "in_order_fix_calls_us": 1e6 * fix_median,
            "late_update_in_steps": late_median / step_median}


# ------------------------------------------------------------------------------------------- the section
def run(quick: bool = False, verbose: bool = True) -> dict:
    from abyssal import generated

    say = print if verbose else (lambda *a, **k: None)
    from bench_scaling import machine

    rounds = 3 if quick else 9
    seconds = 10.0 if quick else 60.0
    results: dict = {"machine": machine(), "rounds": rounds, "seconds_per_run": seconds}
    say(f"sensors and time: {results['machine']}, {rounds} interleaved rounds, minima", flush=True)
    rov_s = load(rov4dof_sensors)
    lin_s = load(linear_cv_sensors)
    overhead = timer_overhead()
    results["perf_counter_overhead_us"] = 1e6 * overhead

    # (a)
    models = [rov_s] + ([] if quick else [load(remus100_sensors)])
    results["one_sensor_vs_stacked_us"] = {}
    for bundle in models:
        sc = scenario(bundle, bundle.sensor_names, bundle.sensor_names[0], 5.0 if quick else 10.0)
        table = one_sensor_vs_stacked(bundle, sc, rounds, overhead)
        results["one_sensor_vs_stacked_us"][bundle.name] = table
        say(f"(a) {bundle.name}: µs per update, median per call, minimum over rounds (perf_counter, its "
            f"{1e6 * overhead:.3f} µs subtracted)")
        for s, sides in table.items():
            for side, row in sides.items():
                say(f"    {s:<6} {'from Python' if side == 'python' else 'C call alone':<12} update(sensor, z, t) "
                    f"{row['sensor']:6.2f}   stacked, its rows {row['stacked, its rows']:6.2f}   stacked, all rows "
                    f"{row['stacked, all rows']:6.2f}   ratio to its rows {row['ratio']:.2f} (median of the rounds' own)")

    sc = scenario(rov_s, rov_s.sensor_names, "usbl", 5.0 if quick else 10.0)
    watch = unit_watch_cost(rov_s, sc, "depth", rounds, overhead)
    results["unit_watch_depth_only"] = watch
    say(f"    the unit watch, rov4dof_sensors, only 'depth' reporting: update('depth', z, t) {watch['watch_on_us']:.2f} µs "
        f"as the engine leaves it (still watching the others after {len(sc.t) - 1} updates: "
        f"{watch['still_watching_at_the_end']}), {watch['watch_off_us']:.2f} µs without the watch")

    # (c)
    rov = generated.load("rov4dof")
    stamped = stamped_overhead(rov, rounds)
    results["stamped_call"] = stamped
    say(f"(c) rov4dof, µs per call (CPU, minimum over rounds): step {stamped['step_us']:.3f}, update(sensor, z, t) one "
        f"dt ahead {stamped['stamped_us']:.3f} (+{stamped['stamped_us'] - stamped['step_us']:.3f}), predict_to + update "
        f"{stamped['predict_to_plus_update_us']:.3f}; same results: {stamped['same_work']} "
        f"(max |difference| {stamped['max_abs_difference']:.3g})")

    # (b) and (d)
    results["delayed_fix"] = {}
    for bundle, ticks, build in ((lin_s, ("dvl",), lambda: cloned(linear_cv_sensors(), "usbl")),
                                 (rov_s, ("depth", "ahrs"), lambda: cloned(rov4dof_sensors(), "usbl"))):
        aug = load(build)
        sc = scenario(bundle, ticks, "usbl", seconds)
        runs = delayed_fix_runs(bundle, aug, sc)
        costs = delayed_costs(bundle, aug, sc, rounds)
        entry = {"ticks": list(ticks), "agreement": {
                     "replay": runs["replay_vs_in_order"], "cloning": runs["cloning_vs_in_order"],
                     "cloning, default repair_floor": runs["cloning_default_repair_floor_vs_in_order"]},
                 "late": runs["late"], "clone_repairs": runs["clone_repairs"], **costs}
        results["delayed_fix"][bundle.name] = entry
        say(f"(b, d) {bundle.name}: 20 Hz steps ({' + '.join(ticks)}), {costs['fixes']} USBL fixes 1 s late over "
            f"{costs['steps']} steps")
        say(f"    replay: late update {costs['late_update_us']:.1f} µs = {costs['late_update_in_steps']:.1f} steps of "
            f"{costs['replay_step_us']:.2f} µs (medians per call, minimum over rounds)")
        for name, us in costs["per_fix_us"].items():
            say(f"    per delayed fix, {name:<36} {us:8.1f} µs CPU")
        say(f"    in order, the fix's predict_to + update alone {costs['in_order_fix_calls_us']:.1f} µs (median per fix); "
            f"cloning, its two resets per fix {costs['cloning_resets_per_fix_us']:.1f} µs; the history's upkeep "
            f"{costs['history_upkeep_per_step_us']:.2f} µs per step")
        for name, agree in entry["agreement"].items():
            extra = "".join(f", {k} {agree[k]:.3g}" for k in ("position_m", "position_over_sigma", "heading_rad")
                            if k in agree)
            say(f"    {name} vs in order: max |dx| / max |x| {agree['x_rel']:.3g}, max |dP| / max |P| "
                f"{agree['P_rel']:.3g}{extra} ({agree['steps_compared']} settled steps)")

    targets = []
    for s, sides in results["one_sensor_vs_stacked_us"]["rov4dof_sensors"].items():
        for side, label in (("python", "from Python"), ("c", "the C call alone")):
            row = sides[side]
            targets.append(target(f"rov4dof_sensors: update({s!r}, z, t) / the stacked update with its rows, {label}",
                                  row["ratio"], 1.0, "x"))
    rov_fix = results["delayed_fix"]["rov4dof_sensors"]
    targets.append(target("rov4dof_sensors: a fix 1 s late at 20 Hz (replay from the history) / one in-order step",
                          rov_fix["late_update_in_steps"], 25.0, "steps"))
    targets.append(target("rov4dof: update(sensor, z, t) over step(u, dt, z), the same work from Python",
                          stamped["stamped_us"] - stamped["step_us"], 0.3, "µs"))
    lin_fix = results["delayed_fix"]["linear_cv_sensors"]
    targets.append(target("linear_cv_sensors: replay vs the in-order run (max |dx| / max |x|)",
                          lin_fix["agreement"]["replay"]["x_rel"], 1e-12, ""))
    targets.append(target("linear_cv_sensors: cloning vs the in-order run (max |dx| / max |x|)",
                          lin_fix["agreement"]["cloning"]["x_rel"], 1e-12, ""))
    targets.append(target("rov4dof_sensors: replay vs the in-order run (max |dx| / max |x|)",
                          rov_fix["agreement"]["replay"]["x_rel"], 1e-12, ""))
    return {"results": results, "targets": targets}


def main(argv=None) -> int:
    import argparse
    import json

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer rounds, shorter runs, no REMUS 100 (smoke run)")
    parser.add_argument("--json", action="store_true", help="the section's report as JSON on stdout (no tables)")
    args = parser.parse_args(argv)
    if args.json:
        print(json.dumps(run(quick=args.quick, verbose=False), indent=1, default=float))
        return 0
    report = run(quick=args.quick, verbose=True)
    print("targets:")
    for t in report["targets"]:
        print(f"  {'met ' if t['met'] else 'MISS'}  {t['name']}: {t['value']:.4g} {t['unit']} "
              f"(target {t['direction']} {t['limit']:g})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
