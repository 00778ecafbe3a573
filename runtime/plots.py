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

#: colour-blind-safe colours: Okabe & Ito (2008) and Tol's "muted" set (15), in the order they are handed out to
#: names no table lists
PALETTE = ("#0072B2", "#E69F00", "#44AA99", "#CC6677", "#117733", "#88CCEE", "#56B4E9", "#CC79A7", "#DDCC77",
           "#332288", "#D55E00", "#009E73", "#882255", "#999933", "#AA4499")
#: line styles and markers that tell filters apart where colours alone would not (print, many lines)
LINESTYLES = ("-", "--", "-.", ":")
MARKERS = ("o", "s", "^", "v", "P", "X", "<", ">", "h", "*")

#: the filters of each experiment's figures (families: a variant such as "CKF (matched model)" takes its family's
#: colour). Within one experiment every two colours differ by a CIEDE2000 distance of at least 15 in normal vision
#: and 10 as a protanope, deuteranope or tritanope sees them (Machado et al. 2009, severity 1), no two filters of
#: the four experiments share a colour (the old palette gave CPF, MCUPF, GP-UKF and fuzzy one vermillion and the PF
#: an orange beside it), and every filter keeps
#: its colour in every experiment: tests/scenarios/test_reproduce.py checks both.
FAMILIES_BY_EXPERIMENT = {
    "rov": ("PF", "CKF", "CPF", "MOGCPF", "EM-MOGCPF", "GS-CKF", "DR"),
    "cn": ("DR", "CKF", "MCUKF", "PF", "UPF", "HRUPF", "IVBCKF", "MCUPF", "MCC-UPF"),
    "tan": ("fuzzy", "oracle", "DR"),
    "remus": ("UKF", "GP-UKF", "oracle"),
}

#: the fixed look of every filter named in the four experiments: one colour per filter, never two alike (the
#: assignment maximises the smallest colour distance inside each experiment, FAMILIES_BY_EXPERIMENT); a name not
#: listed (a variant such as "CKF (matched model)" or "EM-MOGCPF N=1000") takes its family's colour with the next
#: line style
FILTER_STYLES = {
    # baselines and oracles: grey and black, dotted or dashed, so the methods stand out
    "DR": {"color": "#555555", "linestyle": ":", "marker": "x"},
    "dead reckoning": {"color": "#555555", "linestyle": ":", "marker": "x"},
    "oracle": {"color": "black", "linestyle": "--", "marker": "*"},
    # Kalman family
    "CKF": {"color": "#0072B2", "linestyle": "-", "marker": "o"},
    "UKF": {"color": "#882255", "linestyle": "-", "marker": "o"},
    "MCUKF": {"color": "#56B4E9", "linestyle": "-", "marker": "s"},
    "IVBCKF": {"color": "#332288", "linestyle": "-", "marker": "^"},
    "GS-CKF": {"color": "#88CCEE", "linestyle": "-", "marker": "v"},
    "GP-UKF": {"color": "#999933", "linestyle": "-", "marker": "D"},
    "EKF": {"color": "#77AADD", "linestyle": "-", "marker": "o"},       # in no experiment's figures
    "HuberUKF": {"color": "#BBCC33", "linestyle": "-", "marker": "s"},  # in no experiment's figures
    # particle family
    "PF": {"color": "#E69F00", "linestyle": "--", "marker": "P"},
    "CPF": {"color": "#44AA99", "linestyle": "--", "marker": "X"},
    "UPF": {"color": "#CC79A7", "linestyle": "--", "marker": "<"},
    "HRUPF": {"color": "#DDCC77", "linestyle": "--", "marker": ">"},
    "MCUPF": {"color": "#D55E00", "linestyle": "-", "marker": "D"},
    "MCC-UPF": {"color": "#009E73", "linestyle": "--", "marker": "h"},
    "MOGCPF": {"color": "#CC6677", "linestyle": "-.", "marker": "h"},
    "EM-MOGCPF": {"color": "#117733", "linestyle": "-", "marker": "D"},
    "fuzzy": {"color": "#AA4499", "linestyle": "-", "marker": "D"},
}

#: the paper's own values in a figure: black, hollow, drawn above everything (never hidden by our lines)
PAPER_STYLE = {"color": "black", "marker": "D", "markerfacecolor": "none", "markersize": 7, "linestyle": "none",
               "markeredgewidth": 1.4, "zorder": 10}

# hatches that tell apart the variants of one filter ("CKF (matched model)", "EM-MOGCPF N=1000") in its colour, drawn
# with a near-black outline (VARIANT_EDGE) that stands out on every colour (a tint or shade of the family's colour
# would come near another filter's colour for a colour-blind reader)
VARIANT_EDGE = "#222222"
VARIANT_HATCHES = ("", "//", "..", "xx", "\\\\", "++")


#: suffixes that name a variant of a filter ("MCUPF tuned": the same filter with other noise matrices)
VARIANT_SUFFIXES = (" tuned",)
#: a swept parameter drawn as an ordered colour ramp (viridis: ordered in lightness, readable in every colour vision)
#: rather than as filters:
#: TAN's fixed process-noise sigma, "sigma = 2 m" (SEQUENTIAL_RANGE: its smallest and largest value)
SEQUENTIAL_PREFIX, SEQUENTIAL_RANGE = "sigma = ", (1.0, 6.0)


def _family(name: str) -> str:
    """The filter a labelled variant belongs to: "CKF (mismatched Q)" -> "CKF", "EM-MOGCPF N=1000" -> "EM-MOGCPF",
    "MCUPF tuned" -> "MCUPF"."""
    name = name.split(" (")[0].split(" N=")[0]
    for suffix in VARIANT_SUFFIXES:
        name = name.removesuffix(suffix)
    return name


def sequential_style(name: str) -> dict | None:
    """The look of a value of a swept parameter ("sigma = 3 m"): its place on the viridis ramp, a marker by value;
    None for any other name."""
    if not name.startswith(SEQUENTIAL_PREFIX):
        return None
    try:
        value = float(name.removeprefix(SEQUENTIAL_PREFIX).split()[0])
    except ValueError:
        return None
    low, high = SEQUENTIAL_RANGE
    position = 0.12 + 0.76 * min(max((value - low) / (high - low), 0.0), 1.0)  # the ends: neither near black nor pale
    from matplotlib import colormaps
    from matplotlib.colors import to_hex

    return {"color": to_hex(colormaps["viridis"](position)), "linestyle": "-",
            "marker": MARKERS[int(round(value - low)) % len(MARKERS)]}


def filter_style(name: str, ordered: tuple[str, ...] = ()) -> dict:
    """The look of a filter in every figure: {"color", "linestyle", "marker"} (matplotlib keywords).

    A name in FILTER_STYLES keeps its look; a variant of a listed family ("CKF (matched model)", "MCUPF tuned")
    keeps the family's colour and marker with a line style chosen by its place among the family's variants in
    ``ordered``; a value of a swept parameter ("sigma = 3 m") its place on a colour ramp (sequential_style); any
    other unlisted name gets a colour of PALETTE by its place among the unlisted names of ``ordered``, skipping the
    colours the listed names of ``ordered`` already have (give every figure of one experiment the same ``ordered``
    list, so a filter looks the same in all of them and no two filters of it share a colour while the palette
    lasts)."""
    if name in FILTER_STYLES:
        return dict(FILTER_STYLES[name])
    sequential = sequential_style(name)
    if sequential is not None:
        return sequential
    family = _family(name)
    if family in FILTER_STYLES:
        style = dict(FILTER_STYLES[family])
        variants = [n for n in ordered if _family(n) == family and n != family]
        k = variants.index(name) if name in variants else 0
        others = [ls for ls in LINESTYLES if ls != style["linestyle"]]  # never the family's own line style
        style["linestyle"] = others[k % len(others)]
        return style
    taken = {FILTER_STYLES[_family(n)]["color"] for n in ordered if _family(n) in FILTER_STYLES}
    free = [c for c in PALETTE if c not in taken] or list(PALETTE)
    unlisted = [n for n in ordered if _family(n) not in FILTER_STYLES and sequential_style(n) is None]
    k = unlisted.index(name) if name in unlisted else zlib.crc32(name.encode()) % len(PALETTE)
    return {"color": free[k % len(free)], "linestyle": LINESTYLES[(k // len(free)) % len(LINESTYLES)],
            "marker": MARKERS[k % len(MARKERS)]}


def stamp_settings(fig, text: str) -> None:
    """Write the run's settings ("quick run: 3 runs x 300 s, seed 0") in the figure's bottom-left corner, so a
    figure says where it came from wherever it is copied to."""
    fig.text(0.005, 0.005, text, fontsize=7, color="#444444", ha="left", va="bottom")


def save_figure(fig, path, settings: str | None = None, *, rect=None, dpi: int = 110):
    """Stamp the run's settings (``stamp_settings``), lay the figure out (``tight_layout(rect=rect)``; rect None:
    the figure keeps its own layout), write it to path and close it; returns path."""
    if settings:
        stamp_settings(fig, settings)
    if rect is not None:
        fig.tight_layout(rect=rect)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


def plain_log_labels(ax, axis: str = "y") -> None:
    """Tick labels of a log axis as plain numbers (0.3, 1, 20) rather than 3 x 10^-1."""
    from matplotlib.ticker import FuncFormatter

    def minor(value, _):  # label 2, 3 and 5 times a power of ten only, so the labels never crowd
        if value <= 0:
            return ""
        digit = round(value / 10 ** np.floor(np.log10(value)))
        return f"{value:g}" if digit in (2, 3, 5) else ""

    target = ax.yaxis if axis == "y" else ax.xaxis
    target.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
    target.set_minor_formatter(FuncFormatter(minor))


def _break_at_wraps(values: np.ndarray) -> np.ndarray:
    """A wrapped angle error with NaN where it jumps by more than pi, so no line crosses the plot."""
    out = values.astype(float).copy()
    out[1:][np.abs(np.diff(values)) > np.pi] = np.nan
    return out


def error_vs_time(times: np.ndarray, errors: dict[str, np.ndarray], labels, title: str, path: Path,
                  wrapped_panels=(), *, ordered: tuple[str, ...] = (), settings: str | None = None,
                  scales=None) -> Path:
    """2 x 2 panels, one per state component, each with every filter's error over time (the paper's error plots).

    errors: {filter: (T, 4)}; labels: 4 axis labels with their units ("x error (m)"); scales: optional factor per
    component applied before plotting (e.g. 180/pi for an angle in deg: the label must say the unit plotted).
    Each filter has its ``filter_style`` (``ordered``: the experiment's filter list). The y range of a panel
    covers the 99th percentile of every filter's |error| (a diverging filter's excursions are clipped, not
    hidden: its RMSE is in the table and the bar chart). Panels in wrapped_panels hold angle errors wrapped to
    (-pi, pi] (before scaling); their lines break at the wraps. settings: the run's settings, stamped in a corner.
    """
    ordered = tuple(ordered) or tuple(errors)
    scales = np.ones(4) if scales is None else np.asarray(scales, dtype=float)
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True)
    for i, ax in enumerate(axes.flat):
        limit = 0.0
        for name, e in errors.items():
            values = (_break_at_wraps(e[:, i]) if i in wrapped_panels else e[:, i]) * scales[i]
            style = filter_style(name, ordered)
            ax.plot(times, values, lw=0.9, color=style["color"], linestyle=style["linestyle"], label=name, alpha=0.9)
            finite = np.abs(e[:, i][np.isfinite(e[:, i])]) * scales[i]
            if finite.size:
                limit = max(limit, float(np.percentile(finite, 99)))
        if limit > 0:
            ax.set_ylim(-1.15 * limit, 1.15 * limit)
        ax.axhline(0, color="black", lw=0.5)
        ax.set_ylabel(labels[i])
        ax.grid(alpha=0.3)
        ax.set_title(f"({'abcd'[i]}) {labels[i]}", fontsize=10, loc="left")
    for ax in axes[1]:
        ax.set_xlabel("time (s)")
    handles, names = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, names, ncol=min(6, len(names)), fontsize=8, loc="lower center", bbox_to_anchor=(0.5, 0.02),
               frameon=False)
    fig.suptitle(title)
    return save_figure(fig, path, settings, rect=(0, 0.07, 1, 1))


def rmse_bars(metrics: dict[str, dict], paper: dict[str, dict[str, float]] | None, title: str, path: Path, *,
              panels=((("x", "y", "z"), "RMSE (m)"), (("psi",), "RMSE (rad)")), paper_axes=None,
              paper_label: str = "paper (Table 3)", notes: dict | None = None, ordered: tuple[str, ...] = (),
              settings: str | None = None) -> Path:
    """Grouped bars of our RMSE per axis and filter (like the paper's Figures 11-12), one panel per unit.

    metrics: {filter: {"rmse": {axis: value}, "rmse_sd": {axis: sd over runs} (optional: drawn as error bars)}};
    panels: ((axes, y label with its unit), ...): axes of one unit share a panel, so no axis shows two units.
    paper: {filter: {axis: value}}, drawn as PAPER_STYLE markers (hollow, black) in the shape of the filter's own
    marker on the filter's own bar, one legend entry per filter ("<paper_label>: CKF"), above every bar and kept
    out of the legend's way (the legend sits below the panels), on the axes of ``paper_axes`` only (default: all;
    leave an axis out where the paper's unit is not known). A variant of a filter (the second "CKF ...") keeps the
    family's colour, outlined and hatched in near-black (VARIANT_EDGE), one hatch per variant. notes: {panel index: text} written inside that
    panel. Log scale: the filters differ by decades. ordered: the experiment's filter list (styles).
    """
    filters = list(metrics)
    ordered = tuple(ordered) or tuple(filters)
    paper_axes = set(paper_axes) if paper_axes is not None else {a for axes, _ in panels for a in axes}
    sizes = [len(axes) for axes, _ in panels]
    fig, axs = plt.subplots(1, len(panels), figsize=(4.2 * sum(sizes) + 1.5, 5.6), squeeze=False,
                            gridspec_kw={"width_ratios": sizes})
    width = 0.84 / len(filters)
    handles: dict[str, object] = {}
    for p, (axes_names, ylabel) in enumerate(panels):
        ax = axs[0, p]
        centres = np.arange(len(axes_names))
        variants: dict[str, int] = {}
        for j, name in enumerate(filters):
            offsets = centres - 0.42 + width * (j + 0.5)
            values = [metrics[name]["rmse"][a] for a in axes_names]
            sd = metrics[name].get("rmse_sd", {})
            errors = [sd.get(a, np.nan) for a in axes_names]
            k = variants[_family(name)] = variants.get(_family(name), -1) + 1
            bars = ax.bar(offsets, values, width, color=filter_style(name, ordered)["color"],
                          hatch=VARIANT_HATCHES[k % len(VARIANT_HATCHES)], edgecolor=VARIANT_EDGE if k else "white",
                          linewidth=0.9 if k else 0.4, yerr=[e if np.isfinite(e) else 0.0 for e in errors],
                          ecolor="#333333", error_kw={"elinewidth": 0.8, "capsize": 1.5})
            handles.setdefault(f"{name} (ours)", bars)
            if paper and name in paper:
                shown = [(o, paper[name][a]) for o, a in zip(offsets, axes_names) if a in paper_axes and a in paper[name]]
                if shown:
                    look = {**PAPER_STYLE, "marker": filter_style(_family(name))["marker"]}
                    (line,) = ax.plot([o for o, _ in shown], [v for _, v in shown], **look)
                    handles.setdefault(f"{paper_label}: {_family(name)}", line)
        ax.set_xticks(centres, list(axes_names))
        ax.set_yscale("log")
        plain_log_labels(ax)
        ax.set_ylabel(ylabel)
        ax.grid(axis="y", alpha=0.3, which="both")
        if notes and p in notes:  # above the panel, where no bar reaches
            ax.set_title(notes[p], fontsize=7, loc="left")
    fig.legend(list(handles.values()), list(handles), ncol=4, fontsize=8, loc="lower center",
               bbox_to_anchor=(0.5, 0.02), frameon=False)
    fig.suptitle(title)
    rows_of_legend = -(-len(handles) // 4)
    return save_figure(fig, path, settings, rect=(0, 0.035 + 0.045 * rows_of_legend, 1, 1))
