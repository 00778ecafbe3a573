"""The remus figures: errors where the error is the point, the paper's values as markers nothing hides.

* remus_training_data.png   run 1's measured surge, the 40 % pool and each size's regressors (cf. Fig. 3)
* remus_position_error.png  horizontal position error and the filter's own 1-sigma over time, run 0 (cf. Figs. 6-8)
* remus_rmse_vs_size.png    horizontal position RMSE per GP size and training draw, the UKF readings as lines
* remus_state_rmse.png      RMSE per state (Table 3) in four panels by unit
* remus_surge_error.png     surge error over time, run 0, with the sensor's error (cf. Fig. 5)

Every figure uses one look per filter (``style``: runtime/plots.filter_style with the same ``ordered`` tuple
everywhere; the oracle in the shared oracle look; the UKF readings and the GP sizes in their family's colour
with a line style and a marker each (VARIANT_MARKERS), next-state targets dotted with the size's marker hollow, a
UKF reading on measured-feedback truths with its reading's marker hollow: a local rule until plots.py has one for
sizes), and says which run made it (stamp_settings: the command, --quick). The paper's values are black: in the
per-state figure short horizontal lines across a state's whole group (solid: its UKF, dashed: its GP-UKF), each
named beside it, so no marker of ours can be taken for one of the paper's.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from ... import plots
from . import paper
from .experiment import (LOG_DT, READINGS, RemusConfig, draws_of, filter_names, filter_run, is_gp, per_draw,
                         statistic)

ORACLE = READINGS["oracle"][0]
plt = plots.plt


#: markers of one family's variants (UKF readings, GP sizes), so markers alone tell them apart
VARIANT_MARKERS = ("o", "s", "^", "P", "X")


MEASURED = ", measured feedback"


def style(name: str, ordered: tuple[str, ...]) -> dict:
    """The look of a filter in every remus figure (module docstring)."""
    reading = name.replace(MEASURED, "")  # the UKF reading, whichever feedback its truths had
    if reading == ORACLE:
        s = plots.filter_style("oracle")
    else:
        s = plots.filter_style(reading if not is_gp(name) else name, ordered)
    if is_gp(name):
        sizes = sorted({int(n.split("N=")[1]) for n in ordered if is_gp(n)})
        k = sizes.index(int(name.split("N=")[1]))
        s.update(linestyle=plots.LINESTYLES[k % len(plots.LINESTYLES)], marker=VARIANT_MARKERS[k % len(VARIANT_MARKERS)])
        if "(state)" in name:
            s.update(markerfacecolor="none", linestyle=":")
    elif reading != ORACLE:
        readings = [READINGS[key][0] for key in READINGS if READINGS[key][0] != ORACLE]
        k = readings.index(reading) if reading in readings else 0
        s.update(marker=VARIANT_MARKERS[k % len(VARIANT_MARKERS)],
                 linestyle=plots.LINESTYLES[(k + 1) % len(plots.LINESTYLES)])
    if MEASURED in name:
        s.update(markerfacecolor="white", linestyle=(0, (5, 2, 1, 2)))
    return s


def _line(s: dict) -> dict:
    """A style for lines without markers."""
    return {k: v for k, v in s.items() if k in ("color", "linestyle")}


def _marked(s: dict, points: int, k: int) -> dict:
    """A style for a long line: its marker every points/12 samples (offset by the line's index k, so markers of
    lines that lie on each other do not overlap), which tells apart lines of one colour and line style."""
    every = max(1, points // 12)
    return {**_line(s), "marker": s["marker"], "markerfacecolor": s.get("markerfacecolor", s["color"]), "ms": 4,
            "markevery": ((k * every) // 7 % every, every)}


def settings_text(rows, config: RemusConfig, seed: int, settings: str | None = None) -> str:
    """The run's settings for every figure: the command (``settings``, from reproduce) or one read from the config."""
    runs = len({r["run"] for r in rows})
    quick = replace(config, ukfs=(), gps=()) == RemusConfig().quick()
    command = settings or f"abyssal reproduce remus{' --quick' if quick else ''} --seed {seed}"
    return (f"{command}: {runs} run(s) x {config.duration:g} s{' (QUICK: a smoke version)' if quick else ''}; GP "
            f"sizes {', '.join(map(str, config.sizes))}, training draws {', '.join(map(str, config.draws))}")


def _save(fig, path: Path, stamp: str, written: list, rect=(0, 0.03, 1, 1)) -> None:
    written.append(plots.save_figure(fig, path, stamp, rect=rect))


def training_data(prepared: dict, config: RemusConfig, path: Path, stamp: str, written: list) -> None:
    training = prepared["training"]
    draw = config.draws[0]
    sets = {n: s for (targets, n, d), s in prepared["sets"].items() if targets == "increments" and d == draw}
    fig, ax = plt.subplots(figsize=(9, 3.8))
    ax.plot(training.t, training.z[:, 0], color="0.75", lw=0.7, label="run 1, measured u (all 5 Hz samples)")
    if sets:
        pool_times = next(iter(sets.values())).pool_times
        pool = np.isin(training.t, pool_times)
        ax.plot(training.t[pool], training.z[pool, 0], ".", ms=2, color="0.35",
                label=f"40 % pool of draw {draw}, {len(pool_times)} points (denser at the start)")
        shown = [n for n in sorted(sets) if n < len(pool_times)]
        for k, n in reversed(list(enumerate(shown))):             # the larger sets first, the smaller on top
            sel = np.isin(training.t, sets[n].times)
            ax.plot(training.t[sel], training.z[sel, 0], plots.MARKERS[k], ms=7 - 2.5 * k / max(1, len(shown) - 1),
                    color=plots.PALETTE[k + 1], mfc="none", label=f"regressors, N = {n}")
        if max(sets) >= len(pool_times):
            ax.text(0.99, 0.04, f"N = {max(sets)}: the whole pool", transform=ax.transAxes, ha="right", fontsize=8)
    ax.set(xlabel="time t (s)", ylabel="surge speed u (m/s)",
           title=f"GP training data: run 1, training draw {draw}, nested sizes (cf. the paper's Fig. 3)")
    ax.legend(fontsize=7, loc="lower right", bbox_to_anchor=(1.0, 0.1))
    ax.grid(alpha=0.3)
    _save(fig, path, stamp, written)


def position_error(log, traces, ordered, path: Path, stamp: str, written: list, run_label: str) -> None:
    fig, axes = plt.subplots(2, 1, figsize=(10, 7.5), sharex=True)
    groups = (("UKF readings (the oracle knows the true model and noise)", [n for n in traces if not is_gp(n)], "UKF"),
              ("GP-UKF per GP size (regressors per state)", [n for n in traces if is_gp(n)], "GP-UKF"))
    t = log.t[1:]
    for ax, (title, names, kind) in zip(axes, groups):
        for k, name in enumerate(names):
            X, P = traces[name]
            s = style(name, ordered)
            err = np.hypot(X[1:, 6] - log.x[1:, 6], X[1:, 7] - log.x[1:, 7])
            ax.plot(t, err, lw=1.0, label=f"{name}: |error|", **_marked(s, len(t), k))
            ax.plot(t, np.sqrt(P[1:, 6, 6] + P[1:, 7, 7]), lw=0.8, alpha=0.6, color=s["color"], linestyle=(0, (1, 4)),
                    label=f"{name}: own 1-sigma (sparse dots)")
        theirs = paper.TABLE4[(kind, "prediction")]
        ax.plot([t[-1] * 1.015], [theirs], **plots.PAPER_STYLE, label=f"paper {kind}: Table 4 prediction {theirs} m "
                "(their RMSE over 800 s)")
        ax.set_yscale("log")
        ax.set_ylabel("horizontal position error (m)")
        ax.set_title(title, fontsize=10, loc="left")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=6.5, ncol=2, loc="lower right")
    axes[1].set_xlabel("time t (s)")
    fig.suptitle(f"Horizontal position error over time, {run_label} (x, y are never measured)", fontsize=11)
    _save(fig, path, stamp, written)


def rmse_vs_size(rows, ordered, path: Path, stamp: str, written: list) -> None:
    names = filter_names(rows)
    fig, ax = plt.subplots(figsize=(9, 5.5))
    gps = [n for n in names if is_gp(n)]
    sizes = sorted({int(n.split("N=")[1]) for n in gps})
    for targets in ("increments", "state"):
        series = [n for n in gps if ("(state)" in n) == (targets == "state")]
        if not series:
            continue
        s = style(series[0], ordered)
        xs = [int(n.split("N=")[1]) for n in series]
        means = [statistic(rows, n, "prediction").mean for n in series]
        label = "GP-UKF (next-state targets)" if targets == "state" else "GP-UKF (increment targets)"
        ax.plot(xs, means, color=s["color"], linestyle="-" if targets == "increments" else "--", lw=1.2,
                label=f"{label}: mean over draws")
        cases = sorted({c for n in series for c in draws_of(rows, n)}, key=lambda c: int(c.split()[-1]))
        for k, case in enumerate(cases):
            pts = [(int(n.split("N=")[1]) * (1 + 0.04 * (k - 1)), per_draw(rows, n, "prediction").get(case)) for n in series]
            pts = [(x, d) for x, d in pts if d is not None]
            ax.errorbar([x for x, _ in pts], [d.mean for _, d in pts],
                        yerr=[0 if not np.isfinite(d.sd) else d.sd for _, d in pts], fmt=plots.MARKERS[k],
                        color=s["color"], mfc="none" if targets == "state" else s["color"], ms=5, capsize=2, lw=0.8,
                        label=f"{label}, {case}: mean ± sd over its runs")
    for name in (n for n in names if not is_gp(n)):
        s = style(name, ordered)
        ax.axhline(statistic(rows, name, "prediction").mean, lw=1, label=f"{name} (mean over runs)", **_line(s))
    ax.plot([paper.REGRESSORS], [paper.TABLE4[("GP-UKF", "prediction")]], **plots.PAPER_STYLE,
            label=f"paper GP-UKF, Table 4 prediction {paper.TABLE4[('GP-UKF', 'prediction')]} m (~{paper.REGRESSORS} points)")
    left = min(sizes) * 0.6 if sizes else 50
    theirs_ukf = dict(plots.PAPER_STYLE, marker="s")
    ax.plot([left], [paper.TABLE4[("UKF", "prediction")]], **theirs_ukf,
            label=f"paper UKF, Table 4 prediction {paper.TABLE4[('UKF', 'prediction')]} m")
    ax.set(xscale="log", yscale="log", xlabel="GP regressors per state N",
           ylabel="horizontal position RMSE (m)",
           title="Horizontal position RMSE per GP size and training draw\n(filtered x, y: our reading of the paper's "
           "'prediction')")
    ticks = sorted(set(sizes) | {paper.REGRESSORS})
    ax.set_xticks(ticks, [str(n) for n in ticks])
    ax.set_xticks([], minor=True)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=6.5, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2, frameon=False)
    fig.set_size_inches(9, 7.5)
    _save(fig, path, stamp, written)


PANELS = (("velocities", ("u", "v", "w"), "m/s"), ("angular rates", ("p", "q", "r"), "rad/s"),
          ("position", ("x", "y", "z"), "m"), ("angles", ("phi", "theta", "psi"), "rad"))


def state_rmse(rows, ordered, path: Path, stamp: str, written: list) -> None:
    names = filter_names(rows)
    fig, axes = plt.subplots(2, 2, figsize=(11, 8))
    width = 0.8 / max(1, len(names))
    for ax, (title, states, unit) in zip(axes.flat, PANELS):
        centres = np.arange(len(states))
        for j, name in enumerate(names):
            s = style(name, ordered)
            values = [statistic(rows, name, f"rmse_{st}") for st in states]
            means = np.array([v.mean for v in values])
            sds = np.array([v.sd if np.isfinite(v.sd) else 0.0 for v in values])
            # log axis: a lower bar reaching zero or below is drawn down to a tenth of the mean (the title says so)
            lower = np.where(means - sds > 0, sds, 0.9 * means)
            ax.errorbar(centres - 0.4 + width * (j + 0.5), means, yerr=[lower, sds], fmt=s["marker"], color=s["color"],
                        mfc=s.get("markerfacecolor", s["color"]), ms=5, capsize=2, lw=0.8, label=name)
        for row, ls in (("UKF", "-"), ("GP-UKF", "--")):  # the paper's: a black line across the group, named
            for c, st in zip(centres, states):
                v = paper.TABLE3[row].get(st)
                if v is None:
                    continue
                ax.hlines(v, c - 0.44, c + 0.44, colors="black", linestyles=ls, lw=1.8, zorder=10,
                          label=f"THE PAPER's {row} (Table 3; quoted)" if c == centres[0] else None)
                ax.text(c + 0.45, v, f"paper {row}", fontsize=6, va="center", ha="left", zorder=10)
        ax.set_xticks(centres, states)
        ax.set_yscale("log")
        ax.set_ylabel(f"RMSE ({unit})")
        ax.set_title(title, fontsize=10, loc="left")
        ax.grid(axis="y", alpha=0.3, which="both")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=7, frameon=False, bbox_to_anchor=(0.5, 0.02))
    fig.suptitle("RMSE per state (Table 3): ours as coloured markers, the paper's as black lines\nUKF readings: mean ± "
                 "sd over runs; GP-UKF: mean ± sd between training draws (log axis: where mean − sd ≤ 0 the lower bar "
                 "stops at a tenth of the mean)", fontsize=9.5)
    _save(fig, path, stamp, written, rect=(0, 0.1, 1, 0.97))


def surge_error(log, traces, ordered, path: Path, stamp: str, written: list, run_label: str) -> None:
    """Moving RMS (10 s) of the surge error: the filters' errors are a fraction of the sensor noise they follow."""
    window = int(round(10.0 / LOG_DT))
    kernel = np.ones(window) / window

    def moving_rms(e):
        return np.sqrt(np.convolve(e**2, kernel, mode="valid"))

    fig, ax = plt.subplots(figsize=(10, 4.2))
    t = log.t[1:][window - 1:]
    ax.plot(t, moving_rms(log.z[1:, 0] - log.x[1:, 0]), color="0.6", lw=1.2, label="DVL u: measured - true")
    for k, (name, (X, _)) in enumerate(traces.items()):
        ax.plot(t, moving_rms(X[1:, 0] - log.x[1:, 0]), lw=1.0, label=name, **_marked(style(name, ordered), len(t), k))
    ax.set_yscale("log")
    ax.set(xlabel="time t (s)", ylabel="surge error, 10 s moving RMS (m/s)",
           title=f"Surge speed error, {run_label} (cf. the paper's Fig. 5)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7, ncol=3, loc="upper right")
    _save(fig, path, stamp, written)


def all_figures(rows, out: Path, config: RemusConfig, seed: int, prepared: dict, settings: str | None = None) -> list[Path]:
    from ..campaign import run_seeds

    out.mkdir(parents=True, exist_ok=True)
    ordered = tuple(filter_names(rows))
    stamp = settings_text(rows, config, seed, settings)
    written: list[Path] = []
    if prepared:
        training_data(prepared, config, out / "remus_training_data.png", stamp, written)
    _, log, traces = filter_run(config, run_seeds(seed, 1)[0])
    label = f"run 0 (training draw {config.draw_of_run(0)}, dt {LOG_DT:g} s)"
    position_error(log, traces, ordered, out / "remus_position_error.png", stamp, written, label)
    surge_error(log, traces, ordered, out / "remus_surge_error.png", stamp, written, label)
    rmse_vs_size(rows, ordered, out / "remus_rmse_vs_size.png", stamp, written)
    state_rmse(rows, ordered, out / "remus_state_rmse.png", stamp, written)
    return written
