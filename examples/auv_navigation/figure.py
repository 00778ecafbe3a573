"""The example's figure: one dive's track over its fixes, its depth and errors over time with the bottom-lock loss and
the surface marked, and every seed's RMSE per filter and handling."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

COLOURS = {"stamp": "tab:blue", "arrival": "tab:red", "dropped": "tab:orange", "smoothed": "tab:green"}
NAMES = {"stamp": "USBL fused at its stamp", "arrival": "USBL fused at arrival", "dropped": "USBL dropped",
         "smoothed": "smoothed (RTS), at stamp"}


def _phases(ax, mission, label=True):
    """Shade the surface phases (GNSS) and the bottom-lock loss."""
    end = mission.duration
    for a, b in ((0.0, mission.surface_time), (end - mission.surface_time, end)):
        ax.axvspan(a, b, color="tab:cyan", alpha=0.15, lw=0, label="at the surface (GNSS)" if label and a == 0 else None)
    ax.axvspan(*mission.lock_loss, color="0.5", alpha=0.25, lw=0, label="DVL bottom lock lost" if label else None)


def _zoom(ax, dive, tracks, name, truth, t, at):
    """An inset of the track +-4 m around the truth at time `at` (the end of the bottom-lock loss): every handling
    over the 20 s around it, and the USBL fixes pinged then."""
    k = int(np.searchsorted(t, at))
    centre = truth[k, 6:8]
    near = np.abs(t - at) < 10
    inset = ax.inset_axes([0.27, 0.12, 0.46, 0.36])
    inset.plot(truth[near, 7], truth[near, 6], "k-", lw=2)
    for handling in ("arrival", "dropped", "stamp"):
        x = tracks[(name, handling)].x
        inset.plot(x[near, 7], x[near, 6], "-", lw=1.2, color=COLOURS[handling])
    x = tracks[(name, "stamp")].smoothed[0]
    inset.plot(x[near, 7], x[near, 6], "-", lw=1.2, color=COLOURS["smoothed"])
    fixes = [m.z for m in dive.measurements if m.sensor == "usbl" and abs(m.stamp - at) < 10]
    inset.plot([z[1] for z in fixes], [z[0] for z in fixes], "o", color="tab:purple", mec="k", ms=7)
    inset.plot(*centre[::-1], "k+", ms=10)
    inset.set(xlim=(centre[1] - 4, centre[1] + 4), ylim=(centre[0] - 4, centre[0] + 4), aspect="equal")
    inset.set_title(f"+-4 m around + (t = {at:g} s); colours of the error panel", fontsize=8)
    inset.tick_params(labelsize=7)
    ax.indicate_inset_zoom(inset, edgecolor="0.3")


def draw(trace: dict, rows: list, mission, path: Path) -> Path:
    dive, tracks = trace["dive"], trace["tracks"]
    name = "EKF" if ("EKF", "stamp") in tracks else sorted(tracks)[0][0]
    stamp = tracks[(name, "stamp")]
    truth = dive.truth_at(stamp.t)
    seed = rows[0]["seed"]
    fig = plt.figure(figsize=(15, 9.5))
    grid = fig.add_gridspec(3, 2, width_ratios=(1.0, 1.25), height_ratios=(0.55, 1.0, 1.0))
    track_ax = fig.add_subplot(grid[:2, 0])
    depth_ax = fig.add_subplot(grid[0, 1])
    error_ax = fig.add_subplot(grid[1, 1], sharex=depth_ax)
    seeds_ax = fig.add_subplot(grid[2, :])

    # the track over the fixes (east right, north up)
    usbl = [m for m in dive.measurements if m.sensor == "usbl"]
    gnss = [m for m in dive.measurements if m.sensor == "gnss"]
    track_ax.plot(truth[:, 7], truth[:, 6], "k-", lw=2.2, label="truth")
    lost = (stamp.t >= mission.lock_loss[0]) & (stamp.t < mission.lock_loss[1])
    track_ax.plot(truth[lost, 7], truth[lost, 6], "-", color="0.6", lw=6, alpha=0.6, zorder=1,
                  label="truth, DVL bottom lock lost")
    track_ax.plot([m.z[1] for m in gnss], [m.z[0] for m in gnss], "x", color="tab:cyan", ms=4, label="GNSS fixes")
    track_ax.plot([m.z[1] for m in usbl], [m.z[0] for m in usbl], "o", color="tab:purple", ms=3.5, label="USBL fixes")
    track_ax.plot(stamp.x[:, 7], stamp.x[:, 6], "-", color=COLOURS["stamp"], lw=1.1, label=f"{name}, {NAMES['stamp']}")
    track_ax.plot(stamp.smoothed[0][:, 7], stamp.smoothed[0][:, 6], "-", color=COLOURS["smoothed"], lw=1.1,
                  label=f"{name}, {NAMES['smoothed']}")
    track_ax.plot(truth[0, 7], truth[0, 6], "k^", ms=9, label="start (at the surface)")
    track_ax.set(xlabel="east [m]", ylabel="north [m]", aspect="equal",
                 title=f"Seed {seed:g}: the track over the fixes ({mission.duration:g} s)")
    track_ax.legend(loc="upper center", bbox_to_anchor=(0.5, 0.8), fontsize=8, framealpha=0.9)
    _zoom(track_ax, dive, tracks, name, truth, stamp.t, mission.lock_loss[1])

    # depth, with the phases
    _phases(depth_ax, mission)
    depth_ax.plot(stamp.t, truth[:, 8], "k-", lw=1.5, label="true depth")
    depth_ax.axhline(mission.gnss_depth, color="tab:cyan", ls=":", lw=1, label=f"GNSS above {mission.gnss_depth:g} m")
    depth_ax.invert_yaxis()
    depth_ax.set(ylabel="depth [m]", title="Depth, surface phases and the bottom-lock loss")
    depth_ax.legend(loc="center", fontsize=8, ncol=2)
    plt.setp(depth_ax.get_xticklabels(), visible=False)

    # horizontal error over time, per handling, and the filter's own 1-sigma
    _phases(error_ax, mission, label=False)
    for handling in ("arrival", "dropped", "stamp"):
        track = tracks[(name, handling)]
        error = np.hypot(*(track.x[:, 6:8] - truth[:, 6:8]).T)
        error_ax.plot(track.t, error, color=COLOURS[handling], lw=1.0, label=f"{name}, {NAMES[handling]}")
    smoothed_error = np.hypot(*(stamp.smoothed[0][:, 6:8] - truth[:, 6:8]).T)
    error_ax.plot(stamp.t, smoothed_error, color=COLOURS["smoothed"], lw=1.0, label=f"{name}, {NAMES['smoothed']}")
    sigma = np.sqrt(stamp.P[:, 6, 6] + stamp.P[:, 7, 7])
    error_ax.plot(stamp.t, sigma, "--", color=COLOURS["stamp"], lw=0.8, label="its own sqrt(P_nn + P_ee), at stamp")
    error_ax.set(xlabel="time [s]", ylabel="horizontal error [m]",
                 title="Horizontal position error", xlim=(0, mission.duration), ylim=(0, None))
    error_ax.legend(loc="upper right", fontsize=8, ncol=2)

    # every seed's RMSE per filter and handling
    filters = list(dict.fromkeys(r["filter"] for r in rows))
    order = ("stamp", "arrival", "dropped", "smoothed")
    positions, labels = [], []
    rng = np.random.default_rng(0)
    for i, f in enumerate(filters):
        for j, handling in enumerate(order):
            values = [r["rmse_xy"] for r in rows if r["filter"] == f and r["track"] == handling]
            at = i * (len(order) + 1) + j
            seeds_ax.plot(at + rng.uniform(-0.18, 0.18, len(values)), values, "o", color=COLOURS[handling], ms=3.5,
                          alpha=0.7, label=NAMES[handling] if i == 0 else None)
            seeds_ax.plot([at - 0.3, at + 0.3], [np.mean(values)] * 2, "k-", lw=2)
            positions.append(at)
            labels.append(f"{f}\n{handling}")
    n_seeds = len({r["seed"] for r in rows})
    seeds_ax.set_xticks(positions, labels, fontsize=8)
    seeds_ax.set(ylabel="horizontal RMSE [m]", ylim=(0, None),
                 title=f"Every seed's horizontal RMSE ({n_seeds} seeds; bar: mean)")
    seeds_ax.legend(loc="upper right", fontsize=8, ncol=4)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
