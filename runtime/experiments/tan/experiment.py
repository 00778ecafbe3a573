"""Seed 003's tables and figures, made from the tidy rows of the campaign (scenario.run_one).

Rows: one per run x case x filter x metric; metrics mean_error_m, final_error_m, max_error_m,
lost (1 when the error ever exceeded 1000 m), mean_std_m (the filter's own position spread),
step_us (median wall time of one step, a timing: never compared across runs) and, for the fuzzy
filter, mean_sigma_m. Figures of single tracks (paths, errors, fuzzy inputs) come from a
separate figure run (``figure_runs``): run 0's seeds of the chosen cases, recomputed in this process.
"""
from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np

from ...extras import require
from . import paper
from .scenario import ORACLE, TanConfig, case_name, run_case

EXTRA_COLUMNS: tuple[str, ...] = ()
METRICS = ("mean_error_m", "final_error_m", "max_error_m", "lost", "mean_std_m", "step_us")


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


def figures(rows, out: Path, config: TanConfig, seed: int = 0) -> list[Path]:
    require("matplotlib", "the experiment figures").use("Agg")
    plt = require("matplotlib.pyplot", "the experiment figures")

    from .scenario import get_map

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
