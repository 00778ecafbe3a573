"""The replay's figures (PNG, matplotlib's Agg backend), each one question a reviewer asks of a replayed log.

    track.png               where was it? the track (filtered, smoothed) over the fixes, east vs north, with 95 %
                            ellipses of the position at regular times (needs [frames] position)
    states.png              what did it estimate? each state over time with its ±2σ band
    innovations_<s>.png     did sensor s agree with the filter? each output's innovation with ±2√S, its gated
                            samples, and the NIS against its chi-square 95 % interval

Every figure is stamped with the log, the model and the filter in its bottom-left corner.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.stats import chi2

from ..extras import require
from .run import Replay

require("matplotlib", "the replay's figures", extra="replay").use("Agg")
plt = require("matplotlib.pyplot", "the replay's figures", extra="replay")

from ..plots import PALETTE, save_figure  # noqa: E402 (after the backend is chosen, with the replay's message)

FILTERED, SMOOTHED, FIX, GATED = PALETTE[0], PALETTE[1], "black", "#CC0000"
#: the radius of the 95 % ellipse of a 2-D Gaussian, in standard deviations
ELLIPSE_95 = float(np.sqrt(chi2.ppf(0.95, 2)))
ELLIPSES = 12
#: one marker per fix sensor (used fixes, hollow)
FIX_MARKERS = ("o", "s", "^", "D", "v")


def _settings(replay: Replay) -> str:
    smoothing = " + RTS smoother" if replay.smoothed is not None else ""
    return f"abyssal replay: {Path(replay.log.path).name}, model {replay.model.name}, {replay.filter_name}{smoothing}"


def _ellipse(ax, centre, C, color, **style) -> None:
    values, vectors = np.linalg.eigh(0.5 * (C + C.T))
    values = np.clip(values, 0.0, None)
    angle = np.linspace(0, 2 * np.pi, 73)
    circle = np.vstack([np.cos(angle), np.sin(angle)])
    points = centre[:, None] + ELLIPSE_95 * vectors @ (np.sqrt(values)[:, None] * circle)
    ax.plot(points[0], points[1], color=color, **style)


def _fix_group(status: str) -> str:
    return "used" if status in ("used", "partly gated", "tick partly gated") else ("gated" if status == "gated" else "other")


def track_figure(replay: Replay, path: Path) -> Path | None:
    position = replay.sensor_map.frames.position
    if position is None or position[0] is None:
        return None
    north, east = position[0], position[1]
    fig, ax = plt.subplots(figsize=(8.5, 7.5))
    tracks = [("filtered", replay.track, FILTERED)]
    if replay.smoothed is not None:
        tracks.append(("smoothed (RTS)", replay.smoothed, SMOOTHED))
    for label, track, color in tracks:
        ax.plot(track.x[:, east], track.x[:, north], color=color, lw=1.2, label=label)
        chosen = np.unique(np.searchsorted(track.t, np.linspace(track.t[0], track.t[-1], ELLIPSES)).clip(0, len(track.t) - 1))
        for i, k in enumerate(chosen):
            C = track.P[k][np.ix_([east, north], [east, north])]
            _ellipse(ax, np.array([track.x[k, east], track.x[k, north]]), C, color, lw=0.7, alpha=0.7,
                     label=f"95 % ellipses ({label})" if i == 0 else None)
    start = replay.track.x[0]
    ax.plot(start[east], start[north], marker="*", color=FILTERED, markersize=13, linestyle="none", label="start (x0)")
    for s, name in enumerate(replay.sensor_map.fixes):
        fixes = [m for m in replay.measurements if m.sensor == name and np.all(np.isfinite(m.z[:2]))]
        groups = {"used": (FIX_MARKERS[s % len(FIX_MARKERS)], FIX), "gated": ("x", GATED), "other": (".", "#888888")}
        for group, (marker, color) in groups.items():
            chosen = [m for m in fixes if _fix_group(m.status) == group]
            if not chosen:
                continue
            why = sorted({m.status for m in chosen})
            label = f"{name} fixes {group if group != 'other' else 'not used: ' + ', '.join(why)} ({len(chosen)})"
            ax.plot([m.z[1] for m in chosen], [m.z[0] for m in chosen], marker, color=color, markersize=5,
                    mfc="none" if group == "used" else color, linestyle="none", label=label)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    ax.set_title("track about the local origin (NED), filtered and smoothed, with 95 % position ellipses", fontsize=10)
    return save_figure(fig, path, _settings(replay), rect=(0, 0.02, 1, 1))


def states_figure(replay: Replay, path: Path) -> Path:
    model = replay.model
    n = model.n_x
    cols = 1 if n <= 4 else 2
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(6.5 * cols, 2.1 * rows + 0.8), sharex=True, squeeze=False)
    units = [q["unit"] for q in model.manifest["states"]]
    tracks = [("filtered", replay.track, FILTERED)]
    if replay.smoothed is not None:
        tracks.append(("smoothed (RTS)", replay.smoothed, SMOOTHED))
    for i in range(rows * cols):
        ax = axes.flat[i]
        if i >= n:
            ax.set_visible(False)
            continue
        for label, track, color in tracks:
            sigma = np.sqrt(np.clip(track.P[:, i, i], 0.0, None))
            ax.plot(track.t, track.x[:, i], color=color, lw=1.0, label=label)
            ax.fill_between(track.t, track.x[:, i] - 2 * sigma, track.x[:, i] + 2 * sigma, color=color, alpha=0.18,
                            lw=0, label=f"±2σ ({label})")
        ax.set_ylabel(f"{model.state_names[i]} ({units[i]})", fontsize=8)
        ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("t (s since t0)")
    handles, labels = axes.flat[0].get_legend_handles_labels()
    fig.legend(handles, labels, ncol=4, fontsize=8, loc="lower center", bbox_to_anchor=(0.5, 0.015), frameon=False)
    fig.suptitle(f"state estimates with ±2σ bands ({replay.filter_name})", fontsize=11)
    return save_figure(fig, path, _settings(replay), rect=(0, 0.05, 1, 1))


def innovations_figure(replay: Replay, sensor: str, path: Path) -> Path:
    spec = replay.model.sensor(sensor)
    outputs = [q["name"] for q in spec["outputs"]]
    units = [q["unit"] for q in spec["outputs"]]
    records = [m for m in replay.measurements if m.sensor == sensor]
    used = [m for m in records if m.innovation is not None]
    gated = [m for m in records if m.status == "gated"]
    m = len(outputs)
    fig, axes = plt.subplots(m + 1, 1, figsize=(9, 2.0 * (m + 1) + 0.8), sharex=True, squeeze=False)
    axes = axes[:, 0]
    t_used = np.array([r.t for r in used])
    dots = 3 if len(records) > 200 else 7
    for j, ax in enumerate(axes[:m]):
        if used:
            nu = np.array([r.innovation[j] for r in used])
            band = np.array([2 * np.sqrt(r.S[j, j]) if r.S is not None else np.nan for r in used])
            if np.isfinite(band).any():  # each update's own +-2 sqrt(S): a bar at its time (no line between updates)
                ax.vlines(t_used, -band, band, color="#999999", lw=0.6 if len(used) > 200 else 1.2, alpha=0.6,
                          label="±2√S of the update")
            ax.plot(t_used, nu, ".", color=FILTERED, markersize=dots, label="innovation (used)")
        if gated:
            ax.plot([r.t for r in gated], np.zeros(len(gated)), "|", color=GATED, markersize=10,
                    label=f"gated ({len(gated)})")
        ax.axhline(0, color="black", lw=0.5)
        ax.set_ylabel(f"{outputs[j]} ({units[j]})", fontsize=8)
        ax.grid(alpha=0.3)
    ax = axes[m]
    nis = [(r.t, r.nis, r.nis_dof) for r in used if r.nis_dof > 0 and np.isfinite(r.nis)]
    if nis:
        t, values, dof = (np.array(v) for v in zip(*nis))
        ax.semilogy(t, np.maximum(values, 1e-6), ".", color=FILTERED, markersize=dots, label="NIS (floored at 1e-6)")
        d = int(np.bincount(dof).argmax())
        low, high = chi2.ppf([0.025, 0.975], d)
        ax.axhline(low, color="#555555", lw=0.8, linestyle="--", label=f"95 % interval, {d} dof")
        ax.axhline(high, color="#555555", lw=0.8, linestyle="--")
        outside = np.mean((values < chi2.ppf(0.025, dof)) | (values > chi2.ppf(0.975, dof)))
        ax.set_title(f"NIS: mean {values.mean():.3g} (expected {dof.mean():.3g}), {100 * outside:.1f} % outside their "
                     "95 % intervals", fontsize=9, loc="left")
    else:
        ax.text(0.5, 0.5, "no NIS (not defined for a particle filter)" if replay.filter_name == "PF" else
                "no used update", transform=ax.transAxes, ha="center", va="center", fontsize=9)
        ax.set_yticks([])
    ax.set_ylabel("NIS", fontsize=8)
    ax.grid(alpha=0.3, which="both")
    ax.set_xlabel("t (s since t0)")
    handles = {}
    for a in axes:
        for h, label in zip(*a.get_legend_handles_labels()):
            handles.setdefault(label, h)
    fig.legend(list(handles.values()), list(handles), ncol=5, fontsize=8, loc="lower center",
               bbox_to_anchor=(0.5, 0.012), frameon=False)
    counts = replay.counts[sensor]
    fig.suptitle(f"sensor {sensor}: {counts['received']} received, {counts['used']} used, {counts['gated']} entries gated, "
                 f"{counts['late']} late, {counts['too late']} too late", fontsize=11)
    return save_figure(fig, path, _settings(replay), rect=(0, 0.05, 1, 1))


def write_figures(replay: Replay, folder: Path) -> list[Path]:
    """Every figure of the module docstring into folder (created); returns their paths."""
    folder.mkdir(parents=True, exist_ok=True)
    written = [track_figure(replay, folder / "track.png"), states_figure(replay, folder / "states.png")]
    written += [innovations_figure(replay, name, folder / f"innovations_{name}.png") for name in replay.sensor_map.sensors]
    return [p for p in written if p is not None]
