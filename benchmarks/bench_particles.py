"""Bench section: per-step time of the particle filters on rov4dof at N = 300 and 3000.

Each filter runs on the seed-000 scenario (sea state 3, the hardest noise: two-component
measurement mixture); a step is predict + update + (re)sampling, measured as the median of
repeated loops (``bench.median_time``). Targets at N = 300 (the paper's particle count):
EM-MOGCPF <= 2 ms, CPF <= 1.5 ms, PF <= 0.1 ms. The CKF and the Gaussian-sum CKF are timed
as peers.
"""
from __future__ import annotations

import itertools
import json
import sys

import numpy as np

from bench import median_time, target

TARGETS_MS = {"EM-MOGCPF": 2.0, "CPF": 1.5, "PF": 0.1}
FILTERS = ("PF", "CPF", "MOGCPF", "EM-MOGCPF", "GS-CKF", "CKF")


def run(quick: bool = False, verbose: bool = True) -> dict:
    from abyssal.generated import load

    from abyssal.runtime.experiments.rov.scenario import SEA_STATES, RovScenario, make_filter, simulate

    bundle = load("rov4dof")
    scenario = RovScenario()
    sea = SEA_STATES["3"]
    truth = simulate(bundle, scenario, sea, np.random.default_rng(0), n_steps=400)
    repeat, min_time = (3, 0.02) if quick else (7, 0.1)
    results: dict[str, dict[str, float]] = {}
    for n_particles in (300, 3000):
        row = {}
        for name in FILTERS:
            filt = make_filter(name, bundle, scenario, sea, n_particles, np.random.default_rng(1))
            steps = itertools.cycle(range(truth.states.shape[0]))

            def step():
                k = next(steps)
                filt.step(truth.inputs[k], scenario.dt, truth.measurements[k])

            for _ in range(20):  # leave the initial transient
                step()
            row[name] = 1e3 * median_time(step, repeat=repeat, min_time=min_time)
            if verbose:
                print(f"  N = {n_particles:5d}  {name:<10} {row[name]:8.3f} ms/step", flush=True)
        results[f"N={n_particles}"] = row
    targets = [target(f"{name} step at N = 300", results["N=300"][name], limit, "ms")
               for name, limit in TARGETS_MS.items()]
    return {"results": {"ms_per_step": results, "scenario": "rov4dof, seed 000 sea state 3"}, "targets": targets}


if __name__ == "__main__":  # python benchmarks/bench_particles.py [--quick] [--json]
    report = run(quick="--quick" in sys.argv, verbose=True)
    for t in report["targets"]:
        print(f"{'met ' if t['met'] else 'MISS'}  {t['name']}: {t['value']:.3f} {t['unit']} (target <= {t['limit']:g})")
    if "--json" in sys.argv:
        print(json.dumps(report, indent=1))
