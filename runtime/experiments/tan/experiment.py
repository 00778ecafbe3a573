"""Seed 003's experiment: SIR with fixed and fuzzy sigma on several tracks of three maps, on the campaign harness.

One run (``run_one(config, seed) -> rows``) simulates, for every case map x track x current, one truth and runs
every filter on it; ``report``, ``document`` and ``figures`` are made from the tidy rows only (and from the maps,
for the terrain of each track). The paper's words (it prints figures, not an error table) are paper.py.

* Cases: the maps ``arctic`` (synthetic, smooth at the 500 m cell), ``arctic_cells`` (the same layout with
  relief down to the cell, as a survey grid has) and ``topobathy`` (matplotlib's real grid, resampled); the
  tracks of scenario.TRACKS on each (the paper's two printed postures, a drift-along-the-contours and a
  drift-across track, and on the synthetic maps (10, 40) km); the currents 0, 0.1 and 0.15 m/s (+x +y).
* Filters: SIR with fixed sigma 1..6 m, "fuzzy" (gradient in percent, rate in percent per km) and
  "fuzzy_per_cell" (the same rules with the inputs per 500 m map cell: a sensitivity row, the paper
  defines no units), and dead reckoning; 1000 particles at 1 Hz, systematic resampling when N_eff < N/2.
* Start (DECISION): the filter's particles are drawn around the true start posture, N(0, initial_std^2 =
  50^2 m^2) in x and y (the paper gives the initial posture, not its uncertainty).
* Lost track: position error above 1000 m (two map cells) at any time of the run.
* Draws: a case's truth and each filter's streams are keyed by the case's and the filter's names (``derive``),
  so a case run alone (``tracks=``, ``maps=``, ``sigmas=``) gives the numbers it has in the full campaign.
* Dead reckoning: the filter's own model at zero noise from the start posture, with the commanded
  inputs and the compass heading (no map, no current): its error is the current's drift.
* Baseline (not a method of the paper): "oracle_known_current", SIR with sigma = ``oracle_sigma``
  (1 m) that is given the true current as its model parameter -- a matched-model oracle (under a current
  only: with none it is the sigma = 1 m filter). It has no drift to absorb, so it shows what the terrain
  supports when nothing is unknown; it cannot tell how much of a failure is due to the map.
* Gate: none (``gate_probability=0``): the paper's SIR (Fig. 5) has none; with the engine's default gate a depth
  far outside the cloud's predicted depth would be left out.

Rows: one per run x case x filter x metric; metrics mean_error_m, final_error_m, max_error_m, lost (1 when the
error ever exceeded 1000 m), lost_at_s (in a lost run only: when it first did), mean_std_m (the filter's own
position spread sqrt(P_xx + P_yy), averaged over the run), outside_99 (the share of steps whose true position
lies outside the filter's own 99 % ellipse: 0.01 for a consistent filter, near 1 for a confidently wrong one),
step_us (median wall time of one step, a timing: never compared across runs) and, for the fuzzy filters,
mean_sigma_m and the inputs' saturation: gradient_clipped, rate_clipped, input_clipped (the share of steps whose
gradient, gradient rate, or either lies beyond the rule table's [-20, 20], where the fuzzy system clips it).
Figures of single tracks (paths, errors, spreads, fuzzy inputs) come from a separate figure run
(``figure_runs``): run 0's seeds of cases chosen from the table, recomputed in this process.
"""
from __future__ import annotations

import math
import time
import zlib
from collections import defaultdict
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ...extras import require
from ..campaign import derive, run_index
from ..tables import MEAN_SD, over_runs
from . import paper
from .scenario import CURRENTS, TRACKS, Truth, characterise, get_map, nominal_path, simulate

EXTRA_COLUMNS: tuple[str, ...] = ()
SIGMAS = (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
#: fuzzy variants: name -> (gradient_scale, rate_length_m): percent and %/km (default), or per 500 m cell
FUZZY_VARIANTS = {"fuzzy": (100.0, 1000.0), "fuzzy_per_cell": (500.0, 500.0)}
#: the matched-model oracle's row name (module docstring)
ORACLE = "oracle_known_current"
DEAD_RECKONING = "dead_reckoning"
#: chi-square quantile of 2 degrees of freedom at 0.99: -2 ln(0.01)
CHI2_2_99 = -2.0 * math.log(0.01)
#: the current the paper's main claims (Figs. 8-9) and the issue's test are about
MAIN_CURRENT = "0.1"
#: the tracks of the --quick version (on every map)
QUICK_TRACKS = ("drift_along", "drift_across")


@dataclass(frozen=True)
class TanConfig:
    """The experiment's set-up; defaults are the paper's (Table 2) or the documented decisions."""

    duration_s: float = 30000.0
    dt: float = 1.0
    speed: float = 0.5
    n_particles: int = 1000
    sigmas: tuple[float, ...] = SIGMAS
    fuzzy: tuple[str, ...] = tuple(FUZZY_VARIANTS)
    maps: tuple[str, ...] = ("arctic", "arctic_cells", "topobathy")
    #: track names to run (None: every track of each map, scenario.TRACKS)
    tracks: tuple[str, ...] | None = None
    currents: tuple[str, ...] = ("0", "0.1", "0.15")
    altimeter_sigma: float = 5.0
    initial_std: float = 50.0
    resample_threshold: float = 0.5
    autopilot_tau: float = 10.0
    lost_m: float = 1000.0
    map_seed: int = 0
    #: sigma of the known-current oracle (None: no oracle row)
    oracle_sigma: float | None = 1.0
    #: set by quick(): the figures and tables say so
    quick_run: bool = False

    def quick(self) -> "TanConfig":
        """3000 s runs (a tenth of the paper's 30 000 s) at 0.1 m/s only, on the drift-along and drift-across
        tracks of each of the three maps, one track figure per map: the whole pipeline (cases, tables, figures)
        as a smoke test, not evidence (the drift is ~420 m after 3000 s, so a track lost later is not seen)."""
        return replace(self, duration_s=3000.0, currents=(MAIN_CURRENT,), tracks=QUICK_TRACKS, quick_run=True)

    @property
    def n_steps(self) -> int:
        return int(round(self.duration_s / self.dt))

    def tracks_of(self, map_name: str) -> list[str]:
        return [t for t in TRACKS[map_name] if self.tracks is None or t in self.tracks]

    def cases(self) -> list[tuple[str, str, str]]:
        return [(m, t, c) for m in self.maps for t in self.tracks_of(m) for c in self.currents]

    def filters(self, current: str | None = None) -> list[str]:
        """The rows of one case (every row of the experiment when current is None)."""
        oracle = [ORACLE] if self.oracle_sigma is not None and (current is None or current != "0") else []
        return [sigma_name(s) for s in self.sigmas] + list(self.fuzzy) + oracle + [DEAD_RECKONING]

    def settings(self, runs: int, seed: int) -> str:
        return (f"abyssal reproduce tan{' --quick' if self.quick_run else ''}: {runs} run(s) per case, "
                f"{self.duration_s:g} s per run, N = {self.n_particles}, seed {seed}")


def sigma_name(sigma: float) -> str:
    return f"sigma_{sigma:g}"


def case_name(map_name: str, track: str, current: str) -> str:
    return f"{map_name}/{track}/current_{current}"


def parse_case(case: str) -> tuple[str, str, str]:
    map_name, track, current = case.split("/")
    return map_name, track, current.removeprefix("current_")


@dataclass
class FilterRun:
    """One filter on one truth: the estimates, their errors, the filter's own covariance, what the fuzzy logic saw."""

    estimates: np.ndarray      # (T, 2) positions after each step
    cov: np.ndarray | None     # (T, 3): P_xx, P_xy, P_yy after each step (None: dead reckoning claims nothing)
    step_seconds: np.ndarray   # (T,)
    sigma: np.ndarray | None = None
    gradient: np.ndarray | None = None
    gradient_rate: np.ndarray | None = None
    errors: np.ndarray = field(default=None)
    error_xy: np.ndarray = field(default=None)

    @property
    def std(self) -> np.ndarray | None:
        return None if self.cov is None else np.sqrt(np.maximum(self.cov[:, 0] + self.cov[:, 2], 0.0))

    def outside_99(self) -> float:
        """Share of steps whose true position lies outside the filter's 99 % ellipse (e^T P^-1 e > chi2_2(0.99))."""
        a, b, d = self.cov.T
        ex, ey = self.error_xy.T
        det = a * d - b * b
        with np.errstate(divide="ignore", invalid="ignore"):
            nees = np.where(det > 0, (d * ex * ex - 2 * b * ex * ey + a * ey * ey) / det, np.inf)
        return float(np.mean(nees > CHI2_2_99))

    def metrics(self, lost_m: float, dt: float) -> dict[str, float]:
        e = self.errors
        out = {"mean_error_m": float(e.mean()), "final_error_m": float(e[-1]), "max_error_m": float(e.max()),
               "lost": float(e.max() > lost_m), "step_us": float(1e6 * np.median(self.step_seconds))}
        if e.max() > lost_m:
            out["lost_at_s"] = float((np.argmax(e > lost_m) + 1) * dt)
        if self.cov is not None:
            out["mean_std_m"] = float(self.std.mean())
            out["outside_99"] = self.outside_99()
        if self.sigma is not None:
            out["mean_sigma_m"] = float(self.sigma.mean())
            out.update(input_saturation(self.gradient, self.gradient_rate))
        return out


def input_saturation(gradient: np.ndarray, gradient_rate: np.ndarray) -> dict[str, float]:
    """The shares of steps whose fuzzy inputs lie beyond the rule table's domain (Table 2: [-20, 20]), where the
    fuzzy system clips them: the gradient, the gradient rate, and either."""
    from abyssal.symbolic.fuzzy import INPUT_DOMAIN

    low, high = INPUT_DOMAIN
    g = (gradient < low) | (gradient > high)
    r = (gradient_rate < low) | (gradient_rate > high)
    return {"gradient_clipped": float(g.mean()), "rate_clipped": float(r.mean()), "input_clipped": float((g | r).mean())}


def _finish(run: FilterRun, truth: Truth) -> FilterRun:
    run.error_xy = run.estimates - truth.states[1:1 + run.estimates.shape[0], :2]
    run.errors = np.hypot(run.error_xy[:, 0], run.error_xy[:, 1])
    return run


def run_filter(bundle, terrain, config: TanConfig, truth: Truth, sigma, rng: np.random.Generator,
               fuzzy_units: tuple[float, float] = FUZZY_VARIANTS["fuzzy"], knows_current: bool = False,
               stop_beyond_m: float | None = None) -> FilterRun:
    """One filter over one truth. stop_beyond_m: end the run at the first step whose position error exceeds it (the
    track survey's early stop: the run is lost then); the FilterRun then holds the steps up to that one."""
    from ...filters.particle.terrain import TerrainParticleFilter
    from ...resampling import ResamplingPolicy

    T, dt = config.n_steps, config.dt
    start = truth.states[0]
    P0 = np.diag([config.initial_std ** 2, config.initial_std ** 2, 0.0])
    filt = TerrainParticleFilter(bundle, start, P0, sigma, config.altimeter_sigma, config.n_particles, rng,
                                 terrain=terrain, policy=ResamplingPolicy("systematic", config.resample_threshold),
                                 gradient_scale=fuzzy_units[0], rate_length_m=fuzzy_units[1],
                                 gate_probability=0.0)  # the paper's SIR (Fig. 5) has no innovation gate
    est, cov, times = np.empty((T, 2)), np.empty((T, 3)), np.empty(T)
    fuzzy = sigma == "fuzzy"
    sig = np.empty(T) if fuzzy else None
    grad = np.empty(T) if fuzzy else None
    rate = np.empty(T) if fuzzy else None
    U, Z = truth.inputs, truth.measurements
    p = np.array(truth.current, dtype=np.float64) if knows_current else None
    clock = time.perf_counter
    stop = math.inf if stop_beyond_m is None else stop_beyond_m
    true_xy = truth.states[1:, :2]
    done = T
    for k in range(T):
        t0 = clock()
        filt.step(U[k], dt, Z[k], p)
        times[k] = clock() - t0
        x, P = filt.x, filt.P
        est[k] = x[:2]
        cov[k] = P[0, 0], P[0, 1], P[1, 1]
        if fuzzy:
            sig[k], grad[k], rate[k] = filt.sigma, filt.gradient, filt.gradient_rate
        if stop < math.inf and math.hypot(x[0] - true_xy[k, 0], x[1] - true_xy[k, 1]) > stop:
            done = k + 1
            break
    if done < T:
        est, cov, times = est[:done], cov[:done], times[:done]
        sig, grad, rate = (None if a is None else a[:done] for a in (sig, grad, rate))
    return _finish(FilterRun(est, cov, times, sig, grad, rate), truth)


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
    return _finish(FilterRun(X[:, :2], None, np.full(T, elapsed / T)), truth)


def named_stream(seed: np.random.SeedSequence, case: str, filter_name: str | None = None) -> np.random.Generator:
    """The generator of a case's truth (filter_name None) or of one filter on it, keyed by the names alone."""
    key = zlib.crc32(case.encode())
    keys = (key, 0) if filter_name is None else (key, 1, zlib.crc32(filter_name.encode()))
    return np.random.default_rng(derive(seed, *keys))


def run_case(config: TanConfig, case: tuple[str, str, str], seed: np.random.SeedSequence):
    """(truth, {filter name: FilterRun}) of one case (map, track, current) of one run. The draws are keyed by the
    case's and the filter's names, so a case's numbers do not depend on which other cases or filters are configured."""
    from abyssal.generated import load

    map_name, track, current = case
    bundle = load("tan3dof")
    terrain = get_map(map_name, config.map_seed)
    truth = simulate(bundle, terrain, config, TRACKS[map_name][track].start, CURRENTS[current],
                     named_stream(seed, case_name(*case)))

    def stream(name: str) -> np.random.Generator:
        return named_stream(seed, case_name(*case), name)

    runs = {}
    specs = [(sigma_name(s), s, FUZZY_VARIANTS["fuzzy"]) for s in config.sigmas]
    specs += [(name, "fuzzy", FUZZY_VARIANTS[name]) for name in config.fuzzy]
    for name, sigma, units in specs:
        runs[name] = run_filter(bundle, terrain, config, truth, sigma, stream(name), units)
    if ORACLE in config.filters(current):
        runs[ORACLE] = run_filter(bundle, terrain, config, truth, config.oracle_sigma, stream(ORACLE), knows_current=True)
    runs[DEAD_RECKONING] = dead_reckoning(bundle, config, truth)
    return truth, runs


def run_one(config: TanConfig, seed: np.random.SeedSequence) -> list[dict]:
    """Every case and filter of one Monte-Carlo run, as tidy rows (the campaign harness's shape)."""
    run = run_index(seed)
    rows = []
    for map_name, track, current in config.cases():
        _, runs = run_case(config, (map_name, track, current), seed)
        case = case_name(map_name, track, current)
        for name, result in runs.items():
            for metric, value in result.metrics(config.lost_m, config.dt).items():
                rows.append({"run": run, "case": case, "filter": name, "metric": metric, "value": value})
    return rows


# ------------------------------------------------------------------------------------- tables
def summary(rows) -> dict:
    """{case: {filter: {metric: OverRuns over the runs}}} (timings included: the report prints them apart)."""
    values = defaultdict(list)
    for r in rows:
        values[(r["case"], r["filter"], r["metric"])].append(r["value"])
    out: dict = defaultdict(dict)
    for (case, name, metric), v in sorted(values.items()):
        out[case].setdefault(name, {})[metric] = over_runs(v)
    return dict(out)


def track_terrain(config: TanConfig) -> dict:
    """{map: {track: {current: TrackTerrain}}} of the configured cases (scenario.characterise; no filter)."""
    out: dict = {}
    for m, t, c in config.cases():
        terrain = get_map(m, config.map_seed)
        out.setdefault(m, {}).setdefault(t, {})[c] = characterise(
            terrain, TRACKS[m][t].start, CURRENTS[c], config.duration_s, config.speed,
            altimeter_sigma=config.altimeter_sigma)
    return out


def lost_count(entry) -> tuple[int, int]:
    """(runs lost, runs) of one case's filter entry."""
    lost = entry["lost"]
    return int(round(lost.mean * lost.n)), lost.n


def verdict(s: dict, config: TanConfig, current: str = MAIN_CURRENT) -> dict:
    """Per map: {"tracking": {track: [fixed sigmas that kept every run within lost_m]}, "none": [tracks where no
    fixed sigma did]} at ``current``."""
    out = {}
    fixed = [sigma_name(x) for x in config.sigmas]
    for m in config.maps:
        tracking, none = {}, []
        for t in config.tracks_of(m):
            block = s.get(case_name(m, t, current))
            if not block:
                continue
            good = [f for f in fixed if f in block and lost_count(block[f])[0] == 0]
            if good:
                tracking[t] = good
            else:
                none.append(t)
        out[m] = {"tracking": tracking, "none": none}
    return out


def _runs_of(s: dict) -> int:
    return max((e["mean_error_m"].n for block in s.values() for e in block.values()), default=0)


def report(rows, config: TanConfig) -> str:
    s = summary(rows)
    runs = _runs_of(s)
    terrain = track_terrain(config)
    lines = [f"Terrain-aided navigation (seed 003){' -- QUICK run (smoke test, not evidence)' if config.quick_run else ''}: "
             f"{config.n_steps} s per run at 1 Hz, N = {config.n_particles}, {runs} run(s) per case",
             f"error = the per-run time-mean of |estimated - true position| (m); tables give the {MEAN_SD};",
             f"lost = runs whose error ever exceeded {config.lost_m:g} m (k/n); spread = the filter's own sqrt(P_xx + P_yy) "
             "(m), per-run time-mean, mean ± sample sd over runs;",
             "out99 = share of steps with the truth outside the filter's own 99 % ellipse (0.01 if consistent; "
             "near 1: confidently wrong), mean over runs.", ""]
    # the tracks and their terrain (no filter involved)
    lines.append("TRACKS (terrain along the noise-free path under the current shown, the other currents' in the JSON; drift = the "
                 "current's direction, +x +y; heading 0 = +x): "
                 "slope = rms |grad depth|; angle = drift vs depth contours (0 along, 90 across); weakest = slope in "
                 "the least-informative direction per 2 km (median); relief = rms second difference of depth every "
                 "500 m; flat = share with slope < 10 m/km")
    header = ["map", "track", "start, heading", "current", "slope m/km", "angle deg", "weakest m/km", "relief m", "flat"]
    body = []
    for m, tracks in terrain.items():
        for t, by_current in tracks.items():
            c = MAIN_CURRENT if MAIN_CURRENT in by_current else next(iter(by_current))
            tt = by_current[c]
            body.append([m, t, TRACKS[m][t].label(), c, f"{tt.slope_m_per_km:.0f}", f"{tt.drift_contour_angle_deg:.0f}",
                         f"{tt.weakest_slope_m_per_km:.1f}", f"{tt.cell_relief_m:.1f}", f"{tt.flat_fraction:.2f}"])
    lines += aligned(header, body, left=3) + [""]
    # overview: lost runs per track and filter
    for current in config.currents:
        names = [n for n in config.filters(current)]
        lines.append(f"LOST RUNS (error > {config.lost_m:g} m at any time), current {current} m/s: k/n per track and filter")
        header = ["map/track", *(_short(n) for n in names)]
        body = []
        for m in config.maps:
            for t in config.tracks_of(m):
                block = s.get(case_name(m, t, current), {})
                body.append([f"{m}/{t}", *(_lost_cell(block.get(n)) for n in names)])
        lines += aligned(header, body) + [""]
    # the statement the campaign is asked to make
    if MAIN_CURRENT in config.currents:
        lines.append(f"AT {MAIN_CURRENT} m/s, fixed sigma that kept every run within {config.lost_m:g} m:")
        for m, v in verdict(s, config).items():
            good = "; ".join(f"{t}: {', '.join(_short(f) for f in fs)}" for t, fs in v["tracking"].items()) or "no track"
            lines.append(f"  {m}: {good}. No fixed sigma on: {', '.join(v['none']) or '-'}")
        if any("survey_pick" in config.tracks_of(m) for m in config.maps):
            lines.append("  survey_pick: the track survey's pick, chosen on the survey's own streams (`abyssal reproduce "
                         "tan-survey`, which also counts the tracks of each map where a fixed sigma held); here it is "
                         "rerun on this campaign's streams.")
        lines.append("")
    # per case
    header = ["filter", "error", "final", "max(med)", "lost", "spread", "out99", "sigma"]
    for case, block in s.items():
        body = []
        for name in config.filters(parse_case(case)[2]):
            e = block.get(name)
            if e is None:
                continue
            body.append([name, e["mean_error_m"].cell(".0f"), f"{e['final_error_m'].mean:.0f}", f"{e['max_error_m'].median:.0f}",
                         _lost_cell(e), e["mean_std_m"].cell(".0f") if "mean_std_m" in e else "", _mean_cell(e, "outside_99", ".2f"),
                         _mean_cell(e, "mean_sigma_m", ".2f")])
        lines += [f"== {case}", *aligned(header, body), ""]
    lines.append("final = mean over runs of the error at the end; max(med) = median over runs of the largest error.")
    lines += ["", *saturation_table(s, config)]
    if config.oracle_sigma is not None:
        lines.append(f"{ORACLE}: SIR with sigma = {config.oracle_sigma:g} m given the true current -- a matched-model "
                     "oracle, not a method of the paper (run under a current only).")
    lines.append("THE PAPER (quoted; it prints figures, not an error table, for its own IBCAO track): " + paper.SUMMARY)
    lines += [f"  {c} {f}: {text}" for (c, f), text in paper.CLAIMS.items()]
    step = [e["step_us"].median for block in s.values() for n, e in block.items() if n.startswith("sigma_") and "step_us" in e]
    if step:
        lines.append(f"Step time (median over cases of the per-run median, sigma filters): {np.median(step):.1f} us on this "
                     f"machine; THE PAPER: {paper.PAPER_STEP_MS} ms per step in MATLAB (2.6 GHz dual core) -- a "
                     "different machine and language.")
    return "\n".join(lines)


def saturation_table(s: dict, config: TanConfig) -> list[str]:
    """The fuzzy inputs beyond the rule table's domain (clipped there): per case and fuzzy variant the share of steps
    with the gradient, the gradient rate, or either outside [-20, 20], mean over runs (min-max over runs)."""
    header = ["case", "variant", "gradient", "rate", "either"]
    body = []
    for case, block in s.items():
        for name in config.fuzzy:
            e = block.get(name)
            if e and "input_clipped" in e:
                body.append([case, name, *(f"{e[m].mean:.2f} ({e[m].low:.2f}-{e[m].high:.2f})"
                                           for m in ("gradient_clipped", "rate_clipped", "input_clipped"))])
    if not body:
        return []
    return ["FUZZY INPUTS BEYOND [-20, 20] (clipped by the fuzzy system): share of steps, mean over runs (min-max)",
            *aligned(header, body, left=2)]


def aligned(header: list[str], rows: list[list[str]], left: int = 1) -> list[str]:
    """Text table lines: the first ``left`` columns left-aligned, the rest right-aligned, two spaces apart."""
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]

    def line(cells):
        return "  ".join(c.ljust(w) if i < left else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths))).rstrip()

    return [line(header), *(line(r) for r in rows)]


def _short(name: str) -> str:
    return {ORACLE: "oracle", DEAD_RECKONING: "DR", "fuzzy_per_cell": "fuzzy/cell"}.get(name, name.replace("sigma_", "s"))


def _lost_cell(entry) -> str:
    if not entry or "lost" not in entry:
        return "-"
    k, n = lost_count(entry)
    return f"{k}/{n}"


def _mean_cell(entry, metric: str, spec: str) -> str:
    return f"{entry[metric].mean:{spec}}" if metric in entry and entry[metric].n else ""


def json_document(rows, config: TanConfig) -> dict:
    """Per case, per filter, per metric: mean, sd (ddof = 1), median and n over runs."""
    return {case: {name: {metric: dict(v.__dict__) for metric, v in entry.items()} for name, entry in block.items()}
            for case, block in summary(rows).items()}


def document(rows, config: TanConfig, prepared=None) -> dict:
    """The JSON summary's entries: the tracks with their terrain, the cases, and the statement at 0.1 m/s."""
    s = summary(rows)
    tracks = {m: {t: {"start_km": [TRACKS[m][t].x / 1e3, TRACKS[m][t].y / 1e3],
                      "heading_deg": math.degrees(TRACKS[m][t].heading), "why": TRACKS[m][t].why,
                      "terrain": {c: tt.as_dict() for c, tt in by_current.items()}}
                  for t, by_current in tracks.items()} for m, tracks in track_terrain(config).items()}
    doc = {"tracks": tracks, "cases": json_document(rows, config)}
    if MAIN_CURRENT in config.currents:
        doc["fixed_sigma_within_lost_m_at_0.1"] = verdict(s, config)
    return doc


# ------------------------------------------------------------------------------------- docs tables
def _error_cell(entry, spec: str = ".0f") -> str:
    """"k/n · mean ± sd" of one case's filter: runs lost, and the per-run time-mean error in m over every run."""
    if not entry or "lost" not in entry:
        return "-"
    k, n = lost_count(entry)
    return f"{k}/{n} · {entry['mean_error_m'].cell(spec)}"


def markdown(rows, config: TanConfig, document: dict | None = None) -> dict[str, str]:
    """The tables of docs/experiments/tan.md (`abyssal publish tan`, publish.py), from the rows (the tracks' terrain
    from the JSON document when given, else computed from the maps)."""
    from ..publish import markdown_table

    s = summary(rows)
    out = {}
    # the tracks and their terrain (no filter)
    terrain = (document or {}).get("tracks")
    header = ["map", "track", "start, heading", "slope m/km", "drift vs contours deg", "weakest slope m/km",
              "cell relief m", "flat share"]
    body = []
    for m in config.maps:
        for t in config.tracks_of(m):
            if terrain and t in terrain.get(m, {}):
                by_current = terrain[m][t]["terrain"]
                tt = by_current.get(MAIN_CURRENT) or next(iter(by_current.values()))
            else:
                tt = characterise(get_map(m, config.map_seed), TRACKS[m][t].start, CURRENTS[MAIN_CURRENT],
                                  config.duration_s, config.speed, altimeter_sigma=config.altimeter_sigma).as_dict()
            body.append([m, t, TRACKS[m][t].label(), f"{tt['slope_m_per_km']:.0f}", f"{tt['drift_contour_angle_deg']:.0f}",
                         f"{tt['weakest_slope_m_per_km']:.1f}", f"{tt['cell_relief_m']:.1f}", f"{tt['flat_fraction']:.2f}"])
    out["tracks"] = markdown_table(header, body, align="lllrrrrr")
    # lost runs and errors per track and filter, per current
    for current in config.currents:
        names = config.filters(current)
        header = ["map/track", *(DISPLAY.get(n, n) for n in names)]
        body = [[f"{m}/{t}", *(_error_cell(s.get(case_name(m, t, current), {}).get(n)) for n in names)]
                for m in config.maps for t in config.tracks_of(m) if case_name(m, t, current) in s]
        out[f"lost-{current}"] = markdown_table(header, body)
    # the statement at 0.1 m/s
    if MAIN_CURRENT in config.currents:
        body = []
        for m, v in verdict(s, config).items():
            good = "; ".join(f"{t}: sigma = {', '.join(f.removeprefix('sigma_') for f in fs)} m"
                             for t, fs in v["tracking"].items()) or "no track"
            body.append([m, good, ", ".join(v["none"]) or "-"])
        out["verdict"] = markdown_table(["map", "tracks where a fixed sigma kept every run (the sigmas)",
                                         "tracks where none did"], body, align="lll")
        # consistency where a sigma kept every run: the filter's own spread and the truth outside its 99 % ellipse
        body = []
        for m in config.maps:
            for t in config.tracks_of(m):
                block = s.get(case_name(m, t, MAIN_CURRENT), {})
                for n in [sigma_name(x) for x in config.sigmas] + list(config.fuzzy):
                    e = block.get(n)
                    if e and lost_count(e)[0] == 0:
                        body.append([f"{m}/{t}", DISPLAY.get(n, n), e["mean_error_m"].cell(".0f"),
                                     e["mean_std_m"].cell(".0f"), f"{e['outside_99'].mean:.2f}"])
        out["kept-0.1"] = markdown_table(["map/track", "filter", "error m", "own spread m", "truth outside its 99 % "
                                          "ellipse (share of steps)"], body, align="llrrr")
    # the fuzzy inputs' saturation: per map, variant and current, over the tracks
    body = []
    for m in config.maps:
        for variant in config.fuzzy:
            for current in config.currents:
                shares = {metric: [s[case_name(m, t, current)][variant][metric].mean for t in config.tracks_of(m)
                                   if variant in s.get(case_name(m, t, current), {})
                                   and metric in s[case_name(m, t, current)][variant]]
                          for metric in ("gradient_clipped", "rate_clipped", "input_clipped")}
                if shares["input_clipped"]:
                    body.append([m, DISPLAY.get(variant, variant), f"{current} m/s", str(len(shares["input_clipped"])),
                                 *(f"{np.median(v):.2f} ({min(v):.2f}-{max(v):.2f})" for v in shares.values())])
    out["saturation"] = markdown_table(["map", "fuzzy variant", "current", "tracks", "gradient beyond ±20",
                                        "gradient rate beyond ±20", "either"], body, align="lllrrrr")
    step = [e["step_us"].median for block in s.values() for n, e in block.items() if n.startswith("sigma_") and "step_us" in e]
    if step:
        out["timing"] = markdown_table(["statistic", "value"], [
            ["step time of the fixed-sigma filters, median over cases of the per-run median (this campaign's machine and "
             "load)", f"{np.median(step):.1f} µs"], ["the paper: MATLAB, 2.6 GHz dual core (quoted)", f"{paper.PAPER_STEP_MS} ms"]],
            align="lr")
    return out


# ------------------------------------------------------------------------------------- figures
#: display names (the shared look: plots.filter_style with one ordered tuple in every tan figure)
DISPLAY = {**{sigma_name(s): f"sigma = {s:g} m" for s in SIGMAS}, "fuzzy": "fuzzy",
           "fuzzy_per_cell": "fuzzy (per cell)", ORACLE: "oracle (known current)", DEAD_RECKONING: "dead reckoning"}
#: the methods with a fixed look first, so the sigma rows never take one of their colours (see plots.filter_style)
ORDERED = ("fuzzy", "fuzzy (per cell)", "oracle (known current)", "dead reckoning",
           *(f"sigma = {s:g} m" for s in SIGMAS))
#: one colour and marker per track in the figures whose lines are tracks (tracks are not filters)
TRACK_STYLES = {"paper_20_20": ("#0072B2", "o"), "paper_60_10": ("#999999", "s"), "start_10_40": ("#009E73", "^"),
                "drift_along": ("#D55E00", "v"), "drift_across": ("#CC79A7", "D"), "survey_pick": ("#E69F00", "P")}
MAP_MARKERS = {"arctic": "o", "arctic_cells": "s", "topobathy": "^"}
#: where a track's name sits from its start in tan_tracks.png (points), where the default (6, 6) would overlap another
LABEL_OFFSETS = {"survey_pick": (-20, -16), "drift_along": (8, -4)}


def style(name: str) -> dict:
    from ...plots import filter_style

    return filter_style(DISPLAY.get(name, name), ORDERED)


def figure_cases(rows, config: TanConfig) -> list[tuple[str, str, str]]:
    """The cases drawn track by track (run 0): per map at 0.1 m/s the track where the best fixed sigma lost the
    fewest runs and the one where it lost the most, per map the best track at 0.15 m/s, and the paper's flat
    start on the first synthetic map at 0.1 m/s (Fig. 15). A quick run draws the best track of each map only."""
    s = summary(rows)
    fixed = [sigma_name(x) for x in config.sigmas]

    def best_lost(case):
        block = s.get(case, {})
        scores = [(lost_count(block[f])[0], block[f]["mean_error_m"].mean) for f in fixed if f in block]
        return min(scores) if scores else None

    chosen = []
    for current in (MAIN_CURRENT, "0.15"):
        if current not in config.currents:
            continue
        for m in config.maps:
            scored = [(best_lost(case_name(m, t, current)), t) for t in config.tracks_of(m)]
            scored = [(score, t) for score, t in scored if score is not None and t != "paper_60_10"]
            if not scored:
                continue
            chosen.append((m, min(scored)[1], current))
            if current == MAIN_CURRENT and not config.quick_run:
                chosen.append((m, max(scored)[1], current))
    flat = [(m, "paper_60_10", MAIN_CURRENT) for m in config.maps if m.startswith("arctic")][:0 if config.quick_run else 1]
    chosen += [c for c in flat if c in config.cases()]
    return list(dict.fromkeys(chosen))


def figure_runs(config: TanConfig, cases, seed: int = 0):
    """{case: (truth, runs)} with run 0's seed (the same numbers as the campaign's run 0)."""
    seed0 = np.random.SeedSequence(seed).spawn(1)[0]
    all_cases = config.cases()
    return {key: run_case(config, key, seed0) for key in cases if key in all_cases}


def figures(rows, out: Path, config: TanConfig, seed: int = 0, prepared=None, settings: str | None = None) -> list[Path]:
    """The tracks over the maps; lost runs per track and filter; error and spread vs sigma (Figs. 7, 14); the
    terrain measures vs the lost runs; run 0's paths, errors and spreads over time (Figs. 8-11, 15); the fuzzy
    inputs (Figs. 12-13). Every figure is stamped with the run's settings."""
    require("matplotlib", "the experiment figures")
    from ...plots import plt

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    s = summary(rows)
    settings = settings or config.settings(_runs_of(s), seed)
    written = []

    def save(fig, name):
        from ...plots import save_figure

        written.append(save_figure(fig, out / name, settings))

    terrain = track_terrain(config)
    save(_tracks_figure(plt, config), "tan_tracks.png")
    for current in config.currents:
        save(_lost_figure(plt, s, config, current), f"tan_lost_current_{current}.png")
    for m in config.maps:
        save(_sigma_figure(plt, s, config, m), f"tan_{m}_error_spread_vs_sigma.png")
    if MAIN_CURRENT in config.currents:
        save(_terrain_vs_lost_figure(plt, s, config, terrain), "tan_terrain_vs_lost.png")
    inputs_drawn = set()
    for (m, t, c), (truth, runs) in figure_runs(config, figure_cases(rows, config), seed).items():
        save(_track_run_figure(plt, config, m, t, c, truth, runs), f"tan_{m}_{t}_current_{c}.png")
        fz = runs.get("fuzzy")
        # the first (best) track of each map; one map in a quick run
        if fz is not None and fz.sigma is not None and m not in inputs_drawn and not (config.quick_run and inputs_drawn):
            inputs_drawn.add(m)
            save(_fuzzy_inputs_figure(plt, config, m, t, c, truth, fz), f"tan_{m}_{t}_current_{c}_fuzzy_inputs.png")
    return written


def depth_image(ax, terrain, window_km=None, alpha: float = 1.0):
    """The depth grid (or its part inside window_km = (x0, x1, y0, y1)) as an image with contours at a round
    interval giving about 20 levels; returns (image, contour interval in m)."""
    xg, yg = terrain.node_coordinates()
    cols, rows = slice(None), slice(None)
    if window_km is not None:
        x0, x1, y0, y1 = (1e3 * v for v in window_km)
        cols = slice(max(0, np.searchsorted(xg, x0) - 1), np.searchsorted(xg, x1) + 1)
        rows = slice(max(0, np.searchsorted(yg, y0) - 1), np.searchsorted(yg, y1) + 1)
    xs, ys, depth = xg[cols] / 1e3, yg[rows] / 1e3, terrain.depth[rows, cols]
    image = ax.imshow(depth, origin="lower", cmap="Blues", extent=(xs[0], xs[-1], ys[0], ys[-1]), aspect="equal",
                      interpolation="bilinear", alpha=alpha)
    span = float(np.ptp(depth))
    interval = next((step for step in (5, 10, 20, 50, 100, 200, 500) if span / step <= 25), 1000)
    if span > 0:
        levels = np.arange(np.floor(depth.min() / interval) * interval, depth.max() + interval, interval)
        ax.contour(xs, ys, depth, levels=levels, colors="k", linewidths=0.3, alpha=0.5)
    return image, interval


def _tracks_figure(plt, config: TanConfig):
    from matplotlib import patheffects

    fig, axes = plt.subplots(len(config.maps), 1, figsize=(12, 4.1 * len(config.maps)), squeeze=False)
    for ax, m in zip(axes[:, 0], config.maps):
        terrain = get_map(m, config.map_seed)
        image, interval = depth_image(ax, terrain)
        fig.colorbar(image, ax=ax, label="depth (m)", shrink=0.85)
        for t in config.tracks_of(m):
            tr = TRACKS[m][t]
            colour, marker = TRACK_STYLES.get(t, ("black", "o"))
            for current, ls in (("0.1", "-"), ("0.15", ":")):
                x, y = nominal_path(tr.start, CURRENTS[current], config.duration_s, config.speed)
                ax.plot(x / 1e3, y / 1e3, color=colour, lw=2.0, ls=ls, label=f"{t}" if current == "0.1" else None)
            ax.plot(tr.x / 1e3, tr.y / 1e3, marker=marker, color=colour, ms=8, mec="white")
            ax.annotate(t, (tr.x / 1e3, tr.y / 1e3), textcoords="offset points", xytext=LABEL_OFFSETS.get(t, (6, 6)),
                        fontsize=8, color=colour,
                        fontweight="bold", path_effects=[patheffects.withStroke(linewidth=2.5, foreground="white")])
        ax.annotate("", xy=(133, 8), xytext=(127, 2), arrowprops={"arrowstyle": "->", "lw": 2, "color": "black"})
        ax.text(126, 9, "current\n(+x +y)", fontsize=8)
        ax.set(xlabel="x (km)", ylabel="y (km)", title=f"{m}: tracks (marker = start; solid: path at 0.1 m/s, dotted: "
               f"0.15 m/s, {config.duration_s:g} s; contours every {interval} m)")
        ax.legend(fontsize=7, loc="upper right", ncol=2)
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    return fig


def _lost_figure(plt, s, config: TanConfig, current: str):
    """Per map, runs lost and mean error per track and filter; above them the paper's words for its own track
    (Figs. 8-11), where it has any at this current."""
    from ...plots import PAPER_STYLE

    names = config.filters(current)
    verdicts = {n: paper.VERDICTS[(f"current_{current}", n)] for n in names if (f"current_{current}", n) in paper.VERDICTS}
    extra = 1 if verdicts else 0
    fig, axes = plt.subplots(len(config.maps), 1, squeeze=False,
                             figsize=(12, 1.0 + 0.55 * sum(len(config.tracks_of(m)) + extra + 1.6 for m in config.maps)))
    for ax, m in zip(axes[:, 0], config.maps):
        tracks = config.tracks_of(m)
        grid = np.full((len(tracks) + extra, len(names)), np.nan)
        for i, t in enumerate(tracks, start=extra):
            block = s.get(case_name(m, t, current), {})
            for j, n in enumerate(names):
                if n in block:
                    k, total = lost_count(block[n])
                    grid[i, j] = k / total
                    err = block[n]["mean_error_m"].mean
                    ax.text(j, i, f"{k}/{total}\n{err / 1e3:.2f} km" if err >= 1000 else f"{k}/{total}\n{err:.0f} m",
                            ha="center", va="center", fontsize=7, color="white" if k / total > 0.6 else "black")
        image = ax.imshow(grid, cmap="Reds", vmin=0, vmax=1, aspect="auto")
        labels = list(tracks)
        if extra:
            for j, n in enumerate(names):
                if n in verdicts:
                    ax.text(j, 0, verdicts[n], ha="center", va="center", fontsize=7, fontstyle="italic",
                            color=PAPER_STYLE["color"])
            ax.axhline(0.5, color="black", lw=1.2)
            labels = ["THE PAPER (its track)", *labels]
        ax.set_xticks(range(len(names)), [DISPLAY.get(n, n) for n in names], rotation=20, fontsize=8, ha="right")
        ax.set_yticks(range(len(labels)), labels, fontsize=8)
        ax.set_title(f"{m}, current {current} m/s: runs lost (error > {config.lost_m:g} m) k/n and mean error", fontsize=10)
        fig.colorbar(image, ax=ax, label="share of runs lost", shrink=0.9)
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    return fig


def _sigma_figure(plt, s, config: TanConfig, m: str):
    """Figs. 7 and 14: mean error and spread vs the fixed sigma, one line per track, one column per current; the
    fuzzy filter at its mean sigma."""
    from ...plots import plain_log_labels

    currents = config.currents
    fig, axes = plt.subplots(2, len(currents), figsize=(max(7.0, 4.6 * len(currents)), 7.5), squeeze=False, sharex=True)
    fixed = [sigma_name(x) for x in config.sigmas]
    fz = style("fuzzy")
    for j, current in enumerate(currents):
        for t in config.tracks_of(m):
            block = s.get(case_name(m, t, current))
            if not block:
                continue
            colour, marker = TRACK_STYLES.get(t, ("black", "o"))
            present = [f for f in fixed if f in block]
            xs = [float(f.split("_")[1]) for f in present]
            for i, metric in enumerate(("mean_error_m", "mean_std_m")):
                axes[i, j].plot(xs, [block[f][metric].mean for f in present], color=colour, marker=marker, label=t)
                if "fuzzy" in block and metric in block["fuzzy"]:
                    axes[i, j].plot(block["fuzzy"]["mean_sigma_m"].mean, block["fuzzy"][metric].mean, marker=fz["marker"],
                                    ms=9, mfc="none", mec=colour, mew=1.8, ls="none")
        axes[0, j].axhline(config.lost_m, color="black", lw=0.8, ls=":")
        axes[0, j].set_title(f"{m}, current {current} m/s", fontsize=10)
        for i, label in enumerate(("mean position error (m)", "filter's own spread (m)")):
            axes[i, j].set(yscale="log", ylabel=label if j == 0 else None)
            plain_log_labels(axes[i, j])
            axes[i, j].grid(alpha=0.3, which="both")
        axes[1, j].set_xlabel("fixed process-noise sigma (m per step)")
    axes[0, 0].plot([], [], marker=fz["marker"], ms=9, mfc="none", mec="black", ls="none", label="fuzzy, at its mean sigma")
    axes[0, 0].plot([], [], color="black", lw=0.8, ls=":", label=f"{config.lost_m:g} m")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(f"{m}: error and spread vs fixed sigma, means over runs (cf. Figs. 7, 14)")
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    return fig


def _terrain_vs_lost_figure(plt, s, config: TanConfig, terrain):
    """The runs lost by the best fixed sigma at 0.1 m/s vs each filter-independent terrain measure of the track."""
    measures = (("slope_m_per_km", "rms slope (m/km)"), ("drift_contour_angle_deg", "drift vs contours (deg; 0 = along)"),
                ("weakest_slope_m_per_km", "weakest-direction slope (m/km)"), ("cell_relief_m", "cell-scale relief (m)"))
    fig, axes = plt.subplots(1, len(measures), figsize=(4.2 * len(measures), 4.2), sharey=True)
    fixed = [sigma_name(x) for x in config.sigmas]
    for m in config.maps:
        for t in config.tracks_of(m):
            block = s.get(case_name(m, t, MAIN_CURRENT))
            if not block:
                continue
            best = min((lost_count(block[f])[0] / lost_count(block[f])[1], f) for f in fixed if f in block)
            tt = terrain[m][t][MAIN_CURRENT]
            colour, _ = TRACK_STYLES.get(t, ("black", "o"))
            for ax, (key, _) in zip(axes, measures):
                ax.plot(getattr(tt, key), best[0], marker=MAP_MARKERS.get(m, "o"), color=colour, ms=9, ls="none", alpha=0.85)
    for ax, (_, label) in zip(axes, measures):
        ax.set(xlabel=label, ylim=(-0.05, 1.05))
        ax.grid(alpha=0.3)
    axes[0].set_ylabel(f"share of runs lost by the best fixed sigma ({MAIN_CURRENT} m/s)")
    handles = [plt.Line2D([], [], marker=mk, color="black", ls="none", label=m) for m, mk in MAP_MARKERS.items() if m in config.maps]
    handles += [plt.Line2D([], [], marker="o", color=c, ls="none", label=t) for t, (c, _) in TRACK_STYLES.items()]
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=8, frameon=False, bbox_to_anchor=(0.5, 0.03))
    fig.suptitle("terrain of each track (no filter involved) vs runs lost")
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    return fig


def _track_run_figure(plt, config: TanConfig, m, t, c, truth, runs):
    """Figs. 8-11 and 15: paths over the map; error and the filter's own spread over time (run 0)."""
    from ...plots import PAPER_STYLE, plain_log_labels

    terrain = get_map(m, config.map_seed)
    time_s = np.arange(1, truth.states.shape[0]) * config.dt
    fig = plt.figure(figsize=(15, 9.5))
    grid = fig.add_gridspec(2, 2, width_ratios=(1.0, 1.25))
    ax_map, ax_err, ax_std = fig.add_subplot(grid[:, 0]), fig.add_subplot(grid[0, 1]), fig.add_subplot(grid[1, 1])
    order = [n for n in config.filters(c) if n in runs]
    xs = np.concatenate([truth.states[:, 0]] + [runs[n].estimates[:, 0] for n in order]) / 1e3
    ys = np.concatenate([truth.states[:, 1]] + [runs[n].estimates[:, 1] for n in order]) / 1e3
    x_min, x_max, y_min, y_max = (v / 1e3 for v in terrain.extent)
    pad = 2.0
    window = (max(x_min, np.percentile(xs, 1) - pad), min(x_max, np.percentile(xs, 99) + pad),
              max(y_min, np.percentile(ys, 1) - pad), min(y_max, np.percentile(ys, 99) + pad))
    image, interval = depth_image(ax_map, terrain, window, alpha=0.6)
    fig.colorbar(image, ax=ax_map, label="depth (m)", shrink=0.6)
    ax_map.plot(truth.states[:, 0] / 1e3, truth.states[:, 1] / 1e3, color="black", lw=5.0, alpha=0.3, label="truth",
                zorder=3, solid_capstyle="round")
    ax_map.plot(truth.states[0, 0] / 1e3, truth.states[0, 1] / 1e3, "ko", ms=8, zorder=6)
    for name in order:
        r, st = runs[name], style(name)
        label = DISPLAY.get(name, name)
        ax_map.plot(r.estimates[:, 0] / 1e3, r.estimates[:, 1] / 1e3, color=st["color"], ls=st["linestyle"], lw=1.1,
                    label=label, zorder=4)
        ax_err.plot(time_s, r.errors, color=st["color"], ls=st["linestyle"], lw=1.0, label=label)
        if r.cov is not None:
            ax_std.plot(time_s, r.std, color=st["color"], ls=st["linestyle"], lw=1.0, label=label)
    ax_map.set(xlim=window[:2], ylim=window[2:], xlabel="x (km)", ylabel="y (km)",
               title=f"paths over the map (start: dot; contours every {interval} m)")
    for ax in (ax_err, ax_std):
        ax.set(yscale="log", xlabel="time (s)")
        plain_log_labels(ax)
        ax.grid(alpha=0.3, which="both")
    # the reference lines go into the one legend (below the map), so no text lies over the curves
    ax_err.axhline(config.lost_m, color="#555555", lw=1.0, ls=":", zorder=9)
    ax_map.plot([], [], color="#555555", lw=1.0, ls=":", label=f"error panel: lost (error > {config.lost_m:g} m)")
    claim = {k: v for k, v in PAPER_STYLE.items() if k not in ("marker", "markerfacecolor", "markersize", "markeredgewidth")}
    ax_err.axhline(500.0, **{**claim, "linestyle": "-.", "linewidth": 1.4})
    ax_map.plot([], [], **{**claim, "linestyle": "-.", "linewidth": 1.4},
                label="error panel: THE PAPER, fuzzy within one 500 m cell (abstract)")
    handles, labels = ax_map.get_legend_handles_labels()  # one legend for all panels, below them
    fig.legend(handles, labels, loc="lower center", bbox_to_anchor=(0.5, 0.02), ncol=5, fontsize=7, frameon=False)
    ax_err.set(ylabel="position error (m)", title="error over time (cf. Figs. 9, 11, 15)")
    ax_std.set(ylabel="filter's own spread sqrt(Pxx + Pyy) (m)", title="the filter's own spread (below the error: "
               "confidently wrong)")
    ax_std.set_ylim(ax_err.get_ylim())
    tr = TRACKS[m][t]
    fig.suptitle(f"{m} / {t}: start {tr.label()}, current {c} m/s (run 0)")
    fig.tight_layout(rect=(0, 0.09, 1, 1))
    return fig


def _fuzzy_inputs_figure(plt, config: TanConfig, m, t, c, truth, fz):
    """Fig. 12: depth and gradient rate along the path; Fig. 13: gradient x rate vs sigma; the inputs' spread."""
    time_s = np.arange(1, truth.states.shape[0]) * config.dt
    gradient_unit, rate_unit = "%", "%/km"
    fig, axes = plt.subplots(2, 2, figsize=(11, 7.5))
    axes[0, 0].plot(time_s, truth.measurements[:, 0], lw=0.6, color="black")
    axes[0, 0].set(xlabel="time (s)", ylabel="altimeter depth (m)", title="depth and gradient rate along the path (cf. Fig. 12)")
    twin = axes[0, 0].twinx()
    twin.plot(time_s, fz.gradient_rate, color=style("fuzzy")["color"], lw=0.6)
    twin.set_ylabel(f"gradient rate ({rate_unit})", color=style("fuzzy")["color"])
    axes[0, 1].scatter(fz.gradient * fz.gradient_rate, fz.sigma, s=2, color=style("fuzzy")["color"])
    axes[0, 1].set(xlabel=f"gradient x gradient rate ({gradient_unit} x {rate_unit})", ylabel="fuzzy sigma (m)",
                   title="inner product vs sigma (cf. Fig. 13)")
    for ax, values, unit, what in ((axes[1, 0], fz.gradient, gradient_unit, "gradient"),
                                   (axes[1, 1], fz.gradient_rate, rate_unit, "gradient-rate")):
        ax.hist(np.clip(values, -25, 25), bins=50, range=(-25, 25), color="#0072B2")
        for edge in (-20.0, 20.0):
            ax.axvline(edge, color="black", lw=0.9, ls="--")
        ax.set(xlabel=f"{what} ({unit}; values beyond ±25 piled at ±25)", ylabel="steps",
               title=f"{what} input (dashed: fuzzy domain ±20)")
    fig.suptitle(f"fuzzy sigma's inputs: {m} / {t}, current {c} m/s (run 0)")
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    return fig


#: the name `abyssal reproduce` looks up (reproduce.py)
Config = TanConfig
