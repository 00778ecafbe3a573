"""`abyssal reproduce cn`: seed 002's Table 7 and Figs. 7-9 on the simulated lake trial (scenario.py), under the
leader geometries the paper does not publish.

Cases. The paper's trial geometry is unpublished (its Fig. 6 shows the AUV between the two leaders, nothing
more), and the geometry decides how well two ranges fix the AUV, so it is a case of the campaign:
scenario.GEOMETRIES "collinear" (both leaders on one line through the AUV: range lines crossing at ~10 deg),
"crossing60" and "crossing90", crossed with the range-noise cases of scenario.NOISE_CASES. One run simulates one
trial per noise case from ``derive(seed, case)``; the leaders' layout draws no random numbers, so the AUV, its
sensors and the range noise are the same under every geometry (paired comparisons). The report gives each
geometry's measured crossing angle and 2-range GDOP (median and the bad tail over every ping of every run).

Filters: dead reckoning, CKF, MCUKF, PF, UPF, HRUPF, IVBCKF, MCUPF -- and, ours, MCC-UPF: MCUPF's MCC proposal
with a fixed N = N_start and multinomial resampling, to separate the proposal's effect from KLD-resampling's --
with the paper's printed tuning Q = diag(10^2, 10^2) m^2 per 5 s step and R = 0.1 m^2 (Table 6 parameters):
that is the paper's case. Every filter runs with the innovation gate off (``gate_probability=0``): the paper's
filters have none, and a gate would make the plain CKF robust (and the tuned UPFs in the multipath case). The MCUKF
and the UPF family use the paper's lambda = 3 - n sigma points (alpha = 1, beta = 0, kappa = 3 - n). "<filter>
tuned" rows use Q = diag(1, 1) m^2 per step (the DR drift over 5 s is well below
1 m) and R = the variance of the simulated range error as the filter sees it: the range noise (1 m^2) plus the
leader's broadcast GPS error along the line of sight (1.53^2 m^2), everything else unchanged. They show what the
printed Q, R cost under each geometry (with R = 1 m^2, the range noise alone, a CKF's ANEES on the crossing60
layout was ~2 and 79 % of its NEES inside the 95 % bound; with the GPS term, 0.6 and 99 %, on 6 trials).

Leaders as sensors. cn2d declares one range sensor per leader (``leader0``, ``leader1``: each its own range, its own
parameters p_k = the leader's broadcast position, its own R). The CKF and the MCUKF fuse each ping as that leader's
sensor update (``predict_to(t, u)`` then ``update(sensor, z, t, p=gps)``: ``run_kalman_by_sensor``); the IVBCKF and
the particle filters have no per-sensor update and consume the stacked form, both sensors' entries with the silent
leader's NaN (a missing entry: its rows are left out of the update, the likelihood, the proposal's update and
the gate) and both leaders' positions as p. Both forms fuse the same range with the same h, p and R at the same
time: against the former one-range model (p = the pinging leader's position, ``run()``), every filter's estimates
were bit-identical on run 0 of seed 0 (both geometries crossing60 and collinear, the four noise cases), once the
IVBCKF is given the paper's u = 8, t = 5 (its default t = n_y + 4 counts both sensors). Timing: the per-sensor loop is two Python calls per ping,
against one C loop for the whole trial before, so the CKF's and MCUKF's ``step_ms`` now include the Python calls.

Random streams: a particle filter's error on one trial depends on its random numbers (on the collinear
geometry MCUPF's APE on one trial differs by metres between streams), so every particle filter runs
``streams`` times per trial on independent streams ``derive(seed, case, 1, crc32(label), stream)`` (a filter's
numbers do not depend on which other filters run). Its per-run APE is the mean over its streams; the spread
between streams (sd, ddof = 1, across the streams of one trial; median over trials) is reported apart.

Rows (``EXTRA_COLUMNS`` = geometry, stream): per filter and stream ``ape_m`` (eq. 46, over the 352 pings),
``final_error_m``, ``anees`` (mean over pings of NEES / 2 with the filter's own covariance; NaN for DR; inf where a
particle cloud collapsed to one point), ``coverage95`` (share of pings whose NEES is inside the 95 % chi-square
bound),
``mean_particles`` (mean over all steps: step 0 runs N_start), ``steady_particles`` (mean over steps 1..: the
count KLD-resampling settles on), ``step_ms`` (wall clock, kept out of the compared tables), ``refused`` (1 when
the filter refused a step of this trial: its other metrics are then NaN and left out of the averages); per trial
(filter "trial") ``crossing_median_deg``, ``crossing_p10_deg``, ``gdop_median``, ``gdop_p90``. The tables
quote the paper's Table 7 (MATLAB on a 2.9 GHz Pentium, real lake data) beside ours; it is never our data.
"""
from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field, replace

import numpy as np

from ...extras import require
from ..campaign import TIMING_METRICS, derive, run_index, run_seeds
from ..tables import MEAN_SD, fraction, over_runs
from . import paper
from .scenario import (GEOMETRIES, GPS_SIGMA, NOISE_CASES, CnScenario, crossing_angles, gdop, ping, position_errors,
                       simulate)

FILTERS = ("DR", "CKF", "MCUKF", "PF", "UPF", "HRUPF", "IVBCKF", "MCUPF", "MCC-UPF")
PARTICLE_FILTERS = frozenset({"PF", "UPF", "HRUPF", "MCUPF", "MCC-UPF"})
EXTRA_COLUMNS: tuple[str, ...] = ("geometry", "stream")
TRIAL = "trial"  # the filter column of the per-trial geometry rows
GEOMETRY_METRICS = ("crossing_median_deg", "crossing_p10_deg", "gdop_median", "gdop_p90")
METRICS = ("ape_m", "final_error_m", "anees", "coverage95", "mean_particles", "steady_particles", "step_ms")


@dataclass(frozen=True)
class CnConfig:
    """One campaign's set-up: the scenario, the cases (geometries x noise cases), the filters and their tuning."""

    scenario: CnScenario = field(default_factory=CnScenario)
    geometries: tuple = tuple(GEOMETRIES)
    cases: tuple = NOISE_CASES
    filters: tuple = FILTERS
    n_particles: int = 5000          # PF, UPF, HRUPF, MCC-UPF; MCUPF's N_start
    kld_n_max: int = 2000            # Table 6
    kld_n_min: int = 50              # ours (the paper states none; N = 1 collapses the filter for good)
    q_std: float = 10.0              # Q = diag(q_std^2, q_std^2) per step
    r: float = 0.1                   # R (m^2) as printed
    sigma: float = 15.0              # MCC kernel bandwidth
    gamma: float = 1.345             # Huber threshold
    ivb_iterations: int = 10         # ours: the paper does not state T_i1
    tuned: tuple = ("CKF", "MCUKF", "IVBCKF", "MCUPF")  # also run with the tuned Q, R (module docstring)
    q_std_tuned: float = 1.0
    r_tuned: float = 1.0 + GPS_SIGMA**2  # range noise + the leader's GPS error along the line of sight, m^2
    streams: int = 3                 # random streams per trial for every particle filter

    def __post_init__(self):
        unknown = [g for g in self.geometries if g not in GEOMETRIES]
        if unknown or not self.geometries:
            raise ValueError(f"geometries must name some of {tuple(GEOMETRIES)}, got {self.geometries!r}")
        if int(self.streams) < 1:
            raise ValueError(f"streams must be >= 1, got {self.streams}")

    def quick(self) -> "CnConfig":
        """every leader geometry, noise cases gaussian and multipath, a 600 s trial (120 pings), N_start = 1000
        (KLD N_max = 500), 2 random streams per particle filter"""
        scenario = replace(self.scenario, duration=600.0, leg_seconds=(200.0, 60.0, 200.0, 60.0, 100.0))
        return replace(self, scenario=scenario, cases=("gaussian", "multipath"), n_particles=1000, kld_n_max=500,
                       streams=2)

    def scenario_for(self, geometry: str) -> CnScenario:
        return replace(self.scenario, leaders=GEOMETRIES[geometry])


def make_filter(name: str, model, trial, config: CnConfig, rng: np.random.Generator):
    """The filter `name` on cn2d, started at the trial's (x0, P0), with the config's tuning."""
    from ...filters.kalman import CKF, MCUKF
    from ...filters.kalman.ivbckf import IVBCKF
    from ...filters.particle import ParticleFilter
    from ...filters.particle.unscented import UnscentedParticleFilter
    from ...noise.mixtures import GaussianMixture
    from ...resampling import KLDResampling, ResamplingPolicy

    tuned = name.endswith(" tuned")
    name = name.removesuffix(" tuned")
    Q = np.eye(2) * (config.q_std_tuned if tuned else config.q_std) ** 2
    R = np.eye(model.n_y) * (config.r_tuned if tuned else config.r)  # each leader sensor its own block
    x0, P0 = trial.x0, trial.P0
    lam = 3.0 - model.n_x
    if name == "CKF":
        return CKF(model, x0, P0, Q, R, gate_probability=0.0, t0=trial.t[0] - trial.dt)
    if name == "MCUKF":
        return MCUKF(model, x0, P0, Q, R, sigma=config.sigma, alpha=1.0, beta=0.0, kappa=lam, gate_probability=0.0,
                     t0=trial.t[0] - trial.dt)
    if name == "IVBCKF":
        # the paper's printed u = 8, t = 5 (tau_R = t - m - 1 = 3 for the one range of a ping; the class's default
        # t = n_y + 4 would count both leader sensors, m = 2, and give tau_R = 4)
        return IVBCKF(model, x0, P0, Q, R, u=8.0, t=5.0, iterations=config.ivb_iterations,
                      gate_probability=0.0)  # as the paper's
    if name == "PF":
        noise = GaussianMixture(np.ones(1), np.zeros((1, model.n_y)), R[None])
        return ParticleFilter(model, x0, P0, Q, noise, config.n_particles, rng,
                              policy=ResamplingPolicy("multinomial", 1.0), gate_probability=0.0)
    if name == "UPF":
        return UnscentedParticleFilter(model, x0, P0, Q, R, config.n_particles, rng, gate_probability=0.0)
    if name == "HRUPF":
        return UnscentedParticleFilter(model, x0, P0, Q, R, config.n_particles, rng, update="huber", gamma=config.gamma,
                                       gate_probability=0.0)
    if name == "MCUPF":
        return UnscentedParticleFilter(model, x0, P0, Q, R, config.n_particles, rng, update="mcc", sigma=config.sigma,
                                       resampling=KLDResampling(n_min=config.kld_n_min, n_max=config.kld_n_max),
                                       gate_probability=0.0)
    if name == "MCC-UPF":
        return UnscentedParticleFilter(model, x0, P0, Q, R, config.n_particles, rng, update="mcc", sigma=config.sigma,
                                       name="MCC-UPF", gate_probability=0.0)
    raise ValueError(f"unknown filter {name!r}; choose one of {FILTERS}")


def filter_names(config: CnConfig) -> list[str]:
    """The rows of the table: the filters with the printed tuning, then the tuned ones."""
    return list(config.filters) + [f"{f} tuned" for f in config.tuned if f in config.filters]


def is_particle_filter(label: str) -> bool:
    return label.removesuffix(" tuned") in PARTICLE_FILTERS


@dataclass
class FilterTrace:
    """One filter's run on one trial: what the rows and the figures are made from."""

    x: np.ndarray          # (K, 2) estimates
    nees: np.ndarray       # (K,) NaN for DR
    particles: np.ndarray  # (K,) NaN for Kalman filters and DR
    step_time: np.ndarray  # (K,) s


def run_filters(config: CnConfig, seed: np.random.SeedSequence, geometry: str, case_index: int,
                streams: int | None = None, labels=None):
    """(trial, {(label, stream): FilterTrace, or None where the filter refused a step}) for one geometry and noise
    case of one run; ``streams`` (default config.streams) random streams for the particle filters, one for the
    others."""
    import abyssal.generated

    model = abyssal.generated.load("cn2d")
    case = config.cases[case_index]
    trial = simulate(config.scenario_for(geometry), case, np.random.default_rng(derive(seed, case_index)))
    streams = config.streams if streams is None else streams
    K = len(trial.t)
    out = {}
    for label in labels or filter_names(config):
        if label == "DR":
            out[(label, 0)] = FilterTrace(trial.dr, np.full(K, np.nan), np.full(K, np.nan), np.zeros(K))
            continue
        for stream in range(streams if is_particle_filter(label) else 1):
            rng = np.random.default_rng(derive(seed, case_index, 1, zlib.crc32(label.encode()), stream))
            filt = make_filter(label, model, trial, config, rng)
            try:
                with np.errstate(over="ignore"):  # the NEES of a cloud collapsed to one point (P = 0) is inf
                    if hasattr(filt, "update_sensor"):
                        out[(label, stream)] = run_kalman_by_sensor(filt, trial)
                        continue
                    result = filt.run(trial.U, trial.Z, trial.dt, params=trial.params, truth=trial.truth)
            except (ValueError, ArithmeticError, np.linalg.LinAlgError):
                out[(label, stream)] = None  # the filter refused a step: an outcome of this filter on this trial
                continue
            out[(label, stream)] = FilterTrace(result.x, result.nees, result.particles, result.step_time)
    return trial, out


def run_kalman_by_sensor(filt, trial) -> FilterTrace:
    """A Kalman filter of the C runtime over the trial, each ping fused as its leader's own sensor update: predicted
    to the ping's time with the input held (``predict_to``), then ``update(sensor, z, t, p=gps)`` with that sensor's
    R; the NEES of each ping from the filter's own P. Refusals raise ValueError (as ``run``)."""
    import time

    K = len(trial.t)
    x, nees, step_time = np.empty((K, 2)), np.empty(K), np.empty(K)
    for k in range(K):
        sensor, z, p = ping(trial, k)
        start = time.perf_counter()
        filt.predict_to(trial.t[k], trial.U[k])
        filt.update(sensor, z, trial.t[k], p=p)
        step_time[k] = time.perf_counter() - start
        x[k] = filt.x
        e = x[k] - trial.truth[k]
        nees[k] = float(e @ np.linalg.solve(filt.P, e))
    return FilterTrace(x, nees, np.full(K, np.nan), step_time)


def trial_geometry(trial) -> dict:
    """The trial's crossing angle (deg) and 2-range GDOP: median and the bad tail over its pings."""
    angle, dop = crossing_angles(trial), gdop(trial)
    return {"crossing_median_deg": float(np.median(angle)), "crossing_p10_deg": float(np.percentile(angle, 10)),
            "gdop_median": float(np.median(dop)), "gdop_p90": float(np.percentile(dop, 90))}


#: chi-square 95 % quantile with 2 degrees of freedom (= -2 ln 0.05): a consistent filter's NEES is below it at 95 %
#: of the pings
NEES_BOUND_95 = -2.0 * math.log(0.05)


def _anees(nees: np.ndarray) -> float:
    """Mean over the pings of NEES / n_x (n_x = 2); inf when a particle cloud collapsed to a point (P = 0); NaN for
    DR (no covariance)."""
    if np.isnan(nees).all():
        return math.nan
    with np.errstate(over="ignore"):
        return float(np.mean(nees) / 2.0)


def _coverage(nees: np.ndarray) -> float:
    """Share of the pings whose NEES lies inside the 95 % chi-square bound (NaN for DR)."""
    return math.nan if np.isnan(nees).all() else float(np.mean(nees <= NEES_BOUND_95))


def run_one(config: CnConfig, seed: np.random.SeedSequence) -> list[dict]:
    """One campaign run: every geometry x noise case x filter (x stream); tidy rows (campaign.py)."""
    run = run_index(seed)
    rows = []

    def add(case, geometry, label, stream, metrics):
        rows.extend({"run": run, "case": case, "filter": label, "metric": k, "geometry": geometry, "stream": stream,
                     "value": v} for k, v in metrics.items())

    for geometry in config.geometries:
        for i, case in enumerate(config.cases):
            trial, traces = run_filters(config, seed, geometry, i)
            add(case, geometry, TRIAL, 0, trial_geometry(trial))
            for (label, stream), tr in traces.items():
                if tr is None:  # refused: NaN metrics (left out of the averages, counted in "refused")
                    add(case, geometry, label, stream, {**{m: math.nan for m in METRICS}, "refused": 1.0})
                    continue
                pe = position_errors(tr.x, trial.truth)
                counted = np.isfinite(tr.particles)
                add(case, geometry, label, stream, {
                    "ape_m": float(pe.mean()), "final_error_m": float(pe[-1]),
                    "anees": _anees(tr.nees), "coverage95": _coverage(tr.nees),
                    "mean_particles": float(np.mean(tr.particles)) if counted.all() else math.nan,
                    "steady_particles": float(np.mean(tr.particles[1:])) if counted.all() and len(counted) > 1 else math.nan,
                    "step_ms": float(np.mean(tr.step_time) * 1e3), "refused": 0.0})
    return rows


# ---------------------------------------------------------------------------------------------
# tables


def _per_run(rows) -> dict:
    """{(geometry, case, filter, metric): {run: [value per stream]}} (streams in order)."""
    out: dict = {}
    for r in sorted(rows, key=lambda r: (r["run"], int(r["stream"]))):
        out.setdefault((r["geometry"], r["case"], r["filter"], r["metric"]), {}).setdefault(r["run"], []).append(r["value"])
    return out


def _stream_mean(values: list) -> float:
    """Mean over one trial's streams, a refused stream (NaN) left out (inf stays inf; NaN if every one refused)."""
    v = np.asarray(values, dtype=float)
    v = v[~np.isnan(v)]
    return float(np.mean(v)) if v.size else math.nan


def summary(rows) -> dict:
    """{(geometry, case, filter): {metric: OverRuns of the per-run value (a particle filter's = mean over its
    streams), "stream_sd_m": median over runs of the APE's sd across streams (ddof = 1), "below_dr", "below_dr4":
    (runs whose APE < DR's, < DR's / 4, runs)}}; the trial rows give the geometry metrics (over runs' medians)."""
    per_run = _per_run(rows)
    out: dict = {}
    for (geometry, case, label, metric), runs in per_run.items():
        entry = out.setdefault((geometry, case, label), {})
        entry[metric] = over_runs(_stream_mean(v) for v in runs.values())
        if metric == "refused":
            entry["refused_streams"] = int(sum(sum(v) for v in runs.values()))
        if metric == "ape_m":
            sds = [float(np.std(v, ddof=1)) for v in runs.values() if len(v) > 1]
            entry["stream_sd_m"] = float(np.median(sds)) if sds else math.nan
            entry["streams"] = max(len(v) for v in runs.values())
            dr = per_run.get((geometry, case, "DR", "ape_m"), {})
            pairs = [(_stream_mean(v), dr[run][0]) for run, v in runs.items() if run in dr]
            pairs = [(a, d) for a, d in pairs if not math.isnan(a)]
            entry["below_dr"] = fraction(a < d for a, d in pairs)
            entry["below_dr4"] = fraction(a < d / 4 for a, d in pairs)
            entry["ratio_to_dr"] = over_runs(a / d for a, d in pairs)
    return out


def geometry_summary(rows) -> dict:
    """{geometry: {metric: median over the trials (runs x noise cases) of each trial's statistic over its pings}}:
    the crossing angle's median and 10th percentile, the GDOP's median and 90th percentile."""
    values: dict = {}
    for r in rows:
        if r["filter"] == TRIAL:
            values.setdefault(r["geometry"], {}).setdefault(r["metric"], []).append(r["value"])
    return {g: {m: float(np.median(v)) for m, v in metrics.items()} for g, metrics in values.items()}


def best_counts(rows, labels) -> dict:
    """{(geometry, case): {label: runs where label has the lowest APE among labels}} and the number of runs."""
    per_run = _per_run(rows)
    out: dict = {}
    keys = {(g, c) for (g, c, f, m) in per_run if m == "ape_m"}
    for g, c in keys:
        apes = {f: {run: _stream_mean(v) for run, v in per_run[(g, c, f, "ape_m")].items()}
                for f in labels if (g, c, f, "ape_m") in per_run}
        runs = sorted(set.intersection(*(set(v) for v in apes.values()))) if apes else []
        wins = {f: 0 for f in apes}
        for run in runs:
            wins[min(apes, key=lambda f: apes[f][run])] += 1
        out[(g, c)] = (wins, len(runs))
    return out


def _g(value: float) -> str:
    """A consistency number, short: 1.03, 12.5, 3.4e+05, inf."""
    return f"{value:.3g}" if math.isfinite(value) else str(value)


def _leaders_text(geometry: str) -> str:
    (a, b), (c, d) = GEOMETRIES[geometry]
    return f"leader 0 at ({a:+.0f}, {b:+.0f}) m, leader 1 at ({c:+.0f}, {d:+.0f}) m"


def report(rows, config: CnConfig) -> str:
    s, geo = summary(rows), geometry_summary(rows)
    runs = len({r["run"] for r in rows})
    labels = [f for f in filter_names(config) if any(k[2] == f for k in s)]
    cases = [c for c in config.cases if any(k[1] == c for k in s)]
    printed = [f for f in labels if f in paper.TABLE7]
    lines = [
        f"Seed 002, Table 7 on a SIMULATED lake trial (scenario.py; the paper's Lake Thai data is not public): {runs} "
        f"run(s) x {len(config.geometries)} leader geometries x {len(cases)} range-noise cases, particle filters on "
        f"{config.streams} random stream(s) per trial (N_start = {config.n_particles}).",
        f"The paper's case: its printed tuning Q = diag({config.q_std:g}^2, {config.q_std:g}^2) m^2 per ping, "
        f"R = {config.r:g} m^2; 'tuned' rows: Q = diag({config.q_std_tuned:g}^2, {config.q_std_tuned:g}^2), "
        f"R = {config.r_tuned:.3g} (the simulated range noise, sigma = {math.sqrt(config.scenario.range_variance):g} m, "
        f"plus the leader's GPS error, {config.scenario.gps_sigma:.2f} m per axis).",
        f"APE (eq. 46, m): {MEAN_SD}; a particle filter's per-run APE is the mean over its streams.",
        "Paper: Table 7, real lake data of unpublished geometry, MATLAB on a 2.9 GHz Pentium -- quoted, not ours.",
    ]
    for geometry in config.geometries:
        if geometry not in geo:
            continue
        g = geo[geometry]
        lines += ["", f"== geometry {geometry}: {_leaders_text(geometry)} from (the AUV's smoothed east, the centre line)",
                  f"   range lines cross at {g['crossing_median_deg']:.1f} deg (median; 10th percentile "
                  f"{g['crossing_p10_deg']:.1f} deg), 2-range GDOP {g['gdop_median']:.2f} (median; 90th percentile "
                  f"{g['gdop_p90']:.3g}); medians over the trials of each trial's statistic over its pings", ""]
        head = f"{'APE m':14s}" + "".join(f"{c:>17s}" for c in cases) + f"{'paper APE m':>13s}"
        lines += [head, "-" * len(head)]
        for f in labels:
            cells = "".join(f"{s[(geometry, c, f)]['ape_m'].cell('.2f') if (geometry, c, f) in s else '-':>17s}"
                            for c in cases)
            pa = paper.TABLE7.get(f)
            lines.append(f"{f:14s}{cells}{(f'{pa[0]:.1f}' if pa else '-'):>13s}")
        lines += _filter_table("vs DR, streams", "runs with APE < DR/4 (< DR); particle filters: APE sd between streams "
                               "(m, median over runs); R<k>: k refused streams", s, geometry, cases, labels, _vs_dr_cell)
        lines += _filter_table("consistency", "ANEES (NEES / 2, median over runs) / pings inside the 95 % NEES bound "
                               "(mean over runs; 95 % if consistent)", s, geometry, cases, labels, _consistency_cell)
        wins = best_counts([r for r in rows if r["geometry"] == geometry], printed)
        for c in cases:
            if (geometry, c) in wins:
                w, n = wins[(geometry, c)]
                best = max(w, key=w.get) if w else "-"
                lines.append(f"   {c}: MCUPF has the lowest APE of the printed-tuning filters in {w.get('MCUPF', 0)}/{n} "
                             f"runs (most often lowest: {best}, {w.get(best, 0)}/{n})")
    lines += ["", "Paper's APE ranking (Table 7): " + " < ".join(paper.APE_RANKING), "", kld_table(rows, config)]
    return "\n".join(lines)


def _filter_table(title: str, note: str, s: dict, geometry: str, cases, labels, cell) -> list[str]:
    """A sub-table of one geometry: a row per filter (DR left out), a column per noise case, ``cell(f, entry)``."""
    lines = ["", f"{title:14s}" + "".join(f"{c:>22s}" for c in cases) + "   " + note]
    for f in labels:
        if f != "DR":
            entries = [s.get((geometry, c, f)) for c in cases]
            lines.append(f"{f:14s}" + "".join(f"{cell(f, e) if e else '-':>22s}" for e in entries))
    return lines


def _vs_dr_cell(f: str, e: dict) -> str:
    (k4, n), (k1, _) = e["below_dr4"], e["below_dr"]
    cell = f"{k4}/{n} ({k1}/{n})" + (f" R{e['refused_streams']}" if e.get("refused_streams") else "")
    if is_particle_filter(f) and math.isfinite(e["stream_sd_m"]):
        cell += f" sd {e['stream_sd_m']:.2f}"
    return cell


def _consistency_cell(f: str, e: dict) -> str:
    return f"{_g(e['anees'].median)} / {100 * e['coverage95'].mean:.0f} %" if e["coverage95"].n else "-"


def kld_table(rows, config: CnConfig) -> str:
    """MCUPF's particle count: the mean over every step (step 0 runs N_start) and the steady count (steps 1..)."""
    s = summary(rows)
    kld = [f for f in filter_names(config) if f.removesuffix(" tuned") == "MCUPF"]
    lines = [f"KLD-resampling particle count (N_start = {config.n_particles}, N_max = {config.kld_n_max}, our floor "
             f"n_min = {config.kld_n_min}): steady = mean over steps 1.. (mean over every step, step 0 included), "
             "mean over runs and streams"]
    for f in kld:
        for geometry in config.geometries:
            cells = []
            for c in config.cases:
                e = s.get((geometry, c, f))
                if e and e["steady_particles"].n:
                    cells.append(f"{c} {e['steady_particles'].mean:.0f} ({e['mean_particles'].mean:.0f})")
            if cells:
                lines.append(f"  {f:12s} {geometry:11s} " + "; ".join(cells))
    return "\n".join(lines)


def timing_table(rows) -> str:
    """Mean wall time per step (machine- and load-dependent: not part of the reproducible tables)."""
    values: dict = {}
    for r in rows:
        if r["metric"] in TIMING_METRICS and r["filter"] not in ("DR", TRIAL):
            values.setdefault(r["filter"], []).append(r["value"])
    parts = [f"{f} {np.mean(v):.3f}" for f, v in values.items()]
    return ("Wall time per filter step, ms, mean over every run, case and stream (varies with the machine and its "
            "load; `abyssal bench` measures them side by side):\n  " + "; ".join(parts))


def markdown(rows, config: CnConfig, document: dict | None = None) -> dict[str, str]:
    """The tables of docs/experiments/cn.md (`abyssal publish cn`, publish.py), from the rows."""
    from ..publish import markdown_table, number

    s, geo = summary(rows), geometry_summary(rows)
    labels = [f for f in filter_names(config) if any(k[2] == f for k in s)]
    cases = [c for c in config.cases if any(k[1] == c for k in s)]
    printed = [f for f in labels if f in paper.TABLE7]
    out = {"geometry": markdown_table(
        ["geometry", "leaders (east, north) m", "crossing angle deg: median", "10th percentile", "2-range GDOP: median",
         "90th percentile"],
        [[g, _leaders_text(g), f"{geo[g]['crossing_median_deg']:.1f}", f"{geo[g]['crossing_p10_deg']:.1f}",
          f"{geo[g]['gdop_median']:.2f}", f"{geo[g]['gdop_p90']:.3g}"] for g in config.geometries if g in geo],
        align="llrrrr")}
    for geometry in config.geometries:
        if geometry not in geo:
            continue
        body = []
        for f in labels:
            cells = [s[(geometry, c, f)]["ape_m"].cell(".2f") if (geometry, c, f) in s else "-" for c in cases]
            body.append([f, *cells, number(paper.TABLE7[f][0], ".1f") if f in paper.TABLE7 else "-"])
        out[f"ape-{geometry}"] = markdown_table(["filter", *cases, "paper (Table 7, real lake data)"], body)
        body = [[f, *(_vs_dr_cell(f, s[(geometry, c, f)]) if (geometry, c, f) in s else "-" for c in cases)]
                for f in labels if f != "DR"]
        out[f"vs-dr-{geometry}"] = markdown_table(["filter", *cases], body)
        body = [[f, *(_consistency_cell(f, s[(geometry, c, f)]) if (geometry, c, f) in s else "-" for c in cases)]
                for f in labels if f != "DR"]
        out[f"consistency-{geometry}"] = markdown_table(["filter", *cases], body)
    body = []
    wins = best_counts(rows, printed)
    for geometry in config.geometries:
        for c in cases:
            if (geometry, c) in wins:
                w, n = wins[(geometry, c)]
                best = max(w, key=w.get) if w else "-"
                body.append([geometry, c, f"{w.get('MCUPF', 0)}/{n}", f"{best} ({w.get(best, 0)}/{n})"])
    out["best"] = markdown_table(["geometry", "noise case", "runs where MCUPF has the lowest APE of the printed-tuning "
                                  "filters", "most often lowest"], body, align="llrl")
    body = []
    for f in [f for f in labels if f.removesuffix(" tuned") == "MCUPF"]:
        for geometry in config.geometries:
            cells = []
            for c in cases:
                e = s.get((geometry, c, f))
                cells.append(f"{e['steady_particles'].mean:.0f} ({e['mean_particles'].mean:.0f})"
                             if e and e["steady_particles"].n else "-")
            body.append([f, geometry, *cells])
    out["kld"] = markdown_table(["filter", "geometry", *cases], body, align="ll" + "r" * len(cases))
    values: dict = {}
    for r in rows:
        if r["metric"] in TIMING_METRICS and r["filter"] not in ("DR", TRIAL):
            values.setdefault(r["filter"], []).append(r["value"])
    out["timing"] = markdown_table(["filter", "wall time per step, ms (this campaign's machine and load)",
                                    "paper (Table 7, MATLAB), ms"],
                                   [[f, f"{np.mean(v):.3f}", number(1e3 * paper.TABLE7[f][1], ".3g") if f in paper.TABLE7
                                     else "-"] for f, v in values.items()])
    return out


def document(rows, config: CnConfig, prepared=None) -> dict:
    """The JSON summary's entries: what the data is, the geometries (leaders, crossing angle, GDOP) and the
    cases {geometry: {noise case: {filter: {...}}}}."""
    geo = geometry_summary(rows)
    return {"data": "simulated lake trial (the paper's data is not public)",
            "statistic": f"ape_m: {MEAN_SD}; per-run APE of a particle filter = mean over its streams",
            "geometries": {g: {"leaders_m": [list(p) for p in GEOMETRIES[g]], **geo.get(g, {})} for g in config.geometries},
            "cases": json_document(rows)}


def json_document(rows) -> dict:
    """{geometry: {case: {filter: {ape_m, ape_m_sd, ape_m_ci95, runs, ...}}}} (NaN kept: reproduce writes null)."""
    out: dict = {}
    for (geometry, case, f), e in summary(rows).items():
        if f == TRIAL:
            continue
        ape = e["ape_m"]
        entry = {"ape_m": ape.mean, "ape_m_sd": ape.sd, "ape_m_ci95": ape.ci95, "runs": ape.n,
                 "final_error_m": e["final_error_m"].mean, "anees_median": e["anees"].median,
                 "coverage95": e["coverage95"].mean,
                 "runs_below_dr": e["below_dr"][0], "runs_below_quarter_dr": e["below_dr4"][0]}
        if is_particle_filter(f):
            entry.update(streams=e["streams"], stream_sd_m=e["stream_sd_m"], mean_particles=e["mean_particles"].mean,
                         steady_particles=e["steady_particles"].mean)
        if f in paper.TABLE7:  # (tuned rows have no paper number)
            entry["paper_ape_m"] = paper.TABLE7[f][0]
        out.setdefault(geometry, {}).setdefault(case, {})[f] = entry
    return out


# ---------------------------------------------------------------------------------------------
# figures


def _figure_runs(config: CnConfig, seed: int):
    """Run 0 of the first noise case, stream 0, under every geometry (re-run from the same seed, so the figures
    show runs that are in the table): {geometry: (trial, {label: FilterTrace})}."""
    s0 = run_seeds(seed, 1)[0]
    out = {}
    for geometry in config.geometries:
        trial, traces = run_filters(config, s0, geometry, 0, streams=1)
        out[geometry] = (trial, {label: tr for (label, _), tr in traces.items() if tr is not None})
    return out


def _settings_text(rows, config: CnConfig, seed: int, settings: str | None) -> str:
    runs = len({r["run"] for r in rows})
    detail = (f"{runs} run(s), seed {seed}, {config.scenario.duration:g} s trials, N_start {config.n_particles}, "
              f"{config.streams} stream(s)")
    return f"{settings}: {detail}" if settings else detail


def figures(rows, out, config: CnConfig, seed: int = 0, prepared=None, settings: str | None = None) -> list:
    """cn_geometry.png (tracks, leaders, crossing angle), cn_errors.png (position error vs time, the paper's Fig. 9),
    cn_ape.png (APE per filter, geometry and noise case, the paper's Table 7 as markers), cn_kld.png (MCUPF's
    particle count). The time plots show run 0 of the first noise case (stream 0)."""
    from ... import plots

    plt = require("matplotlib.pyplot", "the experiment figures")
    stamp = _settings_text(rows, config, seed, settings)
    labels = filter_names(config)
    runs0 = _figure_runs(config, seed)
    case0 = config.cases[0]
    paths = []

    # geometry: tracks and leaders (top), crossing angle over time (bottom)
    n = len(config.geometries)
    fig, axes = plt.subplots(2, n, figsize=(4.6 * n, 8), squeeze=False, gridspec_kw={"height_ratios": (3, 2)})
    for j, geometry in enumerate(config.geometries):
        trial, _ = runs0[geometry]
        ax = axes[0, j]
        ax.plot(trial.truth[:, 0], trial.truth[:, 1], color="black", lw=1.6, label="AUV (truth)")
        ax.plot(trial.dr[:, 0], trial.dr[:, 1], **_line(plots.filter_style("DR", tuple(labels))), label="dead reckoning")
        for k, marker in ((0, "^"), (1, "v")):
            ax.plot(trial.leaders_true[k, :, 0], trial.leaders_true[k, :, 1], color="#777777", lw=1, ls="--")
            ax.plot(trial.leaders_true[k, ::40, 0], trial.leaders_true[k, ::40, 1], marker, color="#777777", ls="none",
                    label=f"leader {k}")
        ax.set(xlabel="east (m)", ylabel="north (m)", title=f"{geometry}: {_leaders_text(geometry)}", aspect="equal")
        ax.title.set_fontsize(8)
        ax.legend(fontsize=7, loc="best")  # the least-covered corner: the tracks differ per geometry and duration
        ax = axes[1, j]
        angle = crossing_angles(trial)
        ax.plot(trial.t, angle, color="black", lw=1)
        ax.axhline(np.median(angle), color="black", lw=0.8, ls=":",
                   label=f"median {np.median(angle):.1f} deg, GDOP {np.median(gdop(trial)):.2f}")
        ax.set(xlabel="time (s)", ylabel="range-line crossing angle (deg)", ylim=(0, 92))
        ax.legend(fontsize=7, loc="lower right")
        ax.grid(alpha=0.3)
    fig.suptitle(f"seed 002 simulated lake trial: leader geometries (run 0, noise case {case0})")
    paths.append(_save(fig, out / "cn_geometry.png", stamp, plots))

    # position error vs time: rows geometries, columns printed / tuned
    tuned = [f for f in labels if f.endswith(" tuned")]
    columns = [("printed tuning (the paper's Q, R)", [f for f in labels if not f.endswith(" tuned")])]
    if tuned:
        columns.append(("tuned Q, R", ["DR"] + tuned))
    fig, axes = plt.subplots(n, len(columns), figsize=(7 * len(columns), 3.3 * n), squeeze=False, sharex=True)
    for i, geometry in enumerate(config.geometries):
        trial, traces = runs0[geometry]
        for j, (title, names) in enumerate(columns):
            ax = axes[i, j]
            for f in names:
                if f in traces:
                    pe = position_errors(traces[f].x, trial.truth)
                    ax.plot(trial.t, pe, **_line(plots.filter_style(f, tuple(labels)), every=max(1, len(pe) // 12)),
                            label=f"{f} ({pe.mean():.1f})")
            ax.set(yscale="log", ylabel="position error (m)", title=f"{geometry}, {title}")
            plots.plain_log_labels(ax)
            ax.title.set_fontsize(9)
            ax.grid(alpha=0.3, which="both")
            ax.legend(fontsize=6.5, ncol=3, loc="upper left", title="filter (APE, m)", title_fontsize=6.5)
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    fig.suptitle(f"position error PE(k), eq. 45 (cf. the paper's Fig. 9): run 0, noise case {case0}, stream 0")
    paths.append(_save(fig, out / "cn_errors.png", stamp, plots))

    paths.append(_ape_figure(rows, config, out, stamp, labels, plots, plt))

    # KLD particle count: one panel per geometry, the count each MCUPF ran with and what KLD-resampling asked for
    kld = [f for f in labels if f.removesuffix(" tuned") == "MCUPF"]
    if kld:
        paths.append(_kld_figure(config, seed, kld, labels, stamp, out, plots, plt))
    return paths


def kld_trace(config: CnConfig, trial, label: str, rng) -> tuple[np.ndarray, np.ndarray]:
    """(particle count each step ran with, the KLD bound N(k) unclamped) of one MCUPF run, k = the 10 m bins the
    resampled cloud occupies after the step (what KLD-resampling's stopping rule saw), stepped here by hand."""
    import abyssal.generated

    from ...resampling.kld import kld_sample_size

    model = abyssal.generated.load("cn2d")
    filt = make_filter(label, model, trial, config, rng)
    policy = filt.policy
    counts, bounds = np.empty(len(trial.t)), np.empty(len(trial.t))
    for k in range(len(trial.t)):
        counts[k] = filt.N
        filt.step(trial.U[k], trial.dt, trial.Z[k], trial.params[k])
        cells = np.floor(filt.particles[list(policy.coordinates)] / np.asarray(policy.bin_size)[:, None])
        occupied = len(np.unique(cells, axis=1).T)
        bounds[k] = kld_sample_size(occupied, policy.epsilon, policy.delta)
    return counts, bounds


def _kld_figure(config: CnConfig, seed: int, kld: list[str], labels, stamp: str, out, plots, plt):
    """cn_kld.png: one row per MCUPF row (printed tuning, tuned), one column per geometry: the particle count it ran
    with (run 0, first noise case, stream 0) and the KLD bound N(k) it came from before the clamp to [N_min, N_max]:
    where the bound lies below the floor, the floor decides the count."""
    s0 = run_seeds(seed, 1)[0]
    case0 = config.cases[0]
    n = len(config.geometries)
    fig, axes = plt.subplots(len(kld), n, figsize=(4.6 * n + 0.6, 3.3 * len(kld) + 1.2), squeeze=False, sharey=True,
                             sharex=True)
    trials = {g: simulate(config.scenario_for(g), case0, np.random.default_rng(derive(s0, 0))) for g in config.geometries}
    for row, f in enumerate(kld):
        style = plots.filter_style(f, tuple(labels))
        for col, geometry in enumerate(config.geometries):
            ax, trial = axes[row, col], trials[geometry]
            rng = np.random.default_rng(derive(s0, 0, 1, zlib.crc32(f.encode()), 0))  # run_filters' stream 0
            counts, bounds = kld_trace(config, trial, f, rng)
            ax.step(trial.t, counts, where="post", color=style["color"], lw=1.8,
                    label=f"particles the step ran with (steady {np.mean(counts[1:]):.0f})")
            ax.plot(trial.t, bounds, color="#333333", ls=":", lw=0.9,
                    label=f"KLD bound N(k) before the clamp (median {np.median(bounds[1:]):.0f})")
            for level, text, ls in ((config.kld_n_min, f"floor N_min = {config.kld_n_min} (ours)", "-."),
                                    (config.kld_n_max, f"N_max = {config.kld_n_max} (Table 6)", "--")):
                ax.axhline(level, color="black", lw=0.8, ls=ls, zorder=1)
                ax.text(0.02, level * 1.15, text, transform=ax.get_yaxis_transform(), fontsize=7,
                        bbox={"facecolor": "white", "edgecolor": "none", "pad": 0.5, "alpha": 0.8})
            ax.set(yscale="log", title=f"{f}, {geometry}", xlabel="time (s)" if row == len(kld) - 1 else None)
            ax.title.set_fontsize(9)
            plots.plain_log_labels(ax)
            ax.grid(alpha=0.3, which="both")
            ax.legend(fontsize=7, loc="center right")
        axes[row, 0].set_ylabel("particles")
    fig.suptitle(f"MCUPF under KLD-resampling (eps 0.15, delta 0.01, 10 m bins, N_start = {config.n_particles}): the "
                 f"count and the bound it came from; run 0, {case0}, stream 0", fontsize=10)
    return _save(fig, out / "cn_kld.png", stamp, plots, rect=(0, 0.02, 1, 1))


def _line(style: dict, every: int | None = None) -> dict:
    """A filter's look as plot keywords (markers spaced ``every`` points apart, so lines stay readable)."""
    kw = {"color": style["color"], "linestyle": style["linestyle"], "lw": 1.1}
    if every:
        kw.update(marker=style["marker"], markevery=every, markersize=4)
    return kw


def _save(fig, path, stamp: str, plots, rect=(0, 0.02, 1, 1)):
    return plots.save_figure(fig, path, stamp, rect=rect, dpi=100)


def _ape_figure(rows, config: CnConfig, out, stamp, labels, plots, plt):
    """One panel per geometry: each filter's APE (mean over runs, sd as the bar) per noise case; the paper's Table 7
    values in a panel of their own (labelled markers nothing is drawn over; its geometry is unknown)."""
    s = summary(rows)
    geo = geometry_summary(rows)
    cases = [c for c in config.cases if any(k[1] == c for k in s)]
    names = [f for f in labels if any(k[2] == f for k in s)]
    n = len(config.geometries)
    fig, axes = plt.subplots(1, n + 1, figsize=(4.8 * n + 2.2, 5.4), squeeze=False, sharey=True,
                             gridspec_kw={"width_ratios": [max(2, len(cases))] * n + [1.3]})
    width = 0.8 / max(1, len(names))
    for j, geometry in enumerate(config.geometries):
        ax = axes[0, j]
        for k, f in enumerate(names):
            style = plots.filter_style(f, tuple(labels))
            xs = [i - 0.4 + width * (k + 0.5) for i in range(len(cases))]
            stats = [s.get((geometry, c, f), {}).get("ape_m") for c in cases]
            mean = [e.mean if e else np.nan for e in stats]
            sd = [e.sd if e and math.isfinite(e.sd) else 0.0 for e in stats]
            ax.errorbar(xs, mean, yerr=sd, color=style["color"], marker=style["marker"], ls="none", ms=5, capsize=2,
                        markerfacecolor="white" if f.endswith(" tuned") else style["color"], label=f)
        ax.set_xticks(range(len(cases)), cases, fontsize=8)
        ax.set(yscale="log", xlabel="range-noise case",
               title=f"{geometry}: lines cross at {geo.get(geometry, {}).get('crossing_median_deg', math.nan):.0f} deg")
        ax.title.set_fontsize(10)
        plots.plain_log_labels(ax)
        ax.grid(alpha=0.3, which="both", axis="y")
    axes[0, 0].set_ylabel("APE (m): mean over runs ± sd (ddof = 1)")
    ax = axes[0, n]
    quoted = [f for f in paper.APE_RANKING[::-1] if f in paper.TABLE7]
    ax.plot(range(len(quoted)), [paper.TABLE7[f][0] for f in quoted], **plots.PAPER_STYLE,
            label="paper's Table 7 APE (real lake data, geometry unknown)")
    ax.set_xticks(range(len(quoted)), quoted, rotation=70, fontsize=8)
    ax.set_xlim(-0.7, len(quoted) - 0.3)
    ax.set_title("paper, Table 7 (quoted)", fontsize=10)
    ax.grid(alpha=0.3, which="both", axis="y")
    handles, names_ = [], []
    for a in axes[0, [0, n]]:
        h, lab = a.get_legend_handles_labels()
        handles += h
        names_ += lab
    fig.legend(handles, names_, ncol=8, fontsize=7, loc="lower center", bbox_to_anchor=(0.5, 0.03), frameon=False)
    fig.suptitle("APE (eq. 46) per filter, range-noise case and leader geometry (tuned rows hollow)")
    return _save(fig, out / "cn_ape.png", stamp, plots, rect=(0, 0.1, 1, 1))


#: the name `abyssal reproduce` looks up (reproduce.py)
Config = CnConfig
