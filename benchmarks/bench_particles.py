"""Bench section: the particle filters' steps against commit 1dd3f6b's and against the CKF's, measured in one run.

1. Against 1dd3f6b (issue 34: the per-particle proposals ran generated steps there): ``step_times.py --cpu --serial``
   (public API only: the same file runs in both checkouts) in 1dd3f6b's own checkout and venv (baseline.py, built
   once outside the repository) and in this checkout, alternately, ``ROUNDS`` times each: µs of CPU per step on one
   thread (no batch split over the cores, BLAS on one thread), the best of the script's repetitions per run. Rows: the
   CPF (N = 100) and UPF (N = 100) on rov4dof, the UPF at N = 5000 and the MCUPF (KLD-resampling) on cn2d's ranges.
   A ratio (this checkout / 1dd3f6b) is the median over the rounds of each round's own ratio (the two runs of a
   round are adjacent; on a shared host the minima of the two sides over the rounds can come from different speeds
   of the machine: 0.94 against the rounds' 0.69-0.98 for the UPF at N = 5000 once); the ratios of the minima and of
   the medians are reported beside. Targets: each <= 0.7.
2. The CPF at N = 100 against 100 steps of the CKF on the same model, both from this checkout's rounds (the CKF.step
   of the same script). Target: <= 1.
3. Context: per step of PF, CPF, MOGCPF, EM-MOGCPF, the Gaussian-sum CKF and the CKF on the seed-000 scenario (sea
   state 3) at N = 300 and 3000 (wall time, this process).
4. The floors, with ABYSSAL_BENCH_CALLGRIND=1 (valgrind installed; minutes): instructions per step of the CPF
   (N = 100) from Python under callgrind (instructions.py: an x86-64-v3 build), and of them abyssal's C, the model's
   kernels (f and h over the sigma points and the particles) and libmvec; the CKF's are bench_filters'.

The load average is recorded beside every round (``os.getloadavg``): on a machine shared with other work, compare the
ratios, not the times.
"""
from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from bench import median_time, paired_ratio, target

HERE = Path(__file__).resolve().parent
BASELINE = "1dd3f6b"
#: rows of step_times.py compared with the baseline, and the CKF (the CPF's unit)
ROWS = ("CKF", "CPF N=100", "UPF N=100", "UPF cn N=5000", "MCUPF cn")
TARGET_ROWS = ("CPF N=100", "UPF N=100", "UPF cn N=5000", "MCUPF cn")
RATIO_LIMIT = 0.7
ROUNDS, QUICK_ROUNDS = 7, 2
FILTERS = ("PF", "CPF", "MOGCPF", "EM-MOGCPF", "GS-CKF", "CKF")


def _step_times(python: str, cache: str | None, repetitions: int) -> dict:
    env = dict(os.environ)
    if cache is not None:
        env["ABYSSAL_CACHE_DIR"] = cache
    out = subprocess.run([python, str(HERE / "step_times.py"), "--cpu", "--serial", "--repetitions", str(repetitions),
                          "--only", ",".join(ROWS)], env=env, capture_output=True, text=True, check=True, cwd=HERE)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _load() -> float | None:
    return os.getloadavg()[0] if hasattr(os, "getloadavg") else None


def against_baseline(rounds: int, repetitions: int, say) -> dict:
    """The alternating rounds (module docstring, 1 and 2)."""
    from baseline import baseline

    python, cache, reason = baseline(BASELINE)
    runs: dict[str, list] = {"new": [], BASELINE: [], "load": []}
    for r in range(rounds):
        if python is not None:
            runs[BASELINE].append(_step_times(str(python), str(cache), repetitions))
        runs["new"].append(_step_times(sys.executable, None, repetitions))
        runs["load"].append(_load())
        say(f"  round {r + 1}/{rounds}: load {runs['load'][-1]}: "
            + ", ".join(f"{k} {v:.1f}" for k, v in runs["new"][-1].items())
            + ("" if python is None else " | " + BASELINE + ": " + ", ".join(f"{k} {v:.1f}"
                                                                          for k, v in runs[BASELINE][-1].items())))

    def stats(side):
        return {row: {"min": min(run[row] for run in runs[side]),
                      "median": float(np.median([run[row] for run in runs[side]]))} for row in ROWS} if runs[side] else {}

    new, old = stats("new"), stats(BASELINE)
    ratios = {row: {"paired": paired_ratio([r[row] for r in runs["new"]], [r[row] for r in runs[BASELINE]]),
                    "min": new[row]["min"] / old[row]["min"], "median": new[row]["median"] / old[row]["median"]}
              for row in TARGET_ROWS} if old else {}
    ckf_units = {"paired": paired_ratio([r["CPF N=100"] for r in runs["new"]], [100 * r["CKF"] for r in runs["new"]]),
                 "min": new["CPF N=100"]["min"] / (100 * new["CKF"]["min"]),
                 "median": new["CPF N=100"]["median"] / (100 * new["CKF"]["median"])}
    return {"us_cpu_per_step": {"this checkout": new, BASELINE: old}, "ratio_to_baseline": ratios,
            "CPF N=100 over 100 CKF steps": ckf_units, "rounds": runs, "baseline_missing": reason or None,
            "command": f"benchmarks/step_times.py --cpu --serial --repetitions {repetitions} --only {','.join(ROWS)}"}


def seed_000_table(quick: bool, say) -> dict:
    """Per step (ms, wall) of the seed-000 particle filters at N = 300 and 3000 (module docstring, 3)."""
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
            say(f"  N = {n_particles:5d}  {name:<10} {row[name]:8.3f} ms/step")
        results[f"N={n_particles}"] = row
    return results


def floors(say) -> dict | None:
    """Instructions per step under callgrind (module docstring, 4), or None."""
    import instructions

    if os.environ.get("ABYSSAL_BENCH_CALLGRIND") != "1" or not instructions.available():
        return None
    row = "CPF N=100"  # (10 and 20 steps within the 400 rows; the cn rows would take minutes)
    counts = instructions.per_step([sys.executable, str(HERE / "step_times.py"), "--steps", row], 10)
    say(f"  instructions per step, {row}: " + ", ".join(f"{k} {v:,.0f}" for k, v in counts.items()))
    return {row: counts}


def run(quick: bool = False, verbose: bool = True) -> dict:
    def say(text):
        if verbose:
            print(text, flush=True)

    ab = against_baseline(QUICK_ROUNDS if quick else ROUNDS, 3 if quick else 7, say)
    results = {"against_1dd3f6b": ab, "seed_000_ms_per_step": seed_000_table(quick, say),
               "scenario": "rov4dof (bench trajectory and seed 000 sea state 3), cn2d simulated lake trial",
               "instructions_per_step": floors(say), "load_average_end": _load()}
    targets = []
    for row in TARGET_ROWS:
        ratio = ab["ratio_to_baseline"].get(row, {}).get("paired", float("nan"))
        t = target(f"{row} step, CPU on one thread, over {BASELINE}'s (median of the rounds' ratios)", ratio,
                   RATIO_LIMIT, "x")
        if ab["baseline_missing"]:
            t["note"] = ab["baseline_missing"]
        targets.append(t)
    targets.append(target("CPF N=100 step over 100 CKF steps (median of the rounds' ratios)",
                          ab["CPF N=100 over 100 CKF steps"]["paired"], 1.0, "x"))
    return {"results": results, "targets": targets}


if __name__ == "__main__":  # python benchmarks/bench_particles.py [--quick] [--json]
    report = run(quick="--quick" in sys.argv, verbose=True)
    for t in report["targets"]:
        print(f"{'met ' if t['met'] else 'MISS'}  {t['name']}: {t['value']:.3f} {t['unit']} (target <= {t['limit']:g})")
    if "--json" in sys.argv:
        print(json.dumps(report, indent=1))
