"""Soak section of `abyssal bench`: every filter through long runs with faults, beside a fault-free twin.

Every registered filter (``contract.registered_filters``, so a new filter is soaked the day it is
added) runs one scenario twice with the same seed: once with faults injected into its measurements,
once without (the fault-free twin). Scenarios (``--quick`` in brackets):

* ``vehicle``: rov4dof at dt = 0.1 s, measurements x y z psi. The Kalman family 10^5 steps [5000],
  the particle and Gaussian-sum filters 5000 steps at N = 100 [300]. Faults: single outliers of
  1e4 m (x), 1e6 m (y), 1e100 m (z), 1e300 m (x, y, z) and 1e300 rad (psi) at 10, 20, 30, 40 and
  50 % of the run; one NaN entry every 7th step (rotating), a NaN row every 50th, an outage of 100
  steps (5 % of a shorter run) at 80 %. One step of 5 s at 70 % (the truth integrates it in 0.1 s
  steps; the twin gets it too: it is time, not a fault).
* ``ranges``: cn2d, one acoustic range per 5 s ping from two leaders in turn, DVL and compass as
  inputs, range noise 1 m; the UPF family (UPF, HRUPF, MCUPF with KLD-resampling) at N = 200,
  2000 pings [300]. Faults: range outliers of 1e4, 1e6, 1e100 and 1e300 m at 10-40 %, NaN pings,
  a 20-ping outage at 80 %. "MCUPF far from origin" runs the same pings 3 10^7 m from the origin
  (10 m KLD bins: 3 10^6 bins away, beyond 2^20).
* ``terrain``: tan3dof over the synthetic Arctic map's rough slope, 1 Hz, depth (altimeter, 5 m
  noise) and heading; the terrain SIR at N = 1000, 5000 steps [1000]. Faults: depth outliers of
  1e4, 1e6, 1e100, 1e300 m at 10-40 %, a heading of 1e300 rad at 45 %, two bursts of 30 depth
  faults (+100 m: a false bottom) at 50 and 65 %, NaN entries and rows.
* ``vehicle``, stamped (the entries "<filter> stamped", every filter with sensors and time): the same run through
  predict_to(t_k, u_k) and the sensor's update stamped t_{k-3}: every measurement arrives 0.3 s late and is fused
  at its stamp from a 1 s history (the three stamped before the 5 s step are older than the history holds when
  they arrive: refused, counted, nothing changed).
* ``linear``: linear_cv (position relative to a sensor) at dt = 0.5 s for any other filter with its
  own constructor (``contract_example``: the GP-UKF's learned predict), 5000 steps [1000];
  outliers of 1e4-1e300, NaN entries and rows, an outage.

Per filter: steps, updates, refusals (ValueError/TypeError/FloatingPointError raised by ``step``;
the filter is kept and the run goes on) and those in the last 10 % (a filter poisoned for good
keeps refusing there), steps with a non-finite x or P, ``gated`` where the filter counts it, the
RMS position error over the last 10 % beside the twin's and their ratio, and the steps to recover
from each fault: the first step after it from which the error stays within 3x the twin's RMS
error (over the whole run) for 20 steps ("never" when it does not). RSS growth after a 2 % warm-up
(VmRSS) and the peak RSS; microseconds per step for orientation only.

Done when (the targets, reported met/MISS like every bench target, never asserted): no filter
refused at construction, 0 non-finite steps, 0 filters stuck (refusing in the last 10 %, or never
back after a fault), every filter's last-10 % error within 3x its twin's, RSS growth <= 1 MiB.
"""
from __future__ import annotations

import math
import resource
import time
from dataclasses import dataclass, field

import numpy as np

from bench import target

#: (full, quick) steps per scenario; the vehicle scenario's particle and mixture filters use PARTICLE_STEPS
STEPS = {"vehicle": (100_000, 5_000), "ranges": (2_000, 300), "terrain": (5_000, 1_000), "linear": (5_000, 1_000)}
PARTICLE_STEPS = (5_000, 300)
N_PARTICLES = 100          # vehicle scenario
N_RANGES = 200             # UPF family
N_TERRAIN = (1000, 300)
RSS_GROWTH_LIMIT_MIB = 1.0  # allocator noise is ~0.3 MiB
RECOVERY_BAND = 3.0         # back within 3x the twin's error ...
RECOVERY_HOLD = 20          # ... for this many steps
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


# ---------------------------------------------------------------------------------------------
# scenarios


@dataclass
class Scenario:
    """One soak run: truth, inputs, parameters, the faulty measurements and the twin's clean ones."""

    name: str
    bundle: object
    U: np.ndarray               # (T, n_u)
    dt: np.ndarray              # (T,)
    X: np.ndarray               # (T, n_x) truth
    Z: np.ndarray               # (T, n_y) with the faults
    Z_clean: np.ndarray         # (T, n_y) the fault-free twin's
    position: slice             # the states whose error is reported (m)
    params: np.ndarray | None = None   # (T, n_p) or None (defaults)
    faults: list = field(default_factory=list)  # (step after which recovery is counted, description)
    noise: dict = field(default_factory=dict)   # what the filters are built with

    @property
    def steps(self) -> int:
        return self.U.shape[0]


def _fault_step(k: int, bad_rows: set) -> int:
    """The first step from k with a complete (fault-free) measurement row."""
    while k in bad_rows:
        k += 1
    return k


def _drop(Z: np.ndarray, steps: int, outage_from: int, outage_steps: int) -> set:
    """NaN entries every 7th step (rotating), NaN rows every 50th, an outage: the rows touched."""
    n_y = Z.shape[1]
    rows = np.arange(0, steps, 7)
    Z[rows, rows // 7 % n_y] = np.nan
    Z[::50] = np.nan
    Z[outage_from:outage_from + outage_steps] = np.nan
    return set(rows.tolist()) | set(range(0, steps, 50)) | set(range(outage_from, outage_from + outage_steps))


def vehicle(steps: int, seed: int = 0) -> Scenario:
    """rov4dof: slowly swinging thrust in every axis (the vehicle goes back and forth, stays in range)."""
    from abyssal.generated import load

    bundle = load("rov4dof")
    rng = np.random.default_rng(seed)
    Q, R = np.diag([1e-4] * 4 + [1e-3] * 4 + [1e-5] * 4), np.diag([0.05, 0.05, 0.02, 0.01])
    t = 0.1 * np.arange(steps)
    U = np.column_stack([20 * np.sin(2 * np.pi * t / 600), 10 * np.sin(2 * np.pi * t / 900),
                         10 * np.sin(2 * np.pi * t / 750), 0.5 * np.sin(0.2 * t)])
    dts = np.full(steps, 0.1)
    long_step = int(0.7 * steps)
    dts[long_step] = 5.0  # a stalled clock: the filter is given one step of 5 s; the truth integrates it in 0.1 s
    process = rng.standard_normal((steps, 12)) * np.sqrt(np.diag(Q))
    X, x = np.empty((steps, 12)), np.zeros(12)
    for k in range(steps):
        for _ in range(int(round(dts[k] / 0.1))):
            x = bundle.f(x, U[k], None, 0.1)
        X[k] = x = x + process[k]
    Z_clean = bundle.h_batch(X.T).T + rng.standard_normal((steps, 4)) * np.sqrt(np.diag(R))
    Z = Z_clean.copy()
    outage = int(0.8 * steps), min(100, steps // 20)
    bad = _drop(Z, steps, *outage)
    faults = []
    for share, rows, size in ((0.1, [0], 1e4), (0.2, [1], 1e6), (0.3, [2], 1e100), (0.4, [0, 1, 2], 1e300),
                              (0.5, [3], 1e300)):
        k = _fault_step(int(share * steps), bad)
        Z[k, rows] += size
        faults.append((k, f"{size:g} on {','.join('xyzψ'[r] for r in rows)}"))
    faults.append((sum(outage), f"end of a {outage[1]}-step outage"))
    return Scenario("vehicle", bundle, U, dts, X, Z, Z_clean, slice(0, 3), faults=sorted(faults),
                    noise={"x0": np.zeros(12), "P0": 0.3 * np.eye(12), "Q": Q, "R": R})


def ranges(steps: int, seed: int = 0, offset: float = 0.0) -> Scenario:
    """cn2d: an AUV at 1.5 m/s on slowly turning legs, a range to one of two leaders per 5 s ping."""
    from abyssal.generated import load

    bundle = load("cn2d")
    rng = np.random.default_rng(seed)
    dt = 5.0
    heading = 0.4 * np.sin(2 * np.pi * np.arange(steps) / 120) + 2 * np.pi * np.arange(steps) / 400
    U = np.column_stack([np.full(steps, 1.5), np.zeros(steps), heading])
    leaders = np.array([[400.0, 250.0], [-300.0, 150.0]]) + offset
    which = np.arange(steps) % 2  # the sensor (leader0, leader1) that pings at step k
    params = np.tile(leaders.reshape(-1), (steps, 1))
    X, x = np.empty((steps, 2)), np.full(2, offset)
    for k in range(steps):
        X[k] = x = bundle.f(x, U[k], params[k], dt) + rng.normal(0.0, 0.5, 2)
    # DVL and compass as the filter sees them: small noise on the inputs
    U_measured = U + np.column_stack([rng.normal(0, 0.02, steps), rng.normal(0, 0.02, steps), rng.normal(0, 0.01, steps)])
    Z_clean = np.full((steps, 2), np.nan)
    Z_clean[np.arange(steps), which] = np.linalg.norm(X - leaders[which], axis=1) + rng.normal(0.0, 1.0, steps)
    Z = Z_clean.copy()
    bad = _drop(Z, steps, int(0.8 * steps), min(20, steps // 20))
    faults = []
    for share, size in ((0.1, 1e4), (0.2, 1e6), (0.3, 1e100), (0.4, 1e300)):
        k = _fault_step(int(share * steps), bad)
        Z[k, which[k]] += size
        faults.append((k, f"range +{size:g} m"))
    faults.append((int(0.8 * steps) + min(20, steps // 20), "end of a 20-ping outage"))
    return Scenario("ranges" if not offset else "ranges far from origin", bundle, U_measured, np.full(steps, dt), X, Z,
                    Z_clean, slice(0, 2), params=params, faults=sorted(faults),
                    noise={"x0": np.full(2, offset), "P0": 9.0 * np.eye(2), "Q": np.eye(2), "R": np.eye(2)})


def terrain(steps: int, seed: int = 0) -> Scenario:
    """tan3dof over the rough slope of the synthetic Arctic map at 0.5 m/s, 1 Hz."""
    from abyssal.generated import load
    from abyssal.runtime.terrain.maps import synthetic_arctic

    bundle = load("tan3dof")
    rng = np.random.default_rng(seed)
    terrain_map = synthetic_arctic(seed=0)
    t = np.arange(steps, dtype=float)
    U = np.column_stack([np.full(steps, 0.5), 0.01 * np.sin(2 * np.pi * t / 900)])
    X, x = np.empty((steps, 3)), np.array([30e3, 20e3, 0.3])
    for k in range(steps):
        X[k] = x = bundle.f(x, U[k], None, 1.0) + np.array([rng.normal(0, 0.2), rng.normal(0, 0.2), rng.normal(0, 1e-3)])
    depth = terrain_map.depth_at(X[:, 0], X[:, 1])
    Z_clean = np.column_stack([depth + rng.normal(0, 5.0, steps), X[:, 2] + rng.normal(0, 0.01, steps)])
    Z = Z_clean.copy()
    bad = _drop(Z, steps, int(0.8 * steps), 0)
    faults = []
    for share, column, size in ((0.1, 0, 1e4), (0.2, 0, 1e6), (0.3, 0, 1e100), (0.4, 0, 1e300), (0.45, 1, 1e300)):
        k = _fault_step(int(share * steps), bad)
        Z[k, column] += size
        faults.append((k, f"{'depth' if column == 0 else 'heading'} +{size:g}"))
    for share in (0.5, 0.65):
        start = int(share * steps)
        Z[start:start + 30, 0] += 100.0
        faults.append((start + 30, "30 depth faults of +100 m"))
    return Scenario("terrain", bundle, U, np.ones(steps), X, Z, Z_clean, slice(0, 2), faults=sorted(faults),
                    noise={"x0": X[0].copy(), "P0": np.diag([100.0, 100.0, 1e-3]), "map": terrain_map})


def linear(steps: int, seed: int = 0) -> Scenario:
    """linear_cv held near its sensor by a soft controller (a learned model's training region), dt = 0.5 s."""
    from abyssal.generated import load

    bundle = load("linear_cv")
    rng = np.random.default_rng(seed)
    dt = 0.5
    X, U, x = np.empty((steps, 4)), np.empty((steps, 2)), np.array([0.5, -0.5, 0.0, 0.2])
    for k in range(steps):
        U[k] = -0.2 * x[:2] - 0.5 * x[2:] + 0.2 * np.array([np.sin(0.05 * k), np.cos(0.03 * k)])
        X[k] = x = bundle.f(x, U[k], None, dt) + rng.normal(0.0, 0.02, 4)
    Z_clean = bundle.h_batch(X.T).T + rng.normal(0.0, math.sqrt(0.5), (steps, 2))
    Z = Z_clean.copy()
    outage = int(0.8 * steps), min(40, steps // 20)
    bad = _drop(Z, steps, *outage)
    faults = []
    for share, column, size in ((0.1, 0, 1e4), (0.2, 1, 1e6), (0.3, 0, 1e100), (0.4, 1, -1e300)):
        k = _fault_step(int(share * steps), bad)
        Z[k, column] += size
        faults.append((k, f"{size:g} on z[{column}]"))
    faults.append((sum(outage), f"end of a {outage[1]}-step outage"))
    return Scenario("linear", bundle, U, np.full(steps, dt), X, Z, Z_clean, slice(0, 2), faults=sorted(faults))


SCENARIOS = {"vehicle": vehicle, "ranges": ranges, "terrain": terrain, "linear": linear}


# ---------------------------------------------------------------------------------------------
# filters


@dataclass(frozen=True)
class Entry:
    """A filter of the soak: its label, scenario, steps and how it is built on that scenario."""

    label: str
    scenario: str
    steps: tuple[int, int]
    build: object               # (scenario, quick) -> filter
    owner: str                  # the module that implements it (where a failure is fixed)
    scenario_options: tuple = ()
    latency: int = -1           # >= 0: stamped calls, each measurement arriving this many steps after its stamp


STAMPED_LATENCY = 3        # steps (0.3 s) of the stamped entries' measurements
STAMPED_HISTORY_S = 1.0


def _vehicle_builder(cls, kind, stamped: bool = False):
    def build(s: Scenario, quick: bool):
        from abyssal.runtime.noise.mixtures import GaussianMixture

        x0, P0, Q, R = (s.noise[k] for k in ("x0", "P0", "Q", "R"))
        if kind == "kalman":
            return cls(s.bundle, x0, P0, Q, R, history_seconds=STAMPED_HISTORY_S) if stamped else cls(
                s.bundle, x0, P0, Q, R)
        process = GaussianMixture.gaussian(np.zeros(12), Q)
        # a two-component measurement noise (heavy tail) exercises the mixture code paths
        measurement = GaussianMixture(np.array([0.9, 0.1]), np.zeros((2, 4)), np.array([R, 100 * R]))
        rng = np.random.default_rng(1)
        if kind in ("particle", "mixture"):
            return cls(s.bundle, x0, P0, process, measurement, N_PARTICLES, rng)
        return cls(s.bundle, x0, P0, process, measurement, 2, rng)
    return build


def _upf_builder(update: str, kld: bool):
    def build(s: Scenario, quick: bool):
        from abyssal.runtime.filters.particle.unscented import UnscentedParticleFilter
        from abyssal.runtime.resampling import KLDResampling

        resampling = KLDResampling(bin_size=(10.0, 10.0), n_min=50, n_max=N_RANGES) if kld else None
        return UnscentedParticleFilter(s.bundle, s.noise["x0"], s.noise["P0"], s.noise["Q"], s.noise["R"], N_RANGES, 1,
                                       update=update, resampling=resampling)
    return build


def _terrain_build(s: Scenario, quick: bool):
    from abyssal.runtime.filters.particle.terrain import TerrainParticleFilter

    return TerrainParticleFilter(s.bundle, s.noise["x0"], s.noise["P0"], 2.0, 5.0, N_TERRAIN[quick], 1,
                                 terrain=s.noise["map"])


def _example_builder(cls):
    def build(s: Scenario, quick: bool):
        return cls.contract_example(s.bundle, rng=1)
    return build


def entries() -> list[Entry]:
    """Every registered filter class as soak entries (the UPF family as its three filters, and MCUPF far from
    the origin); a class with its own constructor that the soak does not know runs the linear scenario."""
    from abyssal.runtime.contract import registered_filters

    out = []
    for cls, kind in sorted(registered_filters().items(), key=lambda item: item[0].__name__):
        owner = cls.__module__.removeprefix("abyssal.runtime.")
        name = getattr(cls, "name", None)
        label = name if isinstance(name, str) and name not in ("SIR",) else cls.__name__
        if cls.__name__ == "UnscentedParticleFilter":
            out += [Entry("UPF", "ranges", STEPS["ranges"], _upf_builder("ukf", False), owner),
                    Entry("HRUPF", "ranges", STEPS["ranges"], _upf_builder("huber", False), owner),
                    Entry("MCUPF", "ranges", STEPS["ranges"], _upf_builder("mcc", True), owner),
                    Entry("MCUPF far from origin", "ranges", STEPS["ranges"], _upf_builder("mcc", True), owner,
                          (("offset", 3e7),))]
        elif cls.__name__ == "TerrainParticleFilter":
            out.append(Entry("TAN-SIR", "terrain", STEPS["terrain"], _terrain_build, owner))
        elif hasattr(cls, "contract_example"):
            out.append(Entry(label if label != cls.__name__ else cls.__name__, "linear", STEPS["linear"],
                             _example_builder(cls), owner))
        else:
            steps = STEPS["vehicle"] if kind == "kalman" else PARTICLE_STEPS
            out.append(Entry(label, "vehicle", steps, _vehicle_builder(cls, kind), owner))
            if hasattr(cls, "update_sensor"):
                out.append(Entry(f"{label} stamped", "vehicle", STEPS["vehicle"], _vehicle_builder(cls, kind, True),
                                 owner, latency=STAMPED_LATENCY))
    return out


# ---------------------------------------------------------------------------------------------
# one run, its twin, the report


def _stamped_steps(filt, s: Scenario, Z: np.ndarray, latency: int):
    """step(u_k, dt_k, z_k, p_k) through the stamped calls: predict_to(t_k, u_k, p_k), then the one sensor's
    measurement stamped t_{k - latency} (arriving late, fused at its stamp from the history)."""
    (sensor,) = s.bundle.sensor_names
    stamps = np.cumsum(s.dt)
    k = iter(range(s.steps))

    def step(u, dt, z, p):
        i = next(k)
        filt.predict_to(stamps[i], u, p)
        return i >= latency and bool(filt.update(sensor, Z[i - latency], stamps[i - latency]))
    return step


def _run(filt, s: Scenario, Z: np.ndarray, latency: int = -1) -> dict:
    """Step filt through the scenario with measurements Z (latency >= 0: the stamped calls, each measurement that
    many steps late); errors per step and what happened."""
    steps = s.steps
    step = filt.step if latency < 0 else _stamped_steps(filt, s, Z, latency)
    warm_up = max(1, steps // 50)
    tail = steps - steps // 10
    errors = np.full(steps, np.inf)
    refusals = tail_refusals = updates = nan_steps = 0
    first_refusal = None
    gated_before = getattr(filt, "gated", None)
    rss_start = math.nan
    params = s.params
    t0 = time.perf_counter()
    for k in range(steps):
        if k == warm_up:
            rss_start = rss_mib()
        try:
            updates += bool(step(s.U[k], s.dt[k], Z[k], None if params is None else params[k]))
        except ERRORS as error:
            refusals += 1
            tail_refusals += k >= tail
            if first_refusal is None:
                first_refusal = f"step {k}: {type(error).__name__}: {str(error)[:160]}"
        x, P = filt.x, filt.P
        if np.isfinite(x).all() and np.isfinite(P).all():
            errors[k] = float(np.linalg.norm(x[s.position] - s.X[k, s.position]))
        else:
            nan_steps += 1
    elapsed = time.perf_counter() - t0
    gated = getattr(filt, "gated", None)
    return {"errors": errors, "steps": steps, "updates": updates, "refusals": refusals,
            "refusals_last_10pct": tail_refusals, "first_refusal": first_refusal, "nan_steps": nan_steps,
            "gated": None if gated is None else int(gated - (gated_before or 0)),
            "rss_growth_mib": rss_mib() - rss_start, "us_per_step": 1e6 * elapsed / steps}


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if values.size else math.nan


def recovery_steps(errors: np.ndarray, after: int, band: float, hold: int = RECOVERY_HOLD) -> int | None:
    """Steps from `after` until the error stays within `band` for `hold` steps (or to the end); None: never."""
    inside = errors <= band
    run = 0
    for k in range(after, errors.size):
        run = run + 1 if inside[k] else 0
        if run >= hold or (run and k == errors.size - 1):
            return k - run + 1 - after
    return None


def soak(entry: Entry, quick: bool = False, seed: int = 0, steps: int | None = None) -> dict:
    """One entry: its faulty run and its fault-free twin (same seed), compared (see the module docstring)."""
    steps = steps or entry.steps[quick]
    s = SCENARIOS[entry.scenario](steps, seed, **dict(entry.scenario_options))
    try:
        filt, twin = entry.build(s, quick), entry.build(s, quick)
    except ERRORS as error:
        return {"error": f"construction refused: {type(error).__name__}: {error}", "owner": entry.owner}
    faulty, clean = _run(filt, s, s.Z, entry.latency), _run(twin, s, s.Z_clean, entry.latency)
    warm_up, tail = max(1, steps // 50), steps - steps // 10
    reference = _rms(clean["errors"][warm_up:][np.isfinite(clean["errors"][warm_up:])])
    band = RECOVERY_BAND * reference
    recoveries = {description: recovery_steps(faulty["errors"], k, band) for k, description in s.faults}
    tail_rms, twin_tail = _rms(faulty["errors"][tail:]), _rms(clean["errors"][tail:])
    never = [d for d, r in recoveries.items() if r is None]
    return {
        "scenario": s.name, "owner": entry.owner, "steps": steps, "updates": faulty["updates"],
        "refusals": faulty["refusals"], "refusals_last_10pct": faulty["refusals_last_10pct"],
        "first_refusal": faulty["first_refusal"], "nan_steps": faulty["nan_steps"], "gated": faulty["gated"],
        "twin_refusals": clean["refusals"], "twin_error_rms_m": reference,
        "error_last_10pct_m": tail_rms, "twin_error_last_10pct_m": twin_tail,
        "error_ratio_last_10pct": tail_rms / twin_tail if twin_tail > 0 else math.inf,
        "recovery_steps": recoveries, "worst_recovery_steps": None if never else max(recoveries.values(), default=0),
        "never_recovered": never, "stuck": bool(faulty["refusals_last_10pct"] or never),
        "rss_growth_mib": faulty["rss_growth_mib"], "us_per_step": faulty["us_per_step"],
    }


def _print_row(label: str, r: dict) -> None:
    if "error" in r:
        print(f"  {label:<22} {r['error']}", flush=True)
        return
    gated = "-" if r["gated"] is None else r["gated"]
    recovered = "never" if r["never_recovered"] else r["worst_recovery_steps"]
    print(f"  {label:<22} {r['scenario']:<9} {r['steps']:7d} {r['refusals']:7d} {r['refusals_last_10pct']:7d} "
          f"{gated!s:>6} {r['nan_steps']:5d} {r['error_last_10pct_m']:10.3g} {r['twin_error_last_10pct_m']:10.3g} "
          f"{r['error_ratio_last_10pct']:7.3g} {recovered!s:>8} {r['rss_growth_mib']:7.2f} {r['us_per_step']:8.1f}",
          flush=True)
    if r["twin_refusals"]:
        print(f"  {'':<22} the fault-free twin refused {r['twin_refusals']} steps too", flush=True)
    if r["never_recovered"]:
        print(f"  {'':<22} never back within {RECOVERY_BAND:g}x after: {'; '.join(r['never_recovered'])}", flush=True)
    if r["first_refusal"]:
        print(f"  {'':<22} first refusal: {r['first_refusal']}", flush=True)


def run(quick: bool = False, verbose: bool = True, only: tuple[str, ...] = ()) -> dict:
    results: dict[str, dict] = {}
    if verbose:
        print(f"  {'filter':<22} {'scenario':<9} {'steps':>7} {'refused':>7} {'ref.end':>7} {'gated':>6} {'NaN':>5} "
              f"{'err end m':>10} {'twin m':>10} {'ratio':>7} {'recover':>8} {'RSS+MiB':>7} {'us/step':>8}", flush=True)
    for entry in entries():
        if only and entry.label not in only:
            continue
        results[entry.label] = soak(entry, quick)
        if verbose:
            _print_row(entry.label, results[entry.label])
    soaked = [r for r in results.values() if "steps" in r]
    if verbose:
        print(f"  peak RSS {peak_rss_mib():.0f} MiB", flush=True)
    targets = [
        target("soak: filters refused at construction", len(results) - len(soaked), 0, "filters"),
        target("soak: steps with a non-finite x or P (all filters)", sum(r["nan_steps"] for r in soaked), 0, "steps"),
        target("soak: filters stuck (refusing in the last 10 %, or never back after a fault)",
               sum(r["stuck"] for r in soaked), 0, "filters"),
        target("soak: largest last-10 % error against the fault-free twin's",
               max((r["error_ratio_last_10pct"] for r in soaked), default=0.0), RECOVERY_BAND, "x"),
        target("soak: largest RSS growth of one filter", max((r["rss_growth_mib"] for r in soaked), default=0.0),
               RSS_GROWTH_LIMIT_MIB, "MiB"),
    ]
    return {"results": {"filters": results, "recovery_band": RECOVERY_BAND, "recovery_hold": RECOVERY_HOLD,
                        "peak_rss_mib": peak_rss_mib()}, "targets": targets}
