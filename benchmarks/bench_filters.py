"""Filter section of `abyssal bench`: per-step (predict + update) cost of the Kalman filters on rov4dof, from Python
and from C, beside peers measured in the same run.

Ours:   the EKF, UKF and CKF classes, ``step(u, dt, z)`` through a simulated trajectory (Python over the C runtime
        of runtime/c: one call per step), and the same runtime called from a C loop (kalman_timing.c, linked with
        the model's and the runtime's libraries from abyssal's compile cache: the code Python calls); the innovation gate's judgement
        of one update alone (C); the bytes of each filter object.
Peers:  filterpy's UnscentedKalmanFilter with MerweScaledSigmaPoints(1, 0, 0) (the same CKF) on the independent
        NumPy model of rov4dof (verify/reference_models.py, written from the paper: a model as a user would write
        it); the whole generated fused ``ckf_step`` / ``ekf_step`` in a C loop (kalman_timing.c), and bound from
        Python without any checks (the core of the previous Python path, which added its checks and its NumPy gate).
Times:  the minimum over repetitions of a whole trajectory (each from a fresh filter), in us per step, so that a
        loaded machine's interruptions are left out as far as they can be; the ratios are what travels between
        machines.

Targets: CKF step <= 2.5 us from C and <= 3 us from Python, and >= 300x faster than filterpy; EKF step <= 1 us from
C and <= 1.2 us from Python; the gate <= 0.1 us.

    python benchmarks/bench_filters.py [--quick]     # this section alone, JSON on stdout
"""
from __future__ import annotations

import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from abyssal import generated
from abyssal.generated.build import BuildError, cflags, compiler
from abyssal.runtime.compiled import kalman as kalman_runtime
from abyssal.runtime.compiled.sources import C_DIR
from abyssal.symbolic.codegen import MODEL_HEADER
from abyssal.runtime.filters.kalman import CKF, EKF, UKF
from abyssal.verify import reference_models

from bench import json_main, target

MODEL = "rov4dof"
DT = 0.1
HERE = Path(__file__).resolve().parent


def trajectory(bundle, steps: int, seed: int = 0):
    """Inputs, measurements and noise matrices of a simulated run."""
    rng = np.random.default_rng(seed)
    n = bundle.n_x
    Q = np.diag([1e-4] * 8 + [1e-2] * 4)
    R = np.diag([0.05, 0.05, 0.02, 0.01])
    t = DT * np.arange(steps)
    # surge, sway and heave thrust with a yaw moment swinging the heading back and forth
    U = np.column_stack([np.full(steps, 20.0), np.full(steps, 5.0), np.full(steps, 10.0), 0.5 * np.sin(0.2 * t)])
    U += 0.5 * rng.normal(size=U.shape)
    x = np.zeros(n)
    Z = np.empty((steps, bundle.n_y))
    for k in range(steps):
        x = bundle.f(x, U[k], None, DT) + rng.multivariate_normal(np.zeros(n), Q)
        Z[k] = bundle.h(x) + rng.multivariate_normal(np.zeros(bundle.n_y), R)
    return np.zeros(n), 0.3 * np.eye(n), Q, R, U, Z


def best_per_step(make, step, steps: int, repeats: int) -> float:
    """Seconds per step: the minimum over `repeats` runs of steps 1..steps-1, each on a fresh object from make()
    (step 0, the one that checks dt's stability, untimed)."""
    best = float("inf")
    for _ in range(repeats):
        obj = make()
        step(obj, 0)
        t0 = time.perf_counter()
        for k in range(1, steps):
            step(obj, k)
        best = min(best, (time.perf_counter() - t0) / (steps - 1))
    return best


def c_runtime_times(bundle, U, Z, repeats: int) -> dict[str, float]:
    """ns per step of the C runtime from a C loop, the gate's ns, and the filter objects' bytes (kalman_timing.c)."""
    with tempfile.TemporaryDirectory(prefix="abyssal-bench-") as tmp:
        tmp = Path(tmp)
        data = tmp / "trajectory.txt"
        with open(data, "w") as fh:
            fh.write(f"{len(U)} {bundle.n_u} {bundle.n_y}\n")
            np.savetxt(fh, np.hstack([U, Z]), fmt="%.17g")
        exe = tmp / "kalman_timing"
        library, runtime = Path(bundle.library), Path(kalman_runtime.KalmanRuntime.of(bundle).library)
        cmd = [compiler(), *cflags(), f"-DDESCRIPTOR={bundle.name}_descriptor", f"-DCKF_STEP={bundle.name}_ckf_step",
               f"-DEKF_STEP={bundle.name}_ekf_step", f"-I{C_DIR}", f"-I{MODEL_HEADER.parent}",
               str(HERE / "kalman_timing.c"), str(library), str(runtime), f"-Wl,-rpath,{library.parent}",
               f"-Wl,-rpath,{runtime.parent}", "-o", str(exe), "-lm"]
        res = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if res.returncode != 0:
            raise BuildError(f"compiling the timing driver failed: {' '.join(cmd)}\n{res.stderr[-4000:]}")
        out = subprocess.run([str(exe), str(data), str(repeats)], capture_output=True, text=True, check=True).stdout
    return {label: float(value) for label, value in (line.split() for line in out.splitlines())}


def filterpy_ckf(bundle, Q, R):
    """filterpy's UKF with cubature points (Merwe 1, 0, 0) on the NumPy reference model of the bundle."""
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    ref = reference_models.REFERENCES[bundle.name]
    p, disc, substeps = bundle.params(), bundle.manifest["discretisation"], bundle.manifest["substeps"]
    points = MerweScaledSigmaPoints(bundle.n_x, alpha=1.0, beta=0.0, kappa=0.0)

    def make():
        ukf = UnscentedKalmanFilter(bundle.n_x, bundle.n_y, DT, hx=lambda s: ref.h(s, p), fx=None, points=points)
        ukf.Q, ukf.R = Q, R
        ukf.x, ukf.P = np.zeros(bundle.n_x), 0.3 * np.eye(bundle.n_x)
        return ukf
    return make, lambda s, u, dt: reference_models.step(ref, s, u, p, dt, disc, substeps)


def run(quick: bool = False, verbose: bool = True) -> dict:
    bundle = generated.load(MODEL)
    steps = 200 if quick else 400
    repeats = 3 if quick else 15
    x0, P0, Q, R, U, Z = trajectory(bundle, steps)
    results: dict = {"model": MODEL, "steps": steps, "repeats": repeats, "per_step_us": {}, "from_c_us": {}}
    py, c = results["per_step_us"], results["from_c_us"]

    for cls in (EKF, UKF, CKF):
        py[cls.__name__] = 1e6 * best_per_step(lambda cls=cls: cls(bundle, x0, P0, Q, R),
                                               lambda f, k: f.step(U[k], DT, Z[k]), steps, repeats)
    timings = c_runtime_times(bundle, U, Z, repeats)
    for name in ("EKF", "UKF", "CKF"):
        c[name] = timings[name] / 1e3
    results["gate_us"] = timings["gate"] / 1e3
    results["filter_object_bytes"] = {name: int(timings[f"{name}_bytes"]) for name in ("EKF", "UKF", "CKF")}

    # the previous path: the whole generated fused step, in C and bound from Python (no checks, no gate)
    args = {"x": np.full(12, 0.3), "P": np.asfortranarray(0.1 * np.eye(12)), "u": U[1], "p": bundle.params(),
            "dt": np.array([DT]), "Q": np.asfortranarray(Q), "z": Z[1], "R": np.asfortranarray(R), "mask": np.ones(4)}
    for name in ("ckf_step", "ekf_step"):
        c[f"generated {name} alone"] = timings[f"generated_{name}"] / 1e3
        fn = bundle.functions[name]
        outs = [np.zeros(s.shape, order="F") for s in fn.outputs]
        ins = [args[s.name].copy(order="F") if args[s.name].ndim == 2 else args[s.name].copy() for s in fn.inputs]
        evaluate = fn.bind(ins, outs).eval
        py[f"generated {name} bound, no checks (previous path's core)"] = 1e6 * best_per_step(
            lambda: None, lambda _, k: evaluate(), steps, repeats)

    fp_steps = 20 if quick else 60
    try:
        make, fx = filterpy_ckf(bundle, Q, R)
    except ImportError:
        results["filterpy"] = "not installed (pip install 'abyssal[test]')"
    else:
        def filterpy_step(ukf, k):
            ukf.predict(fx=lambda s, dt: fx(s, U[k], dt))
            ukf.update(Z[k])
        py["filterpy UKF (cubature points), NumPy model"] = 1e6 * best_per_step(make, filterpy_step, fp_steps,
                                                                                 2 if quick else 5)

    ratios = {"CKF from Python / from C": py["CKF"] / c["CKF"], "EKF from Python / from C": py["EKF"] / c["EKF"],
              "generated ckf_step alone / CKF from C": c["generated ckf_step alone"] / c["CKF"],
              "generated ekf_step alone / EKF from C": c["generated ekf_step alone"] / c["EKF"]}
    filterpy_us = py.get("filterpy UKF (cubature points), NumPy model")
    if filterpy_us is not None:
        ratios["filterpy / CKF"] = filterpy_us / py["CKF"]
    results["ratios"] = ratios

    if verbose:
        print(f"per step (predict + update) on {MODEL}, minimum over {repeats} runs of {steps} steps:")
        for name, us in py.items():
            print(f"  from Python  {name:<58} {us:9.3f} us")
        for name, us in c.items():
            print(f"  from C       {name:<58} {us:9.3f} us")
        print(f"  the gate's judgement of one update (C)                                   {results['gate_us']:9.3f} us")
        for name, b in results["filter_object_bytes"].items():
            print(f"  {name} filter object: {b} bytes")
        for name, ratio in ratios.items():
            print(f"  {name:<58} {ratio:10.1f} x")

    targets = [
        target("CKF step from C (rov4dof)", c["CKF"], 2.5, "us"),
        target("CKF step from Python (rov4dof)", py["CKF"], 3.0, "us"),
        target("EKF step from C (rov4dof)", c["EKF"], 1.0, "us"),
        target("EKF step from Python (rov4dof)", py["EKF"], 1.2, "us"),
        target("innovation gate (one judgement, C)", results["gate_us"], 0.1, "us"),
    ]
    if "filterpy / CKF" in ratios:
        targets.append(target("CKF speed-up over filterpy", ratios["filterpy / CKF"], 300.0, "x", higher_is_better=True))
    return {"results": results, "targets": targets}


if __name__ == "__main__":  # python benchmarks/bench_filters.py [--quick]: this section alone, as JSON
    json_main(run, __doc__)
