"""`abyssal bench DIR...`: timings of a user's generated model folder (medians, this machine).

Per folder: ns per call of f, F, h on the fast path (preallocated buffers) and through the
convenience call; ns per particle of f_batch (the SIMD structure-of-arrays kernel) for N = 1000
and 10000; us per step() (predict + update, a fixed measurement) of every Kalman-family filter
generated for the model. Nothing is
asserted: these are measurements to compare models and machines, printed or emitted as JSON.
"""
from __future__ import annotations

import json

import numpy as np

from bench import median_time

PARTICLES = (1000, 10000)


def bench_bundle(bundle, quick: bool = False) -> dict:
    from abyssal.runtime.filters.kalman import CKF, EKF, UKF

    timer = (lambda fn: median_time(fn, repeat=3, min_time=0.01)) if quick else median_time
    rng = np.random.default_rng(0)
    x, u, p, dt = 0.1 * rng.normal(size=bundle.n_x), 0.1 * rng.normal(size=bundle.n_u), bundle.params(), np.array([0.1])
    args = {"x": x, "u": u, "p": p, "dt": dt}
    per_call = {}
    for name in ("f", "F", "h"):
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
    per_step = {}
    z = bundle.h(x, p)
    P0, Q, R = 0.1 * np.eye(bundle.n_x), 1e-4 * np.eye(bundle.n_x), 1e-2 * np.eye(bundle.n_y)
    for cls in (EKF, UKF, CKF):
        if cls.predict_function not in bundle.functions:
            continue
        flt = cls(bundle, x, P0, Q, R)
        per_step[cls.__name__] = {"step_us": timer(lambda: flt.step(u, 0.1, z)) * 1e6}  # a fixed z keeps it bounded
    return {"model": bundle.name, "folder": str(bundle.folder), "per_call": per_call, "per_particle": per_particle,
            "per_step": per_step}


def main(folders, json_output: bool = False, quick: bool = False) -> int:
    from abyssal import generated

    results = [bench_bundle(generated.load(folder), quick) for folder in folders]
    if json_output:
        print(json.dumps(results, indent=1))
        return 0
    for res in results:
        print(f"{res['model']} ({res['folder']}), medians on this machine")
        for name, row in res["per_call"].items():
            print(f"  {name:<3} fast path {row['fast_path_ns']:8.1f} ns   convenience {row['convenience_ns']:8.1f} ns")
        for n, row in res["per_particle"].items():
            print(f"  f_batch (SIMD) N = {n:>6}: {row['f_soa_ns']:7.1f} ns per particle")
        for name, row in res["per_step"].items():
            print(f"  {name} step() (predict + update): {row['step_us']:7.2f} us")
    return 0
