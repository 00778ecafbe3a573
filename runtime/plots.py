"""PNG figures of the reproduced experiments (matplotlib, Agg backend: no display needed)."""
from __future__ import annotations

import zlib
from pathlib import Path

import numpy as np

from .extras import require

require("matplotlib", "the experiment figures").use("Agg")
plt = require("matplotlib.pyplot", "the experiment figures")

# ---------------------------------------------------------------------------------------------
# one look per filter, shared by every figure of every experiment

#: colour-blind-safe colours (Okabe & Ito 2008, then Tol's "muted" set), in the order they are handed out
PALETTE = ("#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#882255", "#117733", "#332288",
           "#999933", "#AA4499", "#44AA99", "#DDCC77", "#661100")
#: line styles and markers that tell filters apart where colours alone would not (print, many lines)
LINESTYLES = ("-", "--", "-.", ":")
MARKERS = ("o", "s", "^", "v", "P", "X", "<", ">", "h", "*")

#: the fixed look of every filter named in the four experiments; a name not listed (a variant such as
#: "CKF (matched model)" or "EM-MOGCPF N=1000") takes its family's colour with the next line style
FILTER_STYLES = {
    # baselines and oracles: greys and black, dotted or dashed, so the methods stand out
    "DR": {"color": "#555555", "linestyle": ":", "marker": "x"},
    "dead reckoning": {"color": "#555555", "linestyle": ":", "marker": "x"},
    "oracle": {"color": "black", "linestyle": "--", "marker": "*"},
    # Kalman family
    "EKF": {"color": PALETTE[8], "linestyle": "-", "marker": "o"},
    "UKF": {"color": PALETTE[5], "linestyle": "-", "marker": "o"},
    "CKF": {"color": PALETTE[0], "linestyle": "-", "marker": "o"},
    "MCUKF": {"color": PALETTE[2], "linestyle": "-", "marker": "s"},
    "HuberUKF": {"color": PALETTE[9], "linestyle": "-", "marker": "s"},
    "IVBCKF": {"color": PALETTE[6], "linestyle": "-", "marker": "^"},
    "GS-CKF": {"color": PALETTE[7], "linestyle": "-", "marker": "v"},
    "GP-UKF": {"color": PALETTE[1], "linestyle": "-", "marker": "D"},
    # particle family
    "PF": {"color": PALETTE[4], "linestyle": "--", "marker": "P"},
    "CPF": {"color": PALETTE[1], "linestyle": "--", "marker": "X"},
    "UPF": {"color": PALETTE[3], "linestyle": "--", "marker": "<"},
    "HRUPF": {"color": PALETTE[10], "linestyle": "--", "marker": ">"},
    "MCUPF": {"color": PALETTE[1], "linestyle": "-", "marker": "D"},
    "MCC-UPF": {"color": PALETTE[11], "linestyle": "--", "marker": "h"},
    "MOGCPF": {"color": PALETTE[3], "linestyle": "-.", "marker": "h"},
    "EM-MOGCPF": {"color": PALETTE[13], "linestyle": "-", "marker": "D"},
    "fuzzy": {"color": PALETTE[1], "linestyle": "-", "marker": "D"},
}

#: the paper's own values in a figure: black, hollow, drawn above everything (never hidden by our lines)
PAPER_STYLE = {"color": "black", "marker": "D", "markerfacecolor": "none", "markersize": 7, "linestyle": "none",
               "markeredgewidth": 1.4, "zorder": 10}

# hatches that tell apart the variants of one filter ("CKF (matched model)", "EM-MOGCPF N=1000") in its colour
VARIANT_HATCHES = ("", "//", "..", "xx", "\\\\", "++")


def _family(name: str) -> str:
    """The filter a labelled variant belongs to: "CKF (mismatched Q)" -> "CKF", "EM-MOGCPF N=1000" -> "EM-MOGCPF"."""
    return name.split(" (")[0].split(" N=")[0]


def filter_style(name: str, ordered: tuple[str, ...] = ()) -> dict:
    """The look of a filter in every figure: {"color", "linestyle", "marker"} (matplotlib keywords).

    A name in FILTER_STYLES keeps its look; a variant of a listed family ("CKF (matched model)") keeps the
    family's colour and marker with a line style chosen by its place among the family's variants in
    ``ordered``; a fixed-sigma family ("sigma=1 m" ... "sigma=6 m") or any other unlisted name gets a colour of
    PALETTE by its index in ``ordered`` (give every figure of one experiment the same ``ordered`` list, so a
    filter looks the same in all of them)."""
    if name in FILTER_STYLES:
        return dict(FILTER_STYLES[name])
    family = _family(name)
    if family in FILTER_STYLES:
        style = dict(FILTER_STYLES[family])
        variants = [n for n in ordered if _family(n) == family and n != family]
        k = variants.index(name) + 1 if name in variants else 1
        style["linestyle"] = LINESTYLES[k % len(LINESTYLES)]
        return style
    k = ordered.index(name) if name in ordered else zlib.crc32(name.encode()) % len(PALETTE)
    return {"color": PALETTE[k % len(PALETTE)], "linestyle": LINESTYLES[(k // len(PALETTE)) % len(LINESTYLES)],
            "marker": MARKERS[k % len(MARKERS)]}


def _colour(name: str) -> str:
    return filter_style(name)["color"]


def stamp_settings(fig, text: str) -> None:
    """Write the run's settings ("quick run: 3 runs x 300 s, seed 0") in the figure's bottom-left corner, so a
    figure says where it came from wherever it is copied to."""
    fig.text(0.005, 0.005, text, fontsize=7, color="#444444", ha="left", va="bottom")


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
