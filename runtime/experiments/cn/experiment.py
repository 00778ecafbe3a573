"""`abyssal reproduce cn`: seed 002's Table 7 and Figs. 7-9 on the simulated lake trial (scenario.py).

One campaign run (``run_one``) simulates one trial per noise case and runs every filter on it:
dead reckoning, CKF, MCUKF, PF, UPF, HRUPF, IVBCKF, MCUPF -- and, ours, MCC-UPF: MCUPF's MCC proposal
with a fixed N = 5000 and multinomial resampling, to separate the proposal's effect from
KLD-resampling's -- with the paper's printed tuning
Q = diag(10^2, 10^2) m^2 per 5 s step and R = 0.1 m^2 (Table 6 parameters). Rows: per run x case x
filter, ``ape_m`` (eq. 46), ``final_error_m``, ``step_ms`` (wall clock per step, mean over the
run) and ``mean_particles``. The table quotes the paper's Table 7 (MATLAB on a 2.9 GHz Pentium,
real lake data) beside our means over runs; it is never our data.

Every filter runs with the innovation gate off (``gate_probability=0``): the paper's filters
have none, and a gate would make the plain CKF robust (and the tuned UPFs in the multipath case). The MCUKF and the UPF family use the
paper's lambda = 3 - n sigma points (alpha = 1, beta = 0, kappa = 3 - n).

Tuned rows ("<filter> tuned"): on this simulation the printed Q = (10 m)^2 per 5 s step lets the
estimate random-walk 10 m per step along the direction a single range does not observe, so the
filters end up near dead reckoning (measured: CKF and UPF APE 18-25 m against DR 18-31 m on two
seeds, and 4-5 m with Q = (1 m)^2, R = 1 m^2). The printed values stay the reproduction; the
tuned rows use Q = diag(1, 1) m^2 per step (the DR drift over 5 s is well below 1 m) and R = the
simulated nominal range variance (1 m^2), everything else unchanged.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ...extras import require
from ..campaign import derive, run_index
from . import paper
from .scenario import NOISE_CASES, CnScenario, ape, position_errors, simulate

FILTERS = ("DR", "CKF", "MCUKF", "PF", "UPF", "HRUPF", "IVBCKF", "MCUPF", "MCC-UPF")
EXTRA_COLUMNS: tuple[str, ...] = ()


@dataclass(frozen=True)
class CnConfig:
    """One campaign's set-up: the scenario, the noise cases, the filters and their tuning."""

    scenario: CnScenario = field(default_factory=CnScenario)
    cases: tuple = NOISE_CASES
    filters: tuple = FILTERS
    n_particles: int = 5000          # PF, UPF, HRUPF; MCUPF's N_start
    kld_n_max: int = 2000            # Table 6
    kld_n_min: int = 50              # ours (the paper states none)
    q_std: float = 10.0              # Q = diag(q_std^2, q_std^2) per step
    r: float = 0.1                   # R (m^2) as printed
    sigma: float = 15.0              # MCC kernel bandwidth
    gamma: float = 1.345             # Huber threshold
    ivb_iterations: int = 10         # ours: the paper does not state T_i1
    tuned: tuple = ("CKF", "MCUKF", "IVBCKF", "UPF", "MCUPF", "MCC-UPF")  # also run with the tuned Q, R (docstring)
    q_std_tuned: float = 1.0
    r_tuned: float = 1.0

    def quick(self) -> "CnConfig":
        from dataclasses import replace

        return replace(self, scenario=replace(self.scenario, duration=600.0, leg_seconds=(200.0, 60.0, 200.0, 60.0, 100.0)),
                       n_particles=1000, kld_n_max=500)


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
    R = np.array([[config.r_tuned if tuned else config.r]])
    x0, P0 = trial.x0, trial.P0
    lam = 3.0 - model.n_x
    if name == "CKF":
        return CKF(model, x0, P0, Q, R, gate_probability=0.0)
    if name == "MCUKF":
        return MCUKF(model, x0, P0, Q, R, sigma=config.sigma, alpha=1.0, beta=0.0, kappa=lam, gate_probability=0.0)
    if name == "IVBCKF":
        return IVBCKF(model, x0, P0, Q, R, iterations=config.ivb_iterations, gate_probability=0.0)  # as the paper's
    if name == "PF":
        noise = GaussianMixture(np.ones(1), np.zeros((1, 1)), R[None])
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


def run_filters(config: CnConfig, seed: np.random.SeedSequence, case_index: int):
    """(trial, {filter: (estimates (K, 2), step seconds (K,), particles (K,))}) for one case of one run."""
    import abyssal.generated

    model = abyssal.generated.load("cn2d")
    case = config.cases[case_index]
    trial = simulate(config.scenario, case, np.random.default_rng(derive(seed, case_index)))
    out = {}
    for j, name in enumerate(filter_names(config)):
        if name == "DR":
            out[name] = (trial.dr, np.zeros(len(trial.t)), np.full(len(trial.t), np.nan))
            continue
        filt = make_filter(name, model, trial, config, np.random.default_rng(derive(seed, case_index, 100 + j)))
        result = filt.run(trial.U, trial.Z, trial.dt, params=trial.params)
        out[name] = (result.x, result.step_time, result.particles)
    return trial, out


def run_one(config: CnConfig, seed: np.random.SeedSequence) -> list[dict]:
    """One campaign run: every noise case x filter; tidy rows (campaign.py)."""
    run = run_index(seed)
    rows = []
    for i, case in enumerate(config.cases):
        trial, results = run_filters(config, seed, i)
        for name, (x, step_time, particles) in results.items():
            pe = position_errors(x, trial.truth)
            values = {"ape_m": float(pe.mean()), "final_error_m": float(pe[-1]),
                      "step_ms": float(np.mean(step_time) * 1e3),
                      "mean_particles": float(np.nanmean(particles)) if np.isfinite(particles).any() else math.nan}
            rows += [{"run": run, "case": case, "filter": name, "metric": k, "value": v} for k, v in values.items()]
    return rows


# ---------------------------------------------------------------------------------------------
# tables


def summary(rows) -> dict:
    """{case: {filter: {metric: mean over runs, metric_std: std over runs}}}."""
    table: dict = {}
    for r in rows:
        table.setdefault(r["case"], {}).setdefault(r["filter"], {}).setdefault(r["metric"], []).append(r["value"])
    out = {}
    for case, filters in table.items():
        out[case] = {}
        for f, metrics in filters.items():
            entry = {}
            for k, v in metrics.items():
                v = np.asarray(v, dtype=float)
                entry[k] = float(np.nanmean(v)) if np.isfinite(v).any() else math.nan
                entry[k + "_std"] = float(np.nanstd(v)) if np.isfinite(v).sum() > 1 else math.nan
            entry["runs"] = int(len(metrics.get("ape_m", [])))
            out[case][f] = entry
    return out


def beats_dr(rows) -> dict:
    """{case: {filter: fraction of runs whose APE is below dead reckoning's}}."""
    ape_of = {(r["run"], r["case"], r["filter"]): r["value"] for r in rows if r["metric"] == "ape_m"}
    out: dict = {}
    for (run, case, f), v in ape_of.items():
        if f == "DR":
            continue
        out.setdefault(case, {}).setdefault(f, []).append(v < ape_of[(run, case, "DR")])
    return {c: {f: float(np.mean(v)) for f, v in d.items()} for c, d in out.items()}


def report(rows, config: CnConfig) -> str:
    s, wins = summary(rows), beats_dr(rows)
    runs = len({r["run"] for r in rows})
    lines = [f"Seed 002, Table 7 on a SIMULATED lake trial (scenario.py; the paper's Lake Thai data is not public), "
             f"{runs} run(s). Ours: mean (std over runs); paper: real data, MATLAB on a 2.9 GHz Pentium (a different "
             f"machine, language and data set). Tuning as printed: Q = diag({config.q_std:g}^2, {config.q_std:g}^2), "
             f"R = {config.r:g}; true range noise sigma = {math.sqrt(config.scenario.range_variance):g} m."]
    for case in config.cases:
        if case not in s:
            continue
        lines += ["", f"noise case: {case}",
                  f"{'filter':8s} {'APE m (ours)':>18s} {'beats DR':>9s} {'ms/step':>9s} {'particles':>10s}   "
                  f"{'paper APE m':>11s} {'paper ms':>9s}"]
        for f in filter_names(config):
            e = s[case].get(f)
            if e is None:
                continue
            pa = None if f.endswith("tuned") else paper.TABLE7.get(f)
            win = "" if f == "DR" else f"{100 * wins[case][f]:7.0f} %"
            ape_s = f"{e['ape_m']:8.2f} ({e['ape_m_std']:.2f})" if math.isfinite(e["ape_m_std"]) else f"{e['ape_m']:8.2f}"
            parts = f"{e['mean_particles']:10.0f}" if math.isfinite(e["mean_particles"]) else f"{'-':>10s}"
            paper_s = f"{pa[0]:11.1f} {pa[1] * 1e3:9.3f}" if pa else f"{'-':>11s} {'-':>9s}"
            lines.append(f"{f:8s} {ape_s:>18s} {win:>9s} {e['step_ms']:9.3f} {parts}   {paper_s}")
        ranking = sorted((f for f in s[case] if f in paper.TABLE7), key=lambda f: s[case][f]["ape_m"])
        lines.append("our APE ranking (printed tuning): " + " < ".join(ranking))
        lines.append("paper's ranking (Table 7):        " + " < ".join(paper.APE_RANKING))
    return "\n".join(lines)


def document(rows, config: CnConfig, prepared=None) -> dict:
    """The JSON summary's entries: what the data is, and ``json_document``'s cases."""
    return {"data": "simulated lake trial (the paper's data is not public)", "cases": json_document(rows)}


def json_document(rows) -> dict:
    """{case: {filter: {ape_m, step_ms, mean_particles (particle filters), ...}}} (NaN kept: reproduce writes null)."""
    s = summary(rows)
    out = {}
    for case, filters in s.items():
        out[case] = {}
        for f, e in filters.items():
            entry = {"ape_m": e["ape_m"], "ape_m_std": e["ape_m_std"], "final_error_m": e["final_error_m"],
                     "step_ms": e["step_ms"], "runs": e["runs"]}
            if math.isfinite(e["mean_particles"]):
                entry["mean_particles"] = e["mean_particles"]
            if f in paper.TABLE7:  # (tuned rows have no paper number)
                entry["paper_ape_m"], entry["paper_step_ms"] = paper.TABLE7[f][0], paper.TABLE7[f][1] * 1e3
            out[case][f] = entry
    return out


# ---------------------------------------------------------------------------------------------
# figures


def figures(rows, out, config: CnConfig, seed: int = 0, prepared=None) -> list:
    """Figs. 7-9 analogues (paths, positions, position errors) and MCUPF's particle count, for run 0 of each
    case (re-run here from the same seed, so they show a run that is in the table)."""
    require("matplotlib", "the experiment figures").use("Agg")
    plt = require("matplotlib.pyplot", "the experiment figures")

    from ..campaign import run_seeds

    s0 = run_seeds(seed, 1)[0]
    paths = []
    for i, case in enumerate(config.cases):
        trial, res = run_filters(config, s0, i)
        fig, axes = plt.subplots(2, 2, figsize=(13, 9))
        colours = dict(zip(res, plt.get_cmap("tab20").colors))
        ax = axes[0, 0]
        ax.plot(trial.truth[:, 0], trial.truth[:, 1], "k", lw=2, label="truth")
        for k in range(2):
            ax.plot(trial.leaders_true[k, :, 0], trial.leaders_true[k, :, 1], "--", color="grey", lw=1,
                    label="leaders" if k == 0 else None)
        for f, (x, _, _) in res.items():
            ax.plot(x[:, 0], x[:, 1], lw=1, label=f, color=colours[f])
        ax.set(xlabel="east (m)", ylabel="north (m)", title=f"paths (Fig. 7 analogue), {case}")
        ax.legend(fontsize=7, ncol=2)
        ax = axes[0, 1]
        for f, (x, _, _) in res.items():
            ax.plot(trial.t, x[:, 0] - trial.truth[:, 0], lw=1, label=f, color=colours[f])
        ax.set(xlabel="t (s)", ylabel="east error (m)", title="east position minus truth (Fig. 8 analogue)")
        ax = axes[1, 0]
        for f, (x, _, _) in res.items():
            ax.plot(trial.t, position_errors(x, trial.truth), lw=1, label=f"{f} ({ape(x, trial.truth):.1f} m)",
                    color=colours[f])
        ax.set(xlabel="t (s)", ylabel="PE (m)", title="position error, eq. 45 (Fig. 9 analogue)", yscale="log")
        ax.legend(fontsize=7, ncol=2)
        ax = axes[1, 1]
        for f in ("MCUPF", "MCUPF tuned"):
            if f in res:
                ax.plot(trial.t, res[f][2], label=f, color=colours[f])
        ax.set(xlabel="t (s)", ylabel="particles", title="MCUPF particle number (KLD-resampling; N_start = 5000)",
               yscale="log")
        ax.legend(fontsize=7)
        fig.suptitle(f"seed 002 on a SIMULATED lake trial, noise case {case}, run 0")
        fig.tight_layout()
        path = out / f"cn_{case}.png"
        fig.savefig(path, dpi=90)
        plt.close(fig)
        paths.append(path)
    return paths


#: the name `abyssal reproduce` looks up (reproduce.py)
Config = CnConfig
