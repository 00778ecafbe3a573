"""PNG figures of the reproduced experiments (matplotlib, Agg backend: no display needed)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .extras import require

require("matplotlib", "the experiment figures").use("Agg")
plt = require("matplotlib.pyplot", "the experiment figures")

FILTER_COLOURS = {"PF": "tab:gray", "CKF": "tab:blue", "CPF": "tab:orange", "MOGCPF": "tab:purple",
                  "EM-MOGCPF": "tab:red", "GS-CKF": "tab:green"}


#: hatches that tell apart the variants of one filter ("CKF (matched model)", "EM-MOGCPF N=1000") in its colour
VARIANT_HATCHES = ("", "//", "..", "xx", "\\\\", "++")


def _family(name: str) -> str:
    """The filter a labelled variant belongs to: "CKF (mismatched Q)" -> "CKF", "EM-MOGCPF N=1000" -> "EM-MOGCPF"."""
    return name.split(" (")[0].split(" N=")[0]


def _colour(name: str) -> str:
    return FILTER_COLOURS.get(_family(name), "black")


def _break_at_wraps(values: np.ndarray) -> np.ndarray:
    """A wrapped angle error with NaN where it jumps by more than pi, so no line crosses the plot."""
    out = values.astype(float).copy()
    out[1:][np.abs(np.diff(values)) > np.pi] = np.nan
    return out


def error_vs_time(times: np.ndarray, errors: dict[str, np.ndarray], labels, title: str, path: Path,
                  wrapped_panels=()) -> Path:
    """2 x 2 panels, one per state component, each with every filter's error over time.

    errors: {filter: (T, 4)}; labels: 4 axis labels. The y range of a panel covers the 99th
    percentile of every filter's |error| (a diverging filter's excursions are clipped, not hidden:
    its RMSE is in the table and the bar chart). Panels in wrapped_panels hold angle errors wrapped
    to (-pi, pi]; their lines break at the wraps.
    """
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True)
    for i, ax in enumerate(axes.flat):
        limit = 0.0
        for name, e in errors.items():
            values = _break_at_wraps(e[:, i]) if i in wrapped_panels else e[:, i]
            ax.plot(times, values, lw=0.8, color=_colour(name), label=name, alpha=0.9)
            limit = max(limit, float(np.percentile(np.abs(e[:, i]), 99)))
        ax.set_ylim(-1.15 * limit, 1.15 * limit)
        ax.axhline(0, color="black", lw=0.5)
        ax.set_ylabel(labels[i])
        ax.grid(alpha=0.3)
        ax.set_title(f"({'abcd'[i]}) {labels[i]}", fontsize=10, loc="left")
    for ax in axes[1]:
        ax.set_xlabel("time (s)")
    axes[0, 0].legend(ncol=3, fontsize=8, loc="upper left")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def rmse_bars(metrics: dict[str, dict], paper: dict[str, dict[str, float]] | None, title: str, path: Path) -> Path:
    """Grouped bars of our RMSE per axis and filter (like the paper's Figures 11-12); the paper's
    values as black diamonds over the filters it reports. Log scale: the filters differ by decades."""
    axes_names = ("x", "y", "z", "psi")
    filters = list(metrics)
    width = 0.8 / len(filters)
    fig, ax = plt.subplots(figsize=(10, 5.6))
    centres = np.arange(len(axes_names))
    variants: dict[str, int] = {}
    for j, name in enumerate(filters):
        offsets = centres - 0.4 + width * (j + 0.5)
        values = [metrics[name]["rmse"][a] for a in axes_names]
        k = variants[_family(name)] = variants.get(_family(name), -1) + 1
        ax.bar(offsets, values, width, color=_colour(name), hatch=VARIANT_HATCHES[k % len(VARIANT_HATCHES)],
               edgecolor="white", linewidth=0, label=f"{name} (ours)")
        if paper and name in paper:
            ax.plot(offsets, [paper[name][a] for a in axes_names], "kD", ms=4,
                    label="paper (Table 3)" if j == 0 or "paper (Table 3)" not in ax.get_legend_handles_labels()[1] else None)
    ax.set_xticks(centres, ["x (m)", "y (m)", "z (m)", "psi (rad)"])
    ax.set_yscale("log")
    ax.set_ylabel("RMSE")
    ax.grid(axis="y", alpha=0.3, which="both")
    ax.legend(ncol=4, fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.08), frameon=False)
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
