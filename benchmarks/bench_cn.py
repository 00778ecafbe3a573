"""`abyssal bench` section for seed 002 (cooperative navigation) on the cn2d bundle.

Per-step wall-clock time of every CN filter on the simulated lake trial (gaussian noise case,
printed tuning Q = diag(10^2, 10^2), R = 0.1), median over loops of steps cycling through the
trial, each beside the paper's Table 7 time (MATLAB on a 2.9 GHz Pentium: a different machine
and language, quoted for scale only). Targets: MCUPF <= 1 ms per step at its adaptive
particle number, UPF and HRUPF at N = 5000 <= 5 ms per step.
"""
from __future__ import annotations

import itertools

import numpy as np

from bench import median_time, target


def run(quick: bool = False, verbose: bool = True) -> dict:
    import abyssal.generated

    from abyssal.runtime.experiments.cn import experiment, paper
    from abyssal.runtime.experiments.cn.scenario import CnScenario, simulate

    model = abyssal.generated.load("cn2d")
    config = experiment.CnConfig()
    trial = simulate(CnScenario(), "gaussian", np.random.default_rng(0))
    repeat, min_time = (3, 0.05) if quick else (7, 0.2)
    times, particles = {}, {}
    for name in ("CKF", "MCUKF", "IVBCKF", "PF", "UPF", "HRUPF", "MCUPF"):
        filt = experiment.make_filter(name, model, trial, config, np.random.default_rng(1))
        rows = itertools.cycle(range(len(trial.t)))

        def step(filt=filt, rows=rows):
            k = next(rows)
            filt.step(trial.U[k], trial.dt, trial.Z[k], trial.params[k])

        for _ in range(20):  # past MCUPF's N_start step, into its adaptive regime
            step()
        times[name] = 1e3 * median_time(step, repeat=repeat, min_time=min_time)
        particles[name] = float(filt.n_particles) if np.isfinite(filt.n_particles) else None
        if verbose:
            extra = f", N = {particles[name]:.0f}" if particles[name] else ""
            print(f"  {name:7s} step {times[name]:9.4f} ms{extra}   (paper, MATLAB: {paper.TABLE7[name][1] * 1e3:9.4f} ms)",
                  flush=True)
    targets = [target("MCUPF step at its adaptive N", times["MCUPF"], 1.0, "ms"),
               target("UPF step at N = 5000", times["UPF"], 5.0, "ms"),
               target("HRUPF step at N = 5000", times["HRUPF"], 5.0, "ms")]
    return {"step_ms": times, "particles": particles,
            "paper_step_ms": {k: v[1] * 1e3 for k, v in paper.TABLE7.items()},
            "scenario": "cn2d, simulated lake trial, gaussian range noise, printed tuning", "targets": targets}
