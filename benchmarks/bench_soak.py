"""Soak section of `abyssal bench`: long runs with gross outliers and dropouts, reported, never asserted.

Every registered filter (``contract.registered_filters``, so a new filter is soaked the day it is
added): the Kalman family 10^5 steps on rov4dof (``--quick``: 5000), the particle and Gaussian-sum
filters 5000 steps at N = 100 particles (``--quick``: 300), one ``step(u, dt, z)`` per step, on a
simulated run with faults injected into the measurements:

* gross outliers: a 1e4 m error on x at 20 % of the run, a 1e6 m error on y at 40 %, and 1e4 m
  on every position entry at 60 %;
* dropouts: every 7th step one measurement entry is NaN (rotating), every 50th step the whole
  row is NaN (no measurement), and an outage of 100 steps (5 % of shorter runs; all rows NaN) at
  80 %;
* one step of 5 s instead of 0.1 s at 70 % (the truth integrates it in 0.1 s steps).

Targets (reported as met/MISS like every bench target, never asserted): no filter refused at
construction, 0 steps with a non-finite state, 0 refusals in the last 10 % of any run (no
permanent divergence), RSS growth <= 1 MiB per filter.

Per filter it reports: steps, updates (step returned True), refusals (ValueError / TypeError /
FloatingPointError raised by step; the filter is kept and the run goes on), ``gated`` (the
filter's own counter of measurements rejected by its innovation gate, when it has one), NaN steps
(x or P not finite after a step), the position error against the truth at the end and its RMS
over the last 10 % of the run, refusals in the last 10 % (a filter poisoned for good by an outlier
keeps refusing there), the first steps where the gate acted (to tell outliers from consistent
measurements it rejected), and the growth of the resident set size (VmRSS from /proc/self/status,
after a warm-up of 2 % of the run, so first-use allocations are not counted) with the peak RSS
(``resource.getrusage``). Microseconds per step are reported only for orientation.
"""
from __future__ import annotations

import math
import resource
import time

import numpy as np

from bench import target

MODEL = "rov4dof"
DT = 0.1
KALMAN_STEPS, KALMAN_STEPS_QUICK = 100_000, 5_000
PARTICLE_STEPS, PARTICLE_STEPS_QUICK = 5_000, 300
#: RSS growth over a soak after its warm-up that counts as growth (allocator noise is ~0.3 MiB)
RSS_GROWTH_LIMIT_MIB = 1.0
LONG_DT = 5.0  # s: one step of this length at 70 % of the run (dt >= 5 s overflowed the integration)
N_PARTICLES = 100
ERRORS = (ValueError, TypeError, FloatingPointError, np.linalg.LinAlgError)


def rss_mib() -> float:
    """Current resident set size (VmRSS) in MiB; NaN where /proc is unavailable."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return math.nan


def peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux


def noise_matrices(bundle):
    """Process and measurement covariances of the soak (positive definite, so every family takes them)."""
    if (bundle.n_x, bundle.n_y) != (12, 4):
        raise ValueError(f"the soak's noise is written for rov4dof (12 states, 4 outputs), not {bundle.name}")
    return np.diag([1e-4] * 4 + [1e-3] * 4 + [1e-5] * 4), np.diag([0.05, 0.05, 0.02, 0.01])


def soak_run(bundle, steps: int, seed: int = 0) -> dict:
    """Truth, inputs and faulty measurements of a soak run of `steps` steps.

    Thrust swings slowly in every axis (periods of 10-15 min), so the vehicle goes back and forth
    and stays in the model's range over 10^4 s; the yaw moment swings the heading.
    """
    rng = np.random.default_rng(seed)
    Q, R = noise_matrices(bundle)
    t = DT * np.arange(steps)
    U = np.column_stack([20 * np.sin(2 * np.pi * t / 600), 10 * np.sin(2 * np.pi * t / 900),
                         10 * np.sin(2 * np.pi * t / 750), 0.5 * np.sin(0.2 * t)])
    process = rng.standard_normal((steps, bundle.n_x)) * np.sqrt(np.diag(Q))
    # a long gap between two steps (a stalled clock, a missed ping): the filter is given one step of
    # LONG_DT; the truth integrates it in steps of DT
    dts = np.full(steps, DT)
    long_step = int(0.7 * steps)
    dts[long_step] = LONG_DT
    X = np.empty((steps, bundle.n_x))
    x = np.zeros(bundle.n_x)
    for k in range(steps):
        for _ in range(int(round(dts[k] / DT))):
            x = bundle.f(x, U[k], None, DT)
        x = x + process[k]
        X[k] = x
    Z = bundle.h_batch(X.T).T + rng.standard_normal((steps, bundle.n_y)) * np.sqrt(np.diag(R))
    dropped_entries = np.arange(0, steps, 7)
    Z[dropped_entries, dropped_entries // 7 % bundle.n_y] = np.nan
    Z[::50] = np.nan
    outage, outage_steps = int(0.8 * steps), min(100, steps // 20)  # ends before the last 10 %
    Z[outage:outage + outage_steps] = np.nan

    def complete_row(k: int) -> int:
        """The first step from k whose measurement is complete (for the outliers)."""
        while k % 7 == 0 or k % 50 == 0 or outage <= k < outage + outage_steps:
            k += 1
        return k

    outliers = {complete_row(int(0.2 * steps)): (slice(0, 1), 1e4), complete_row(int(0.4 * steps)): (slice(1, 2), 1e6),
                complete_row(int(0.6 * steps)): (slice(0, 3), 1e4)}
    for k, (rows, size) in outliers.items():
        Z[k, rows] += size
    return {"U": U, "X": X, "Z": Z, "Q": Q, "R": R, "dt": dts, "long_step": long_step, "outlier_steps": sorted(outliers),
            "nan_rows": int(np.all(np.isnan(Z), axis=1).sum()),
            "nan_entries": int(np.isnan(Z).sum())}


def soak_filter(filt, run: dict) -> dict:
    """Run filt through the soak; count what happened (see the module docstring)."""
    U, Z, X, dts = run["U"], run["Z"], run["X"], run["dt"]
    steps = U.shape[0]
    step = filt.step
    warm_up = max(1, steps // 50)
    tail = steps - steps // 10
    refusals = tail_refusals = updates = nan_steps = 0
    first_refusal = None
    tail_errors = []
    gated_before = getattr(filt, "gated", None)
    gated_last, gated_steps = gated_before, []
    rss_start = math.nan
    t0 = time.perf_counter()
    for k in range(steps):
        if k == warm_up:
            rss_start = rss_mib()
        z = Z[k]
        try:
            updates += bool(step(U[k], dts[k], z))
        except ERRORS as error:
            refusals += 1
            tail_refusals += k >= tail
            if first_refusal is None:
                first_refusal = f"step {k}: {type(error).__name__}: {str(error)[:160]}"
        if gated_last is not None and filt.gated != gated_last:
            gated_last = filt.gated
            if len(gated_steps) < 12:
                gated_steps.append(k)
        x, P = filt.x, filt.P
        if not (np.isfinite(x).all() and np.isfinite(P).all()):
            nan_steps += 1
        if k >= tail:
            tail_errors.append(np.linalg.norm(x[:3] - X[k, :3]))
    elapsed = time.perf_counter() - t0
    rss_end = rss_mib()
    gated = getattr(filt, "gated", None)
    return {
        "steps": steps, "updates": updates, "refusals": refusals, "refusals_last_10pct": tail_refusals,
        "gated": None if gated is None else int(gated - (gated_before or 0)), "first_gated_steps": gated_steps,
        "nan_steps": nan_steps,
        "final_position_error_m": float(tail_errors[-1]),
        "rms_position_error_last_10pct_m": float(np.sqrt(np.mean(np.square(tail_errors)))),
        "rss_growth_mib": rss_end - rss_start, "rss_mib": rss_end,
        "us_per_step": 1e6 * elapsed / steps, "first_refusal": first_refusal,
    }


def build_filter(cls, kind: str, bundle, run: dict, n_particles: int, seed: int = 1):
    """A filter of a registered class (``contract.registered_filters``) on the soak's noise."""
    from abyssal.runtime.noise.mixtures import GaussianMixture

    x0, P0, Q, R = np.zeros(bundle.n_x), 0.3 * np.eye(bundle.n_x), run["Q"], run["R"]
    if kind == "kalman":
        return cls(bundle, x0, P0, Q, R)
    process = GaussianMixture.gaussian(np.zeros(bundle.n_x), Q)
    # a two-component measurement noise (heavy tail) exercises the mixture code paths
    measurement = GaussianMixture(np.array([0.9, 0.1]), np.zeros((2, bundle.n_y)), np.array([R, 100 * R]))
    rng = np.random.default_rng(seed)
    if kind in ("particle", "mixture"):
        return cls(bundle, x0, P0, process, measurement, n_particles, rng)
    if kind == "gaussian-sum":
        return cls(bundle, x0, P0, process, measurement, 2, rng)
    raise ValueError(f"no soak builder for filter kind {kind!r}")


def filter_groups() -> dict[str, list]:
    """Registered filter classes: the Kalman family, and everything else (particles, mixtures)."""
    from abyssal.runtime.contract import registered_filters

    groups: dict[str, list] = {"kalman": [], "particle": []}
    for cls, kind in sorted(registered_filters().items(), key=lambda item: item[0].__name__):
        if hasattr(cls, "contract_example"):
            continue  # its own model or learned step (GP-UKF, UPF family, terrain SIR): not the soak's rov4dof set-up
        groups["kalman" if kind == "kalman" else "particle"].append((cls, kind))
    return groups


def _print_row(name: str, r: dict) -> None:
    gated = "-" if r["gated"] is None else r["gated"]
    print(f"  {name:<10} {r['steps']:7d} {r['updates']:7d} {r['refusals']:7d} {r['refusals_last_10pct']:7d} "
          f"{gated!s:>6} {r['nan_steps']:5d} {r['final_position_error_m']:10.3g} "
          f"{r['rms_position_error_last_10pct_m']:10.3g} {r['rss_growth_mib']:8.2f} {r['us_per_step']:9.1f}", flush=True)
    if r["first_refusal"]:
        print(f"             first refusal: {r['first_refusal']}", flush=True)


def run(quick: bool = False, verbose: bool = True) -> dict:
    from abyssal.generated import load

    bundle = load(MODEL)
    steps = {"kalman": KALMAN_STEPS_QUICK if quick else KALMAN_STEPS,
             "particle": PARTICLE_STEPS_QUICK if quick else PARTICLE_STEPS}
    results: dict[str, dict] = {}
    runs = {}
    if verbose:
        print(f"  {'filter':<10} {'steps':>7} {'updates':>7} {'refused':>7} {'ref.end':>7} {'gated':>6} {'NaN':>5} "
              f"{'err end m':>10} {'rms end m':>10} {'RSS +MiB':>8} {'us/step':>9}", flush=True)
    for group, classes in filter_groups().items():
        soak = runs.setdefault(steps[group], soak_run(bundle, steps[group]))
        for cls, kind in classes:
            name = getattr(cls, "name", cls.__name__)
            try:
                filt = build_filter(cls, kind, bundle, soak, N_PARTICLES)
            except ERRORS as error:
                results[name] = {"error": f"construction refused: {type(error).__name__}: {error}"}
                if verbose:
                    print(f"  {name:<10} construction refused: {error}", flush=True)
                continue
            results[name] = {"family": kind, **soak_filter(filt, soak)}
            if verbose:
                _print_row(name, results[name])
    faults = {str(n): {"outlier_steps": r["outlier_steps"], "all_nan_rows": r["nan_rows"],
                       "nan_entries": r["nan_entries"], "long_step": [r["long_step"], LONG_DT]} for n, r in runs.items()}
    if verbose:
        print(f"  peak RSS {peak_rss_mib():.0f} MiB; faults: {faults}", flush=True)
    soaked = [r for r in results.values() if "steps" in r]
    targets = [
        target("soak: filters refused at construction", len(results) - len(soaked), 0, "filters"),
        target("soak: steps with a non-finite x or P (all filters)", sum(r["nan_steps"] for r in soaked), 0, "steps"),
        target("soak: refusals in the last 10 % (permanent divergence, all filters)",
               sum(r["refusals_last_10pct"] for r in soaked), 0, "steps"),
        target("soak: largest RSS growth of one filter", max((r["rss_growth_mib"] for r in soaked), default=0.0),
               RSS_GROWTH_LIMIT_MIB, "MiB"),
    ]
    return {"results": {"filters": results, "faults": faults, "model": MODEL, "dt": DT,
                        "n_particles": N_PARTICLES, "peak_rss_mib": peak_rss_mib()},
            "targets": targets}
