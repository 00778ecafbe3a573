"""Bench section (seed 004): ideal UKF and GP-UKF step times on the REMUS 100 helix, GP training time, and the
GP-UKF predict's generated C (size, generation and compile time) at the campaign's GP sizes N.

The GPs' data are run-time inputs of the generated predict (abyssal.symbolic.gp), so its C should not grow with
N; the step time does (the kernel products grow with N d, the variance's triangular factor with N^2 / 2).
Per N: a training set of draw 4 of run 1 (hyperparameters optimised once on 100 regressors and timed, then
conditioned on N: the timing does not depend on their values), the predict's C generated (size, seconds) and
compiled in a fresh cache folder (so the compile is really timed), then one predict + update of each filter on
run 2 (median of repeated loops). Targets: generated file <= 0.5 MB at every N, compile <= 60 s.
"""
from __future__ import annotations

import os
import tempfile

import numpy as np

from bench import median_time, target

TRAINING_SIZES = (100, 400, 1600)
QUICK_SIZES = (100,)


def run(quick: bool = False, verbose: bool = True) -> dict:
    from abyssal.generated import load

    from abyssal.runtime.experiments.remus import experiment, gp_codegen, gp_model, scenario
    from abyssal.runtime.filters.kalman import UKF
    from abyssal.runtime.filters.kalman.gp_ukf import GPUKF

    bundle = load("remus100")
    duration = 300.0 if quick else 800.0
    setup = scenario.HelixSetup(duration=duration)
    training, evaluation = scenario.simulate(1, setup, bundle), scenario.simulate(2, setup, bundle)
    repeat, min_time = (3, 0.02) if quick else (7, 0.1)
    P0 = np.diag(experiment.P0_DIAG)
    Q = experiment.process_noise(training, bundle)

    def timed_step(filt):
        k = [1]

        def step():
            i = k[0]
            filt.predict(evaluation.u[i - 1], 0.2)
            filt.update(evaluation.z[i])
            k[0] = i + 1 if i + 1 < len(evaluation.t) else 1
        return step

    ukf = UKF(bundle, evaluation.x[0], P0, Q, scenario.SENSOR_R, gate_probability=0.0)
    results = {"ukf_step_ms": 1e3 * median_time(timed_step(ukf), repeat=repeat, min_time=min_time), "gp": {}}
    if verbose:
        print(f"  ideal UKF (remus100, 2 RK4 substeps)  {results['ukf_step_ms']:8.3f} ms/step", flush=True)
    sizes = QUICK_SIZES if quick else TRAINING_SIZES
    sets = gp_model.fit_draw(training, 4, sizes, hyper_max=100)
    previous_cache = os.environ.get("ABYSSAL_CACHE_DIR")
    for n, training_set in sets.items():
        with tempfile.TemporaryDirectory() as tmp:
            path = training_set.save(os.path.join(tmp, f"n{n}.npz"))
            layout, data = gp_model.runtime_data(str(path), gp_model.file_digest(path))
            os.environ["ABYSSAL_CACHE_DIR"] = os.path.join(tmp, "cache")  # a cold compile, timed
            try:
                compiled = gp_codegen.build_predict(n, tmp, name=f"remus_gpukf_bench_n{n}")
                gpukf = GPUKF(bundle, compiled.library, compiled.name, evaluation.x[0], P0, scenario.SENSOR_R, gp_dt=0.2,
                              gp_data=data, gate_probability=0.0)
                step_ms = 1e3 * median_time(timed_step(gpukf), repeat=repeat, min_time=min_time)
            finally:
                if previous_cache is None:
                    os.environ.pop("ABYSSAL_CACHE_DIR", None)
                else:
                    os.environ["ABYSSAL_CACHE_DIR"] = previous_cache
        row = {"train_s": sets[min(sets)].train_seconds, "c_bytes": compiled.c_bytes, "data_bytes": layout.nbytes(),
               "generate_s": compiled.generate_seconds, "compile_s": compiled.compile_seconds, "gpukf_step_ms": step_ms}
        results["gp"][f"N={n}"] = row
        if verbose:
            print(f"  GP-UKF N = {n:4d}: hyperparameters (12 GPs, 100 points) {row['train_s']:6.1f} s, C "
                  f"{row['c_bytes'] / 1e6:5.2f} MB, data {row['data_bytes'] / 1e6:6.1f} MB, generate "
                  f"{row['generate_s']:4.1f} s, compile {row['compile_s']:5.1f} s, step {step_ms:7.3f} ms "
                  f"({step_ms / results['ukf_step_ms']:.0f}x the UKF)", flush=True)
    targets = []
    for key, row in results["gp"].items():
        targets.append(target(f"GP-UKF predict C size, {key}", row["c_bytes"] / 1e6, 0.5, "MB"))
        targets.append(target(f"GP-UKF predict compile, {key}", row["compile_s"], 60.0, "s"))
    return {"results": results, "targets": targets}
