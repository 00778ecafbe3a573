"""Per-step times of the runtime's filters (rov4dof, and the cooperative-navigation particle filters on cn2d), as JSON:
for before/after comparisons of two checkouts. It uses only the public API, so the same file runs against an older
installed abyssal (bench_particles runs it in commit 1dd3f6b's own venv and in this checkout's, alternately):

    OLD_VENV/bin/python benchmarks/step_times.py --cpu --serial; .venv/bin/python benchmarks/step_times.py --cpu --serial

(give each checkout its own ABYSSAL_CACHE_DIR if their generated C differs). Each value: the best of the repetitions
(7; ``--repetitions R``) of step(u, dt, z[, p]) over a simulated run, each on a fresh filter after its warm-up steps,
in µs per step. ``--cpu``: the process's CPU time (all its threads) instead of the wall clock, steadier on a machine
shared with other work. ``--serial``: one thread (the batch layer never splits a batch over the cores and BLAS uses
one thread), so CPU time is the work of one core. ``--only NAME,NAME``: those rows (FILTERS). ``--steps NAME K``: K
steps of one filter and nothing else (for an instruction count under callgrind).
"""
import json
import os
import sys
import time

if "--serial" in sys.argv[1:]:  # (before numpy loads its BLAS)
    for variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[variable] = "1"

import numpy as np  # noqa: E402

import abyssal.generated  # noqa: E402
from abyssal.runtime import CKF, EKF, UKF  # noqa: E402
from abyssal.runtime.experiments.cn import scenario  # noqa: E402
from abyssal.runtime.filters.particle import (CubatureParticleFilter, ParticleFilter,  # noqa: E402
                                              UnscentedParticleFilter)
from abyssal.runtime.noise.mixtures import GaussianMixture  # noqa: E402
from abyssal.runtime.resampling import KLDResampling  # noqa: E402
from trajectory import trajectory  # noqa: E402  (this folder is sys.path[0] when the script runs)

REPETITIONS = 7


def _clock():
    return time.process_time if "--cpu" in sys.argv[1:] else time.perf_counter


def per_step(make, U, Z, steps: int, dt=0.1, params=None, warm: int = 0) -> float:
    """µs per step: the best of REPETITIONS runs of `steps` steps, each on a fresh filter after `warm` steps."""
    clock, best = _clock(), float("inf")
    for _ in range(REPETITIONS):
        f = make()
        for k in range(warm):
            f.step(U[k], dt, Z[k], None if params is None else params[k])
        t = clock()
        for k in range(warm, warm + steps):
            f.step(U[k], dt, Z[k], None if params is None else params[k])
        best = min(best, (clock() - t) / steps * 1e6)
    return best


def filters():
    """name -> (make, U, Z, steps, dt, params, warm-up steps)."""
    rov = abyssal.generated.load("rov4dof")
    x0, P0, Q, R, U, Z = trajectory(rov, 400)
    Qm, Rm = GaussianMixture.gaussian(np.zeros(12), Q), GaussianMixture.gaussian(np.zeros(4), R)
    rows = {
        "EKF": (lambda: EKF(rov, x0, P0, Q, R), U, Z, 400, 0.1, None, 0),
        "UKF": (lambda: UKF(rov, x0, P0, Q, R), U, Z, 400, 0.1, None, 0),
        "CKF": (lambda: CKF(rov, x0, P0, Q, R), U, Z, 400, 0.1, None, 0),
        "PF N=1000": (lambda: ParticleFilter(rov, x0, P0, Qm, Rm, 1000, np.random.default_rng(0)), U, Z, 100, 0.1, None, 0),
        "CPF N=100": (lambda: CubatureParticleFilter(rov, x0, P0, Qm, Rm, 100, np.random.default_rng(0)), U, Z, 60, 0.1,
                      None, 0),
        "UPF N=100": (lambda: UnscentedParticleFilter(rov, x0, P0, Q, R, 100, np.random.default_rng(0)), U, Z, 60, 0.1,
                      None, 0),
    }
    # the cooperative-navigation filters of seed 002 (cn2d, one leader sensor's range per 5 s step; n_y = 1 at
    # 1dd3f6b): the UPF at its N_start = 5000,
    # and the MCUPF in its KLD-resampling regime (N_start = 5000, N_max = 2000; timed after 20 steps)
    cn = abyssal.generated.load("cn2d")
    trial = scenario.simulate(scenario.CnScenario(), "gaussian", np.random.default_rng(11))
    Qc, Rc = np.diag([100.0, 100.0]), np.eye(cn.n_y) * 0.1  # each leader sensor's R
    rows["UPF cn N=5000"] = (lambda: UnscentedParticleFilter(cn, trial.x0, trial.P0, Qc, Rc, 5000, np.random.default_rng(0)),
                             trial.U, trial.Z, 20, trial.dt, trial.params, 0)
    rows["MCUPF cn"] = (lambda: UnscentedParticleFilter(cn, trial.x0, trial.P0, Qc, Rc, 5000, np.random.default_rng(0),
                                                        update="mcc", resampling=KLDResampling(n_max=2000)),
                        trial.U, trial.Z, 60, trial.dt, trial.params, 20)
    return rows


FILTERS = ("EKF", "UKF", "CKF", "PF N=1000", "CPF N=100", "UPF N=100", "UPF cn N=5000", "MCUPF cn")


def main(argv):
    global REPETITIONS
    if "--serial" in argv:
        import abyssal.runtime.compiled.batches as batches

        batches.SPLIT_MIN_SECONDS = float("inf")  # (read at every call: no batch is split over the cores)
    if "--repetitions" in argv:
        REPETITIONS = int(argv[argv.index("--repetitions") + 1])
    rows = filters()
    if "--steps" in argv:
        name, count = argv[argv.index("--steps") + 1], int(argv[argv.index("--steps") + 2])
        make, U, Z, _, dt, params, warm = rows[name]
        f = make()
        for k in range(warm + count):
            f.step(U[k % len(U)], dt, Z[k % len(U)], None if params is None else params[k % len(U)])
        return
    only = argv[argv.index("--only") + 1].split(",") if "--only" in argv else FILTERS
    out = {name: per_step(*rows[name][:4], dt=rows[name][4], params=rows[name][5], warm=rows[name][6]) for name in only}
    print(json.dumps(out))


if __name__ == "__main__":
    main(sys.argv[1:])
