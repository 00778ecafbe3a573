"""Per-step times of the runtime's filters on rov4dof (and the cn UPF at N = 5000), as JSON: for
before/after comparisons of two checkouts. It uses only the public API, so the same file runs
against an older installed abyssal:

    for r in 1 2 3 4 5; do OLD_VENV/bin/python benchmarks/step_times.py; .venv/bin/python benchmarks/step_times.py; done

(give each checkout its own ABYSSAL_CACHE_DIR if their generated C differs), then compare the min and
median of each filter over the runs. Each value: the best of 7 repetitions of step(u, dt, z) over a
simulated trajectory, in µs per step. ``--cpu``: the process's CPU time (all its threads) instead of
the wall clock, steadier on a machine shared with other work (a batch split over the cores then
counts each core's share).
"""
import json
import sys
import time

import numpy as np

import abyssal.generated
from abyssal.runtime import CKF, EKF, UKF
from abyssal.runtime.experiments.cn import scenario
from abyssal.runtime.filters.particle import CubatureParticleFilter, ParticleFilter, UnscentedParticleFilter
from abyssal.runtime.noise.mixtures import GaussianMixture
from bench_filters import trajectory  # this folder is sys.path[0] when the script runs

REPETITIONS = 7
CLOCK = time.process_time if "--cpu" in sys.argv[1:] else time.perf_counter


def per_step(make, U, Z, steps: int, dt=0.1, params=None) -> float:
    best = float("inf")
    for _ in range(REPETITIONS):
        f = make()
        t = CLOCK()
        for k in range(steps):
            f.step(U[k], dt, Z[k], None if params is None else params[k])
        best = min(best, (CLOCK() - t) / steps * 1e6)
    return best


def main():
    rov = abyssal.generated.load("rov4dof")
    _, _, Q, R, U, Z = trajectory(rov, 400)
    x0, P0 = np.zeros(12), 0.3 * np.eye(12)
    Qm, Rm = GaussianMixture.gaussian(np.zeros(12), Q), GaussianMixture.gaussian(np.zeros(4), R)
    out = {
        "EKF": per_step(lambda: EKF(rov, x0, P0, Q, R), U, Z, 400),
        "UKF": per_step(lambda: UKF(rov, x0, P0, Q, R), U, Z, 400),
        "CKF": per_step(lambda: CKF(rov, x0, P0, Q, R), U, Z, 400),
        "PF N=1000": per_step(lambda: ParticleFilter(rov, x0, P0, Qm, Rm, 1000, np.random.default_rng(0)), U, Z, 100),
        "CPF N=100": per_step(lambda: CubatureParticleFilter(rov, x0, P0, Qm, Rm, 100, np.random.default_rng(0)), U, Z, 60),
        "UPF N=100": per_step(lambda: UnscentedParticleFilter(rov, x0, P0, Q, R, 100, np.random.default_rng(0)), U, Z, 60),
    }
    # the cooperative-navigation UPF of seed 002 at its N_start = 5000 (cn2d, one leader sensor's range per 5 s step)
    cn = abyssal.generated.load("cn2d")
    trial = scenario.simulate(scenario.CnScenario(), "gaussian", np.random.default_rng(11))
    Qc, Rc = np.diag([100.0, 100.0]), np.eye(2) * 0.1  # each leader sensor's R
    out["UPF cn N=5000"] = per_step(lambda: UnscentedParticleFilter(cn, trial.x0, trial.P0, Qc, Rc, 5000,
                                                                    np.random.default_rng(0)),
                                    trial.U, trial.Z, 20, trial.dt, trial.params)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
