"""`abyssal reproduce cn-count`: MCUPF's particle count swept, under the paper's rules and ours (seed 002).

The cn experiment's MCUPF settles on ~50 particles: KLD-resampling with 10 m bins asks for fewer than that once the
cloud is tight, so our floor N_min = 50 decides. The paper's Table 7 says its MCUPF ran longer per step than its
5000-particle UPF (0.2156 s against 0.1725 s, a ratio of 1.25; PAPER_TIME_RATIO), so the authors' MCUPF did not run
on ~50 particles. How many it ran on the paper does not say, so the count is swept: the KLD floor N_min over
``floors`` (N_max = max(2000, N_min), N_start = 5000: at N_min = 5000 the count is fixed at the UPF's), and the
count the paper's timing implies is read off the same runs (below).

Two rules of our particle engine are not the paper's (filters/particle/engine.py), and the cn experiment's MCUPF
finding ("the lowest APE of the particle filters in multipath") rests on both; each MCUPF runs under each rule set:

* "paper": ``underflow="normalise"`` (eq. 21's normalisation whatever the likelihoods: when a range underflows the
  likelihood at every particle, the weight goes to the particles nearest it) and ``estimate="after"`` (the estimate
  from the resampled particles, eqs. 23-24 and Table 3 step 4: "State estimation by N_KLD resampled particles");
* "ours": the engine's defaults, the cn experiment's MCUPF (weights kept when every likelihood underflows; the
  estimate before resampling).

The UPF (N = 5000, multinomial every step) runs under both rule sets as the reference. Everything else is the cn
experiment's (cn/experiment.py): its simulated trials (the same draws: trial i of noise case c comes from
``derive(seed, c)`` as there), the printed tuning (Q = diag(10^2, 10^2) m^2, R = 0.1 m^2), sigma = 15, no gate,
``streams`` random streams per filter and trial (a filter's per-run APE is the mean over its streams).

The count implied by the paper's timing: with our per-step CPU times of this campaign (process time, so the
machine's load changes them little), t(MCUPF at its steady count n) / t(UPF at 5000) rises with n; the
implied count is where it reaches 1.25 (log-linear interpolation between the swept floors; "beyond the sweep" when
even N_min = 5000 stays below). A second reading assumes the paper's MCC update costs what its UKF update costs per
particle (the KLD overhead only adds): 1.25 x 5000 = 6250 particles, above N_start.

Rows (``EXTRA_COLUMNS`` = geometry, stream): per filter and stream ``ape_m``, ``final_error_m``,
``steady_particles`` (mean count over steps 1..), ``uninformative`` (share of the pings whose likelihood underflowed
at every particle), ``cpu_ms`` (the process's CPU time per step over the trial, for the timing ratio only) and
``refused``.
"""
from __future__ import annotations

import math
import time
import zlib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..campaign import derive, run_index
from ..tables import MEAN_SD, over_runs
from . import paper
from .experiment import CnConfig
from .scenario import position_errors, simulate

EXTRA_COLUMNS: tuple[str, ...] = ("geometry", "stream")
#: KLD floors N_min swept (N_max = max(base.kld_n_max, N_min); 5000 = the UPF's fixed count)
FLOORS = (50, 200, 500, 1000, 2000, 5000)
#: the engine's options of each rule set (module docstring)
RULES = {"paper": {"underflow": "normalise", "estimate": "after"}, "ours": {"underflow": "keep", "estimate": "before"}}
#: Table 7: the paper's MCUPF time per step over its 5000-particle UPF's
PAPER_TIME_RATIO = paper.TABLE7["MCUPF"][1] / paper.TABLE7["UPF"][1]
METRICS = ("ape_m", "final_error_m", "steady_particles", "uninformative", "cpu_ms")


#: how a rule set is named in labels and tables
RULE_NAMES = {"paper": "paper's rules", "ours": "our rules"}
#: the UPF's particle number in the paper (Table 6: N_start, the UPF's fixed count)
PAPER_UPF_PARTICLES = 5000


def mcupf_label(floor: int, rules: str) -> str:
    return f"MCUPF N_min={floor} ({RULE_NAMES[rules]})"


def upf_label(rules: str) -> str:
    return f"UPF ({RULE_NAMES[rules]})"


def rules_of(label: str) -> str:
    return next(r for r, name in RULE_NAMES.items() if label.endswith(f"({name})"))


@dataclass(frozen=True)
class CountConfig:
    """The sweep: the cn experiment's set-up (``base``), the geometries and noise cases, the floors, the rule sets."""

    base: CnConfig = field(default_factory=CnConfig)
    geometries: tuple[str, ...] = ("crossing60", "collinear")
    cases: tuple[str, ...] = ("gaussian", "eps0.1", "eps0.3", "multipath")
    floors: tuple[int, ...] = FLOORS
    rules: tuple[str, ...] = tuple(RULES)
    streams: int = 3
    quick_run: bool = False

    def __post_init__(self):
        unknown = [c for c in self.cases if c not in self.base.cases] + [r for r in self.rules if r not in RULES]
        if unknown or any(int(f) < 1 for f in self.floors):
            raise ValueError(f"cases must be among {self.base.cases}, rules among {tuple(RULES)}, floors >= 1; "
                             f"got {unknown or self.floors}")

    def quick(self) -> "CountConfig":
        """the crossing60 geometry, noise cases gaussian and multipath, 600 s trials, N_start = 1000, floors 50 and
        1000, 2 random streams: a smoke test of the pipeline, not evidence"""
        base = self.base.quick()
        return replace(self, base=base, geometries=("crossing60",), cases=("gaussian", "multipath"), floors=(50, 1000),
                       streams=2, quick_run=True)

    def labels(self) -> list[str]:
        return [mcupf_label(f, r) for r in self.rules for f in self.floors] + [upf_label(r) for r in self.rules]


def make_filter(label: str, model, trial, config: CountConfig, rng):
    """One filter of the sweep on cn2d with the printed tuning (cn/experiment.py's)."""
    from ...filters.particle.unscented import UnscentedParticleFilter
    from ...resampling import KLDResampling

    base = config.base
    Q, R = np.eye(2) * base.q_std**2, np.eye(model.n_y) * base.r  # each leader sensor's R (the stacked form)
    rules = RULES[rules_of(label)]
    if label.startswith("UPF"):
        return UnscentedParticleFilter(model, trial.x0, trial.P0, Q, R, base.n_particles, rng, gate_probability=0.0,
                                       **rules)
    floor = int(label.split("N_min=")[1].split()[0])
    kld = KLDResampling(n_min=floor, n_max=max(base.kld_n_max, floor))
    return UnscentedParticleFilter(model, trial.x0, trial.P0, Q, R, base.n_particles, rng, update="mcc",
                                   sigma=base.sigma, resampling=kld, name="MCUPF", gate_probability=0.0, **rules)


def run_one(config: CountConfig, seed: np.random.SeedSequence) -> list[dict]:
    """Every geometry x noise case x filter x stream of one run (module docstring)."""
    import abyssal.generated

    model = abyssal.generated.load("cn2d")
    run = run_index(seed)
    rows = []
    for geometry in config.geometries:
        for case in config.cases:
            c = config.base.cases.index(case)  # the cn experiment's case number: the same trials
            trial = simulate(config.base.scenario_for(geometry), case, np.random.default_rng(derive(seed, c)))
            for label in config.labels():
                for stream in range(config.streams):
                    rng = np.random.default_rng(derive(seed, c, 1, zlib.crc32(label.encode()), stream))
                    filt = make_filter(label, model, trial, config, rng)
                    try:
                        started = time.process_time()
                        with np.errstate(over="ignore"):
                            result = filt.run(trial.U, trial.Z, trial.dt, params=trial.params)
                        cpu_ms = 1e3 * (time.process_time() - started) / len(trial.t)
                    except (ValueError, ArithmeticError, np.linalg.LinAlgError):
                        metrics = {**{m: math.nan for m in METRICS}, "refused": 1.0}
                    else:
                        pe = position_errors(result.x, trial.truth)
                        metrics = {"ape_m": float(pe.mean()), "final_error_m": float(pe[-1]),
                                   "steady_particles": float(np.mean(result.particles[1:])),
                                   "uninformative": filt.uninformative / len(trial.t),
                                   "cpu_ms": cpu_ms, "refused": 0.0}
                    rows += [{"run": run, "case": case, "filter": label, "metric": m, "geometry": geometry,
                              "stream": stream, "value": v} for m, v in metrics.items()]
    return rows


# ---------------------------------------------------------------------------------------------- tables
def per_run(rows) -> dict:
    """{(geometry, case, filter, metric): {run: mean over the streams (a refused stream, NaN, left out)}}."""
    values: dict = {}
    for r in rows:
        values.setdefault((r["geometry"], r["case"], r["filter"], r["metric"]), {}).setdefault(r["run"], []).append(
            r["value"])
    out = {}
    for key, runs in values.items():
        out[key] = {run: (float(np.nanmean(v)) if not np.all(np.isnan(v)) else math.nan) for run, v in runs.items()}
    return out


def summary(rows) -> dict:
    """{(geometry, case, filter, metric): OverRuns of the per-run values}."""
    return {key: over_runs(runs.values()) for key, runs in per_run(rows).items()}


def beats(rows, geometry: str, case: str, label: str, reference: str) -> tuple[int, int]:
    """(runs where label's APE < reference's, runs with both)."""
    p = per_run(rows)
    a, b = p.get((geometry, case, label, "ape_m"), {}), p.get((geometry, case, reference, "ape_m"), {})
    pairs = [(a[r], b[r]) for r in a if r in b and not (math.isnan(a[r]) or math.isnan(b[r]))]
    return sum(x < y for x, y in pairs), len(pairs)


def time_ratios(rows, rules: str = "ours") -> list[tuple[int, float, float]]:
    """[(floor, steady count, mean CPU time per step of MCUPF at that floor / the UPF's)] over every case and stream
    of the campaign (``rules``' filters)."""
    times: dict = {}
    counts: dict = {}
    for r in rows:
        if r["metric"] == "cpu_ms" and not math.isnan(r["value"]):
            times.setdefault(r["filter"], []).append(r["value"])
        if r["metric"] == "steady_particles" and not math.isnan(r["value"]):
            counts.setdefault(r["filter"], []).append(r["value"])
    reference = times.get(upf_label(rules))
    if not reference:
        return []
    out = []
    for label in sorted(times):
        if label.startswith("MCUPF") and rules_of(label) == rules:
            floor = int(label.split("N_min=")[1].split()[0])
            out.append((floor, float(np.mean(counts[label])), float(np.mean(times[label]) / np.mean(reference))))
    return sorted(out)


def implied_count(ratios: list[tuple[int, float, float]], target: float = PAPER_TIME_RATIO) -> float | None:
    """The steady count at which the time ratio reaches ``target`` (log-linear between the swept points); None when
    every point lies below it (beyond the sweep) or above it (below the sweep's smallest count)."""
    points = sorted((count, ratio) for _, count, ratio in ratios)
    for (n0, r0), (n1, r1) in zip(points, points[1:]):
        if (r0 - target) * (r1 - target) <= 0 and r0 != r1:
            t = (target - r0) / (r1 - r0)
            return float(math.exp(math.log(n0) + t * (math.log(n1) - math.log(n0))))
    return None


def report(rows, config: CountConfig) -> str:
    s = summary(rows)
    runs = len({r["run"] for r in rows})
    L = [f"MCUPF particle-count sweep (seed 002){' -- QUICK run (smoke test, not evidence)' if config.quick_run else ''}:"
         f" {runs} run(s) x {len(config.geometries)} geometries x {len(config.cases)} noise cases, {config.streams} "
         f"stream(s) per filter and trial; printed tuning (Q = diag({config.base.q_std:g}^2, {config.base.q_std:g}^2) "
         f"m^2, R = {config.base.r:g} m^2), KLD epsilon 0.15, delta 0.01, 10 m bins, N_start = "
         f"{config.base.n_particles}, N_max = max({config.base.kld_n_max}, N_min).",
         f"APE (m): {MEAN_SD}, a run's value the mean over its streams. Rules: 'paper' = weights normalised whatever "
         "the likelihoods (eq. 21) and the estimate from the resampled particles (eqs. 23-24); 'ours' = weights kept "
         "when every likelihood underflows, the estimate before resampling (the cn experiment's MCUPF).",
         f"The paper's Table 7 (real lake data, quoted): MCUPF {paper.TABLE7['MCUPF'][0]} m, UPF {paper.TABLE7['UPF'][0]} "
         f"m; time per step MCUPF {paper.TABLE7['MCUPF'][1]} s, UPF {paper.TABLE7['UPF'][1]} s (ratio "
         f"{PAPER_TIME_RATIO:.2f})."]
    for geometry in config.geometries:
        for rules in config.rules:
            L += ["", f"== {geometry}, {RULE_NAMES[rules]}: APE (m) [runs where it beats the UPF under the same rules]; "
                      "steady particle count; share of pings whose likelihood underflowed at every particle",
                  f"{'filter':<34}" + "".join(f"{c:>28}" for c in config.cases) + f"{'steady N':>10}{'underflow':>11}"]
            for label in [mcupf_label(f, rules) for f in config.floors] + [upf_label(rules)]:
                cells = []
                for case in config.cases:
                    e = s.get((geometry, case, label, "ape_m"))
                    k, n = beats(rows, geometry, case, label, upf_label(rules))
                    cells.append(f"{e.cell('.2f') if e else '-'} [{k}/{n}]" if not label.startswith("UPF") else
                                 (e.cell('.2f') if e else '-'))
                steady = [s[(geometry, c, label, "steady_particles")].mean for c in config.cases
                          if (geometry, c, label, "steady_particles") in s]
                under = [s[(geometry, c, label, "uninformative")].mean for c in config.cases
                         if (geometry, c, label, "uninformative") in s]
                L.append(f"{label:<34}" + "".join(f"{c:>28}" for c in cells)
                         + f"{np.mean(steady) if steady else math.nan:>10.0f}{np.mean(under) if under else math.nan:>11.3f}")
    L += ["", "The paper's rules against ours, paired per run: runs where the MCUPF under the paper's rules has the "
               "lower APE"]
    for geometry in config.geometries:
        for case in config.cases:
            cells = []
            for floor in config.floors:
                k, n = beats(rows, geometry, case, mcupf_label(floor, "paper"), mcupf_label(floor, "ours"))
                cells.append(f"N_min={floor} {k}/{n}")
            L.append(f"  {geometry:<11}{case:<10} " + "; ".join(cells))
    for rules in config.rules:
        ratios = time_ratios(rows, rules)
        if not ratios:
            continue
        L += ["", f"CPU time per step, MCUPF / UPF (N = {config.base.n_particles}), {RULE_NAMES[rules]}, mean over every "
                  "case and stream of this campaign (process time: a ratio, not a benchmark):",
              "  " + "; ".join(f"N_min={f}: steady {n:.0f}, ratio {r:.2f}" for f, n, r in ratios)]
        n = implied_count(ratios)
        top = max(ratios, key=lambda t: t[1])
        L.append(f"  the paper's ratio {PAPER_TIME_RATIO:.2f} is reached at a steady count of "
                 + (f"~{n:.0f} particles" if n is not None else
                    f"more than the sweep holds (at {top[1]:.0f} particles the ratio is {top[2]:.2f})"))
    L.append(f"  If the paper's MCC update cost its UKF update's per particle, 0.2156 / 0.1725 x {PAPER_UPF_PARTICLES} = "
             f"{PAPER_TIME_RATIO * PAPER_UPF_PARTICLES:.0f} particles (above its N_start; its KLD-resampling would "
             "only add time)")
    return "\n".join(L)


def markdown(rows, config: CountConfig, document: dict | None = None) -> dict[str, str]:
    """The sweep's tables for docs/experiments/cn.md (`abyssal publish cn-count`, publish.py)."""
    from ..publish import markdown_table, number

    s = summary(rows)
    out = {}
    for geometry in config.geometries:
        body = []
        for rules in config.rules:
            for label in [mcupf_label(f, rules) for f in config.floors] + [upf_label(rules)]:
                cells = []
                for case in config.cases:
                    e = s.get((geometry, case, label, "ape_m"))
                    text = e.cell(".2f") if e else "-"
                    if not label.startswith("UPF") and e:
                        k, n = beats(rows, geometry, case, label, upf_label(rules))
                        text += f" [{k}/{n}]"
                    cells.append(text)
                steady = [s[(geometry, c, label, "steady_particles")].mean for c in config.cases
                          if (geometry, c, label, "steady_particles") in s]
                under = [s[(geometry, c, label, "uninformative")].mean for c in config.cases
                         if (geometry, c, label, "uninformative") in s]
                body.append([label, *cells, number(float(np.mean(steady)) if steady else math.nan, ".0f"),
                             number(float(np.mean(under)) if under else math.nan, ".3f")])
        out[f"ape-{geometry}"] = markdown_table(
            ["filter", *(f"{c}: APE m [runs beating the UPF]" for c in config.cases), "steady N",
             "share of pings whose likelihood underflowed"], body)
    body = []
    for geometry in config.geometries:
        for case in config.cases:
            cells = []
            for floor in config.floors:
                k, n = beats(rows, geometry, case, mcupf_label(floor, "paper"), mcupf_label(floor, "ours"))
                cells.append(f"{k}/{n}")
            body.append([geometry, case, *cells])
    out["rules"] = markdown_table(["geometry", "noise case", *(f"N_min = {f}" for f in config.floors)], body,
                                  align="ll" + "r" * len(config.floors))
    body = []
    for rules in config.rules:
        ratios = time_ratios(rows, rules)
        implied = implied_count(ratios)
        for floor, count, ratio in ratios:
            body.append([RULE_NAMES[rules], str(floor), f"{count:.0f}", f"{ratio:.2f}"])
        body.append([RULE_NAMES[rules], "the paper's ratio 1.25 reached at", "-",
                     f"~{implied:.0f} particles" if implied is not None else "beyond the sweep"])
    out["timing"] = markdown_table(["rules", "N_min", "steady N", f"CPU time per step / the UPF's (N = "
                                    f"{config.base.n_particles})"], body, align="llrr")
    return out


def document(rows, config: CountConfig, prepared=None) -> dict:
    s = summary(rows)
    cases = {}
    for (geometry, case, label, metric), e in s.items():
        cases.setdefault(geometry, {}).setdefault(case, {}).setdefault(label, {})[metric] = vars(e)
    return {"cases": cases, "paper_time_ratio": PAPER_TIME_RATIO,
            "time_ratios": {r: time_ratios(rows, r) for r in config.rules},
            "implied_count": {r: implied_count(time_ratios(rows, r)) for r in config.rules}}


def figures(rows, out, config: CountConfig, seed: int = 0, prepared=None, settings: str | None = None) -> list[Path]:
    """cn_count.png: APE against the steady particle count per geometry and noise case, the paper's rules and ours
    (the UPF at 5000 under each as a reference), the paper's Table 7 MCUPF value as its labelled marker;
    cn_count_time.png: the time ratio against the count with the paper's 1.25."""
    from ... import plots

    plt = plots.plt
    s = summary(rows)
    runs = len({r["run"] for r in rows})
    stamp = (f"{settings}: " if settings else "") + f"{runs} run(s), seed {seed}, {config.streams} stream(s)"
    rule_look = {"paper": {"marker": "s", "linestyle": "--", "mfc": "white"}, "ours": {"marker": "o", "linestyle": "-"}}
    mcupf, upf = plots.filter_style("MCUPF"), plots.filter_style("UPF")
    fig, axes = plt.subplots(len(config.geometries), len(config.cases), squeeze=False, sharex=True,
                             figsize=(3.6 * len(config.cases) + 1, 3.4 * len(config.geometries) + 1.2))
    for i, geometry in enumerate(config.geometries):
        for j, case in enumerate(config.cases):
            ax = axes[i, j]
            for rules in config.rules:
                look = rule_look[rules]
                xs, ys, es = [], [], []
                for floor in config.floors:
                    label = mcupf_label(floor, rules)
                    e, n = s.get((geometry, case, label, "ape_m")), s.get((geometry, case, label, "steady_particles"))
                    if e and n:
                        xs.append(n.mean), ys.append(e.mean), es.append(e.sd if math.isfinite(e.sd) else 0.0)
                ax.errorbar(xs, ys, yerr=es, color=mcupf["color"], capsize=2, lw=1.2, ms=5,
                            label=f"MCUPF, {RULE_NAMES[rules]}", **look)
                ref = s.get((geometry, case, upf_label(rules), "ape_m"))
                if ref:
                    ax.axhline(ref.mean, color=upf["color"], lw=1.0, ls=look["linestyle"],
                               label=f"UPF N = {config.base.n_particles}, {RULE_NAMES[rules]}")
            ax.plot([config.base.kld_n_max], [paper.TABLE7["MCUPF"][0]], **plots.PAPER_STYLE)
            ax.set(xscale="log", yscale="log", title=f"{geometry}, {case}")
            ax.title.set_fontsize(9)
            plots.plain_log_labels(ax)
            plots.plain_log_labels(ax, "x")
            ax.grid(alpha=0.3, which="both")
            if j == 0:
                ax.set_ylabel("APE (m): mean over runs ± sd")
            if i == len(config.geometries) - 1:
                ax.set_xlabel("MCUPF steady particle count")
    handles, names = axes[0, 0].get_legend_handles_labels()
    handles.append(plt.Line2D([], [], **{k: v for k, v in plots.PAPER_STYLE.items() if k != "zorder"}))
    names.append(f"paper's MCUPF: Table 7, {paper.TABLE7['MCUPF'][0]} m on its lake data (quoted; drawn at its printed "
                 f"N_max = {config.base.kld_n_max}, its count is not stated)")
    fig.legend(handles, names, loc="lower center", ncol=2, fontsize=8, frameon=False, bbox_to_anchor=(0.5, 0.01))
    fig.suptitle("MCUPF APE against its particle count (KLD floor N_min swept), the paper's rules and ours")
    paths = [plots.save_figure(fig, Path(out) / "cn_count.png", stamp, rect=(0, 0.13, 1, 1))]

    fig, ax = plt.subplots(figsize=(7, 4.2))
    for rules in config.rules:
        ratios = time_ratios(rows, rules)
        if ratios:
            look = rule_look[rules]
            ax.plot([n for _, n, _ in ratios], [r for _, _, r in ratios], color=mcupf["color"], ms=5, lw=1.2,
                    label=f"ours: MCUPF / UPF (N = {config.base.n_particles}), {RULE_NAMES[rules]}", **look)
    ax.axhline(PAPER_TIME_RATIO, **{**{k: v for k, v in plots.PAPER_STYLE.items() if k not in
                                       ("marker", "markerfacecolor", "markersize", "markeredgewidth", "linestyle")},
                                    "linestyle": "-.", "linewidth": 1.2},
               label=f"paper's Table 7: MCUPF / UPF = {PAPER_TIME_RATIO:.2f} (quoted)")
    ax.set(xscale="log", xlabel="MCUPF steady particle count", ylabel="CPU time per step / the UPF's",
           title="CPU time per step against the count (process time in the campaign; not a benchmark)")
    ax.title.set_fontsize(9)
    plots.plain_log_labels(ax, "x")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    paths.append(plots.save_figure(fig, Path(out) / "cn_count_time.png", stamp, rect=(0, 0.03, 1, 1)))
    return paths


#: the name `abyssal reproduce` looks up (reproduce.py)
Config = CountConfig
