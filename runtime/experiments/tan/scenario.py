"""Seed 003's simulation (section 4): an AUV crossing a bathymetry map under an unknown current.

One run (``run_one(config, seed) -> rows``, the campaign harness's shape) simulates, for every
case map x start x current, one truth and runs every filter on it: SIR with fixed sigma = 1..6 m,
SIR with fuzzy sigma, and dead reckoning. Rows: {"run", "case", "filter", "metric", "value"}.

Set-up (Table 2 where it says; DECISION where it does not):

* Vehicle: forward speed 0.5 m/s, heading 0 (along +x), operating depth 0 m; filter and truth at
  1 Hz (dt = 1 s) for ``duration_s`` (the paper's 30 000 s; ``quick`` shortens it).
* Truth (DECISION): eq. 1 with the body noise of eq. 2 (a = 0.1, 0.1, 0.001, 0.1) disturbing the
  true speed and turn rate, plus the current (d_x, d_y) (Table 2: (0.1, 0.1) and (0.15, 0.15)
  m/s along +x +y; (0, 0) for Fig. 7's "body noise alone"). A heading autopilot with an ideal
  heading sensor commands omega_k = -(theta_k - 0)/tau, tau = 10 s, so the track stays straight
  (the body noise alone would random-walk the heading by ~2.7 rad over 30 000 s).
* What the filter gets: the commanded [v, omega_k] as its input, and z = [altimeter depth, compass
  heading]: depth = map(x, y) + N(0, 5^2) (Table 2), heading exact (the paper's filter estimates
  position only). The current is unknown to the filter: absorbing it is the process noise's job.
* Start: the filter's particles are drawn around the true start posture, N(0, initial_std^2 = 50^2 m^2)
  in x and y (the paper gives the initial posture, not its uncertainty).
* Lost track: position error above 1000 m (two map cells) at any time of the run.
* Dead reckoning: the filter's own model at zero noise from the start posture, with the commanded
  inputs and the compass heading (no map, no current): its error is the current's drift.
* Maps: the synthetic Arctic-like map (seeded, ``map_seed``) with the paper's start postures
  [20 km, 20 km] (rough slope) and [60 km, 10 km] (flat plain); and the topobathy window with
  the same postures, labelled "slope" ([20, 20] km: the upper continental slope) and "shelf"
  ([60, 10] km: the continental shelf, gently sloping -- not a flat plain).
* Filters: SIR with fixed sigma 1..6 m, "fuzzy" (gradient in percent, rate in percent per km) and
  "fuzzy_per_cell" (the same rules with the inputs per 500 m map cell: a sensitivity row, the paper
  defines no units), and dead reckoning.
* Baseline (not a method of the paper): "oracle_known_current", SIR with sigma = ``oracle_sigma``
  (1 m) that is given the true current as its model parameter -- a matched-model oracle. It shows
  what the terrain information supports when nothing has to be absorbed, so a failure of the
  other filters can be told apart from a map without information.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..campaign import derive, run_index

SIGMAS = (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
STARTS = {"rough": (20e3, 20e3, 0.0), "flat": (60e3, 10e3, 0.0)}
#: what the paper's two postures land on in each map (the topobathy window has no flat plain there)
START_LABELS = {"arctic": {"rough": "rough", "flat": "flat"}, "topobathy": {"rough": "slope", "flat": "shelf"}}
#: fuzzy variants: name -> (gradient_scale, rate_length_m): percent and %/km (default), or per 500 m cell
FUZZY_VARIANTS = {"fuzzy": (100.0, 1000.0), "fuzzy_per_cell": (500.0, 500.0)}
CURRENTS = {"0": (0.0, 0.0), "0.1": (0.1, 0.1), "0.15": (0.15, 0.15)}
#: the matched-model oracle's row name (module docstring)
ORACLE = "oracle_known_current"


@dataclass(frozen=True)
class TanConfig:
    """The experiment's set-up; defaults are the paper's (Table 2) or the documented decisions."""

    duration_s: float = 30000.0
    dt: float = 1.0
    speed: float = 0.5
    n_particles: int = 1000
    sigmas: tuple[float, ...] = SIGMAS
    fuzzy: tuple[str, ...] = tuple(FUZZY_VARIANTS)
    maps: tuple[str, ...] = ("arctic", "topobathy")
    starts: tuple[str, ...] = ("rough", "flat")
    currents: tuple[str, ...] = ("0", "0.1", "0.15")
    altimeter_sigma: float = 5.0
    initial_std: float = 50.0
    resample_threshold: float = 0.5
    autopilot_tau: float = 10.0
    lost_m: float = 1000.0
    map_seed: int = 0
    trace_every: int = 10
    #: sigma of the known-current oracle (None: no oracle row)
    oracle_sigma: float | None = 1.0

    def quick(self) -> "TanConfig":
        return replace(self, duration_s=3000.0)

    @property
    def n_steps(self) -> int:
        return int(round(self.duration_s / self.dt))

    def cases(self) -> list[tuple[str, str, str]]:
        return [(m, s, c) for m in self.maps for s in self.starts for c in self.currents]

    def filters(self) -> list[str]:
        oracle = [ORACLE] if self.oracle_sigma is not None else []
        return [sigma_name(s) for s in self.sigmas] + list(self.fuzzy) + oracle + ["dead_reckoning"]


def sigma_name(sigma: float) -> str:
    return f"sigma_{sigma:g}"


def case_name(map_name: str, start: str, current: str) -> str:
    return f"{map_name}/{START_LABELS.get(map_name, {}).get(start, start)}/current_{current}"


_MAP_CACHE: dict = {}


def get_map(name: str, seed: int = 0):
    """The named map (built once per process)."""
    from ...terrain import MAPS

    key = (name, seed)
    if key not in _MAP_CACHE:
        _MAP_CACHE[key] = MAPS[name](seed) if name == "arctic" else MAPS[name]()
    return _MAP_CACHE[key]


@dataclass
class Truth:
    states: np.ndarray        # (T + 1, 3): x, y, theta at t = 0, dt, ..., T dt
    inputs: np.ndarray        # (T, 2): commanded v, omega of each step
    measurements: np.ndarray  # (T, 2): depth, heading after each step
    current: tuple[float, float]


def simulate(bundle, terrain, config: TanConfig, start, current, rng: np.random.Generator) -> Truth:
    """The true track (see the module docstring), integrated with the generated eq. 1 step."""
    from ...filters.particle.terrain import BODY_NOISE

    T, dt, v = config.n_steps, config.dt, config.speed
    a1, a2, a3, a4 = BODY_NOISE
    x_next = bundle.function("x_next")
    states = np.empty((T + 1, 3))
    inputs = np.empty((T, 2))
    states[0] = start
    p = np.array(current, dtype=np.float64)
    noise = rng.standard_normal((T, 2))
    for k in range(T):
        omega = -(states[k, 2] - start[2]) / config.autopilot_tau
        inputs[k] = (v, omega)
        w = np.array([noise[k, 0] * math.sqrt(a1 * v * v + a2 * omega * omega),
                      noise[k, 1] * math.sqrt(a3 * v * v + a4 * omega * omega), 0.0, 0.0])
        states[k + 1] = x_next(states[k], inputs[k], p, w, dt)
    depth = terrain.depth_at(states[1:, 0], states[1:, 1])
    measurements = np.column_stack([depth + config.altimeter_sigma * rng.standard_normal(T), states[1:, 2]])
    return Truth(states, inputs, measurements, tuple(current))


@dataclass
class FilterRun:
    """One filter on one truth: the estimates, their errors and what the fuzzy logic saw."""

    estimates: np.ndarray      # (T, 2) positions after each step
    std: np.ndarray            # (T,) sqrt(P_xx + P_yy)
    step_seconds: np.ndarray   # (T,)
    sigma: np.ndarray | None = None
    gradient: np.ndarray | None = None
    gradient_rate: np.ndarray | None = None
    errors: np.ndarray = field(default=None)

    def metrics(self, lost_m: float) -> dict[str, float]:
        e = self.errors
        return {"mean_error_m": float(e.mean()), "final_error_m": float(e[-1]), "max_error_m": float(e.max()),
                "lost": float(e.max() > lost_m), "mean_std_m": float(self.std.mean()),
                "step_us": float(1e6 * np.median(self.step_seconds))}


def run_filter(bundle, terrain, config: TanConfig, truth: Truth, sigma, rng: np.random.Generator,
               fuzzy_units: tuple[float, float] = FUZZY_VARIANTS["fuzzy"], knows_current: bool = False) -> FilterRun:
    from ...filters.particle.terrain import TerrainParticleFilter
    from ...resampling import ResamplingPolicy

    T, dt = config.n_steps, config.dt
    start = truth.states[0]
    P0 = np.diag([config.initial_std ** 2, config.initial_std ** 2, 0.0])
    filt = TerrainParticleFilter(bundle, start, P0, sigma, config.altimeter_sigma, config.n_particles, rng,
                                 terrain=terrain, policy=ResamplingPolicy("systematic", config.resample_threshold),
                                 gradient_scale=fuzzy_units[0], rate_length_m=fuzzy_units[1])
    est, std, times = np.empty((T, 2)), np.empty(T), np.empty(T)
    fuzzy = sigma == "fuzzy"
    sig = np.empty(T) if fuzzy else None
    grad = np.empty(T) if fuzzy else None
    rate = np.empty(T) if fuzzy else None
    U, Z = truth.inputs, truth.measurements
    p = np.array(truth.current, dtype=np.float64) if knows_current else None
    clock = time.perf_counter
    for k in range(T):
        t0 = clock()
        filt.step(U[k], dt, Z[k], p)
        times[k] = clock() - t0
        x, P = filt._x, filt._P
        est[k] = x[:2]
        std[k] = math.sqrt(max(P[0, 0] + P[1, 1], 0.0))
        if fuzzy:
            sig[k], grad[k], rate[k] = filt.sigma, filt.gradient, filt.gradient_rate
    run = FilterRun(est, std, times, sig, grad, rate)
    run.errors = np.hypot(*(est - truth.states[1:, :2]).T)
    return run


def dead_reckoning(bundle, config: TanConfig, truth: Truth) -> FilterRun:
    """The model at zero noise from the start posture, commanded inputs, compass heading, no current."""
    T, dt = config.n_steps, config.dt
    X = np.empty((T, 3))
    x = truth.states[0].copy()
    f = bundle.function("x_next")
    zero_p, zero_w = np.zeros(2), np.zeros(4)
    t0 = time.perf_counter()
    for k in range(T):
        x = f(x, truth.inputs[k], zero_p, zero_w, dt)
        x[2] = truth.measurements[k, 1]
        X[k] = x
    elapsed = time.perf_counter() - t0
    run = FilterRun(X[:, :2], np.zeros(T), np.full(T, elapsed / T))
    run.errors = np.hypot(*(X[:, :2] - truth.states[1:, :2]).T)
    return run


def run_case(config: TanConfig, case_index: int, seed: np.random.SeedSequence):
    """(truth, {filter name: FilterRun}) of one case of one run."""
    from abyssal.generated import load

    map_name, start, current = config.cases()[case_index]
    bundle = load("tan3dof")
    terrain = get_map(map_name, config.map_seed)
    truth = simulate(bundle, terrain, config, STARTS[start], CURRENTS[current],
                     np.random.default_rng(derive(seed, case_index, 0)))
    runs = {}
    specs = [(sigma_name(s), s, FUZZY_VARIANTS["fuzzy"]) for s in config.sigmas]
    specs += [(name, "fuzzy", FUZZY_VARIANTS[name]) for name in config.fuzzy]
    for j, (name, sigma, units) in enumerate(specs):
        runs[name] = run_filter(bundle, terrain, config, truth, sigma,
                                np.random.default_rng(derive(seed, case_index, 1 + j)), units)
    if config.oracle_sigma is not None:
        runs[ORACLE] = run_filter(bundle, terrain, config, truth, config.oracle_sigma,
                                  np.random.default_rng(derive(seed, case_index, 1 + len(specs))), knows_current=True)
    runs["dead_reckoning"] = dead_reckoning(bundle, config, truth)
    return truth, runs


def run_one(config: TanConfig, seed: np.random.SeedSequence) -> list[dict]:
    """Every case and filter of one Monte-Carlo run, as tidy rows (the campaign harness's shape)."""
    run = run_index(seed)
    rows = []
    for i, (map_name, start, current) in enumerate(config.cases()):
        _, runs = run_case(config, i, seed)
        case = case_name(map_name, start, current)
        for name, result in runs.items():
            for metric, value in result.metrics(config.lost_m).items():
                rows.append({"run": run, "case": case, "filter": name, "metric": metric, "value": value})
            if result.sigma is not None:
                rows.append({"run": run, "case": case, "filter": name, "metric": "mean_sigma_m",
                             "value": float(result.sigma.mean())})
    return rows
