"""`abyssal bench DIR...`: timings of a user's generated model folder (medians of process CPU time, this machine).

Per folder: ns per call of f, F, h (and of each sensor's own h when the model has several sensors) on the fast
path (preallocated buffers) and through the convenience call; ns per particle of the SIMD structure-of-arrays f
kernel for N = 1000 and 10000; us per step() (predict + update of every sensor stacked, a fixed measurement) of
every Kalman filter -- EKF, UKF, CKF, MCUKF and HuberUKF all run on any model folder (the C runtime holds their
algebra) -- and, with several sensors, us per stamped ``update(sensor, z, t)`` of each sensor alone (the CKF's).
The filters are timed in their steady state, without the unit watch of their first updates (bench_sensors.steady:
a filter fed one sensor alone would otherwise evaluate h from Python on every update, the other sensors' outputs
never collecting their samples). Nothing is asserted: these are measurements to compare models and machines,
printed or emitted as JSON.
"""
from __future__ import annotations

import json
import time

import numpy as np

from bench import median_time
from bench_sensors import steady

PARTICLES = (1000, 10000)
DT = 0.1


def _filters():
    from abyssal.runtime.filters.kalman import CKF, EKF, MCUKF, UKF, HuberUKF

    return (EKF, UKF, CKF, MCUKF, HuberUKF)


def bench_bundle(bundle, quick: bool = False) -> dict:
    from abyssal.runtime.filters.kalman import CKF

    repeat, min_time = (3, 0.01) if quick else (7, 0.05)

    def timer(fn):  # CPU time: steadier than wall time on a shared machine (every call here is single-threaded)
        return median_time(fn, repeat=repeat, min_time=min_time, clock=time.process_time)
    rng = np.random.default_rng(0)
    x, u, p, dt = 0.1 * rng.normal(size=bundle.n_x), 0.1 * rng.normal(size=bundle.n_u), bundle.params(), np.array([DT])
    args = {"x": x, "u": u, "p": p, "dt": dt}
    sensors = list(bundle.sensor_names)
    names = ["f", "F", "h"] + ([f"{s}_h" for s in sensors if f"{s}_h" in bundle.functions] if len(sensors) > 1 else [])
    per_call = {}
    for name in names:
        fn = bundle.functions[name]
        ins = [args[s.name] for s in fn.inputs]
        fast = fn.bind(ins, [np.zeros(s.shape, order="F") for s in fn.outputs]).eval
        per_call[name] = {"fast_path_ns": timer(fast) * 1e9, "convenience_ns": timer(lambda: fn(*ins)) * 1e9}
    per_particle = {}
    for n in PARTICLES:
        X = np.ascontiguousarray(x[:, None] + 0.01 * rng.normal(size=(bundle.n_x, n)))
        U = np.ascontiguousarray(np.repeat(u[:, None], n, axis=1))
        Y = np.zeros((bundle.n_x, n))
        simd = bundle.functions["f"].bind_soa([X, U, p, dt], [Y])
        per_particle[str(n)] = {"f_soa_ns": timer(lambda: simd(n)) * 1e9 / n}
    z = bundle.h(x, p)
    P0, Q, R = 0.1 * np.eye(bundle.n_x), 1e-4 * np.eye(bundle.n_x), 1e-2 * np.eye(bundle.n_y)
    per_step = {}
    for cls in _filters():
        flt = steady(cls(bundle, x, P0, Q, R))
        per_step[cls.__name__] = {"step_us": timer(lambda: flt.step(u, DT, z)) * 1e6}  # a fixed z keeps it bounded
    per_sensor = {}
    if len(sensors) > 1:
        for k, sensor in enumerate(sensors):
            spec = bundle.sensors[k]
            rows = slice(spec["offset"], spec["offset"] + len(spec["outputs"]))
            flt = steady(CKF(bundle, x, P0, Q, R))
            clock = [0.0]

            def stamped(flt=flt, z_k=z[rows].copy(), sensor=sensor):  # a predict of DT to a new stamp, then the update
                clock[0] += DT
                flt.predict_to(clock[0], u)
                flt.update(sensor, z_k, clock[0])
            per_sensor[sensor] = {"CKF predict_to + update_us": timer(stamped) * 1e6}
    return {"model": bundle.name, "folder": str(bundle.folder), "sensors": sensors, "per_call": per_call,
            "per_particle": per_particle, "per_step": per_step, "per_sensor": per_sensor}


def main(folders, json_output: bool = False, quick: bool = False) -> int:
    from abyssal import generated

    results = [bench_bundle(generated.load(folder), quick) for folder in folders]
    if json_output:
        print(json.dumps(results, indent=1))
        return 0
    for res in results:
        print(f"{res['model']} ({res['folder']}), medians of CPU time on this machine; sensors "
              f"{', '.join(res['sensors'])}")
        for name, row in res["per_call"].items():
            print(f"  {name:<10} fast path {row['fast_path_ns']:8.1f} ns   convenience {row['convenience_ns']:8.1f} ns")
        for n, row in res["per_particle"].items():
            print(f"  f SoA kernel (SIMD) N = {n:>6}: {row['f_soa_ns']:7.1f} ns per particle")
        for name, row in res["per_step"].items():
            print(f"  {name:<8} step() (predict + update, every sensor stacked): {row['step_us']:7.2f} us")
        for name, row in res["per_sensor"].items():
            print(f"  CKF predict_to(t) + update({name!r}, z, t): {row['CKF predict_to + update_us']:7.2f} us")
    return 0
