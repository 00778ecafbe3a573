"""Seed 003's experiment: SIR with fixed and fuzzy sigma on the simulated tracks (scenario.py), on the campaign harness.

One run (``run_one(config, seed) -> rows``) simulates, for every case map x start x current, one truth and runs
every filter on it; ``report``, ``document`` and ``figures`` are made from the tidy rows only. The paper's words
(it prints figures, not an error table) are paper.py.

* Filters: SIR with fixed sigma 1..6 m, "fuzzy" (gradient in percent, rate in percent per km) and
  "fuzzy_per_cell" (the same rules with the inputs per 500 m map cell: a sensitivity row, the paper
  defines no units), and dead reckoning; 1000 particles at 1 Hz, systematic resampling when N_eff < N/2.
* Start (DECISION): the filter's particles are drawn around the true start posture, N(0, initial_std^2 =
  50^2 m^2) in x and y (the paper gives the initial posture, not its uncertainty).
* Lost track: position error above 1000 m (two map cells) at any time of the run.
* Dead reckoning: the filter's own model at zero noise from the start posture, with the commanded
  inputs and the compass heading (no map, no current): its error is the current's drift.
* Baseline (not a method of the paper): "oracle_known_current", SIR with sigma = ``oracle_sigma``
  (1 m) that is given the true current as its model parameter -- a matched-model oracle. It shows
  what the terrain information supports when nothing has to be absorbed, so a failure of the
  other filters can be told apart from a map without information.

Rows: one per run x case x filter x metric; metrics mean_error_m, final_error_m, max_error_m,
lost (1 when the error ever exceeded 1000 m), mean_std_m (the filter's own position spread),
step_us (median wall time of one step, a timing: never compared across runs) and, for the fuzzy
filter, mean_sigma_m. Figures of single tracks (paths, errors, fuzzy inputs) come from a
separate figure run (``figure_runs``): run 0's seeds of the chosen cases, recomputed in this process.
"""
from __future__ import annotations

import math
import time
from collections import defaultdict
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ...extras import require
from ..campaign import derive, run_index
from . import paper
from .scenario import CURRENTS, START_LABELS, STARTS, Truth, get_map, simulate

EXTRA_COLUMNS: tuple[str, ...] = ()
METRICS = ("mean_error_m", "final_error_m", "max_error_m", "lost", "mean_std_m", "step_us")
SIGMAS = (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
#: fuzzy variants: name -> (gradient_scale, rate_length_m): percent and %/km (default), or per 500 m cell
FUZZY_VARIANTS = {"fuzzy": (100.0, 1000.0), "fuzzy_per_cell": (500.0, 500.0)}
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
        x, P = filt.x, filt.P
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


# ------------------------------------------------------------------------------------- tables
def summary(rows) -> dict:
    """{case: {filter: {metric: mean over runs, plus runs and the std of mean_error_m}}}."""
    values = defaultdict(list)
    for r in rows:
        values[(r["case"], r["filter"], r["metric"])].append(r["value"])
    out: dict = defaultdict(dict)
    for (case, name, metric), v in sorted(values.items()):
        entry = out[case].setdefault(name, {})
        entry[metric] = float(np.mean(v))
        if metric == "mean_error_m":
            entry["runs"] = len(v)
            entry["mean_error_sd_m"] = float(np.std(v, ddof=1)) if len(v) > 1 else float("nan")
    for case in out.values():
        for entry in case.values():
            entry["lost_fraction"] = entry.pop("lost", float("nan"))
    return dict(out)


def report(rows, config: TanConfig) -> str:
    s = summary(rows)
    lines = [f"Terrain-aided navigation (seed 003): {config.n_steps} s per run at 1 Hz, N = {config.n_particles}, "
             f"runs = {next(iter(next(iter(s.values())).values()))['runs']}",
             "error = |estimated - true position| (m), averaged over runs; lost = share of runs whose error ever "
             f"exceeded {config.lost_m:g} m; spread = the filter's own sqrt(P_xx + P_yy); +- = sd over runs of the mean error",
             ""]
    width = max(len(name) for name in config.filters()) + 2
    header = f"{'filter':<{width}}{'mean':>9}{'+-':>7}{'final':>9}{'max':>9}{'lost':>6}{'spread':>8}{'sigma':>7}{'us/step':>9}"
    for case, block in s.items():
        lines += [f"== {case}", header]
        for name in config.filters():
            if name not in block:
                continue
            e = block[name]
            sig = f"{e['mean_sigma_m']:7.2f}" if "mean_sigma_m" in e else f"{'':7}"
            lines.append(f"{name:<{width}}{e['mean_error_m']:9.1f}{e['mean_error_sd_m']:7.1f}{e['final_error_m']:9.1f}"
                         f"{e['max_error_m']:9.1f}{e['lost_fraction']:6.2f}{e['mean_std_m']:8.1f}{sig}{e['step_us']:9.1f}")
        lines.append("")
    if config.oracle_sigma is not None:
        lines.append(f"{ORACLE}: SIR with sigma = {config.oracle_sigma:g} m given the true current -- a matched-model "
                     "oracle, not a method of the paper.")
    lines.append("THE PAPER (quoted; it prints figures, not an error table): " + paper.SUMMARY)
    lines.append(f"THE PAPER's timing: {paper.PAPER_STEP_MS} ms per step in MATLAB (2.6 GHz dual core); ours above is the "
                 "median of this machine's steps (a different machine and language).")
    return "\n".join(lines)


def json_document(rows) -> dict:
    """Per case, per filter: mean_error_m, max_error_m, final_error_m, lost_fraction, step_us (+ the rest)."""
    return summary(rows)


def document(rows, config: TanConfig, prepared=None) -> dict:
    """The JSON summary's entries: {"cases": json_document(rows)}."""
    return {"cases": json_document(rows)}


# ------------------------------------------------------------------------------------- figures
FIGURE_CASES = (("arctic", "rough", "0.1"), ("arctic", "rough", "0.15"), ("arctic", "flat", "0.1"))


def figure_runs(config: TanConfig, seed: int = 0):
    """{case: (truth, runs)} for FIGURE_CASES with run 0's seed (the same numbers as the campaign's run 0)."""

    seed0 = np.random.SeedSequence(seed).spawn(1)[0]
    cases = config.cases()
    out = {}
    for key in FIGURE_CASES:
        if key in cases:
            out[key] = run_case(config, cases.index(key), seed0)
    return out


def figures(rows, out: Path, config: TanConfig, seed: int = 0, prepared=None) -> list[Path]:
    """Figs. 7-15 analogues: spread and error vs sigma per map (from the rows), and run 0's tracks of FIGURE_CASES."""
    require("matplotlib", "the experiment figures").use("Agg")
    plt = require("matplotlib.pyplot", "the experiment figures")

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    s = summary(rows)

    def save(fig, name):
        path = out / name
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)

    # Figs. 7 and 14: localisation spread (and error) vs process noise, per current, rough vs flat
    for m in config.maps:
        fig, axes = plt.subplots(1, 2, figsize=(11, 4))
        for start, style in (("rough", "-"), ("flat", "--")):
            for current in config.currents:
                block = s.get(case_name(m, start, current))
                if not block:
                    continue
                names = [n for n in config.filters() if n.startswith("sigma_")]
                xs = [float(n.split("_")[1]) for n in names]
                axes[0].plot(xs, [block[n]["mean_std_m"] for n in names], style, marker="o", label=f"{start}, current {current}")
                axes[1].plot(xs, [block[n]["mean_error_m"] for n in names], style, marker="o", label=f"{start}, current {current}")
                if "fuzzy" in block:
                    axes[0].axhline(block["fuzzy"]["mean_std_m"], ls=":", lw=0.8, color=axes[0].lines[-1].get_color())
                    axes[1].axhline(block["fuzzy"]["mean_error_m"], ls=":", lw=0.8, color=axes[1].lines[-1].get_color())
        axes[0].set(xlabel="fixed process noise sigma (m)", ylabel="mean localisation spread (m)",
                    title=f"{m}: spread vs sigma (dotted: fuzzy) - cf. Figs. 7, 14")
        axes[1].set(xlabel="fixed process noise sigma (m)", ylabel="mean position error (m)", title=f"{m}: error vs sigma")
        axes[0].legend(fontsize=7)
        save(fig, f"tan_{m}_spread_vs_sigma.png")

    runs = figure_runs(config, seed)
    for (m, start, current), (truth, filt) in runs.items():
        terrain = get_map(m, config.map_seed)
        t = np.arange(1, truth.states.shape[0]) * config.dt
        # Figs. 8/10: paths over the map; Figs. 9/11/15: errors over time
        fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
        xg, yg = terrain.node_coordinates()
        axes[0].contourf(xg / 1e3, yg / 1e3, terrain.depth, 30, cmap="Blues")
        axes[0].plot(truth.states[:, 0] / 1e3, truth.states[:, 1] / 1e3, "k", lw=2, label="truth")
        for name, r in filt.items():
            axes[0].plot(r.estimates[:, 0] / 1e3, r.estimates[:, 1] / 1e3, lw=0.9, label=name)
            axes[1].plot(t, r.errors, lw=0.9, label=name)
        pad = 3.0
        xs, ys = truth.states[:, 0] / 1e3, truth.states[:, 1] / 1e3
        axes[0].set(xlim=(xs.min() - pad, xs.max() + pad), ylim=(ys.min() - pad, ys.max() + pad), xlabel="x (km)",
                    ylabel="y (km)", title=f"{m}, {start} start, current {current} m/s (run 0)")
        axes[1].axhline(config.lost_m, color="r", ls=":", lw=0.8)
        axes[1].set(xlabel="time (s)", ylabel="position error (m)", title="path error - cf. Figs. 9, 11, 15")
        axes[1].legend(fontsize=7, ncol=2)
        save(fig, f"tan_{m}_{start}_current_{current}_paths.png")
        for fz_name in config.fuzzy:
            fz = filt.get(fz_name)
            if fz is None or fz.sigma is None:
                continue
            grad_unit, rate_unit = ("m per 500 m cell", "per cell travelled") if fz_name.endswith("per_cell") else ("%", "%/km")
            # Fig. 12: depth and gradient rate along the path; Fig. 13: G * R vs sigma; input histograms
            fig, axes = plt.subplots(2, 2, figsize=(11, 7))
            axes[0, 0].plot(t, truth.measurements[:, 0], lw=0.6)
            axes[0, 0].set(xlabel="time (s)", ylabel="altimeter depth (m)", title=f"{fz_name}: depth along the path - cf. Fig. 12")
            ax2 = axes[0, 0].twinx()
            ax2.plot(t, fz.gradient_rate, color="tab:red", lw=0.6)
            ax2.set_ylabel(f"gradient rate ({rate_unit})", color="tab:red")
            axes[0, 1].scatter(fz.gradient * fz.gradient_rate, fz.sigma, s=2)
            axes[0, 1].set(xlabel="gradient x gradient rate", ylabel="fuzzy sigma (m)",
                           title="inner product vs sigma - cf. Fig. 13")
            axes[1, 0].hist(np.clip(fz.gradient, -25, 25), bins=50, color="tab:blue")
            axes[1, 0].set(xlabel=f"gradient ({grad_unit}; fuzzy domain [-20, 20])", ylabel="steps", title="distribution of the gradient input")
            axes[1, 1].hist(np.clip(fz.gradient_rate, -25, 25), bins=50, color="tab:red")
            axes[1, 1].set(xlabel=f"gradient rate ({rate_unit}; domain [-20, 20])", ylabel="steps",
                           title="distribution of the gradient-rate input")
            save(fig, f"tan_{m}_{start}_current_{current}_{fz_name}_inputs.png")
    return written


#: the name `abyssal reproduce` looks up (reproduce.py)
Config = TanConfig
