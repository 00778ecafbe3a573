"""Seed 003's track survey: on how many of a map's tracks does a fixed sigma keep every run?

`abyssal reproduce tan-survey`. The paper's claim (Figs. 8-9: at 0.1 m/s, sigma = 2-3 m tracks where 1 m and 4-6 m
lose) is about one track of its IBCAO area; on our maps its printed start is an arbitrary point, and the tan
experiment's few tracks cannot say whether a failure belongs to the track or to the map. The survey runs the
claim on every admissible track of each map instead (scenario.admissible_starts: starts on a ``grid_km`` grid,
headings 0/90/180/270 deg, the path at 0.15 m/s >= 2 km inside the map, at most 10 % flat at 0.1 m/s) and counts
the tracks on which a fixed sigma kept every run within ``lost_m``.

* Per track and run: one truth at ``current`` (scenario.simulate, the tan experiment's set-up: 30 000 s at 1 Hz,
  N = 1000, the altimeter's 5 m), and the SIR with each fixed sigma of ``sigmas`` on it (experiment.run_filter).
  A run is stopped at the first step whose error exceeds ``lost_m`` (it is lost then; nothing after it can
  change that), so a lost run's error columns cover the steps up to that one.
* Draws: keyed by the map, the track's label and the filter's name (``derive``), independent of the tan
  experiment's streams and of which other tracks are configured.
* Rows: one per run x case (map/track label) x filter x metric: lost (0/1), lost_at_s (lost runs), max_error_m,
  and mean_error_m of the runs that kept the track (a lost run's mean would be that of a truncated run).
* Report: per map, the tracks where each sigma (and either) kept every run, by the track's drift-contour angle
  and by its weakest slope (the terrain measures of scenario.characterise, no filter involved); the tracks with
  the largest margin; the survey's pick (below). Figure: every surveyed track over its map, coloured by outcome.
* The pick (scenario.TRACKS' ``survey_pick``): among the tracks where a fixed sigma kept every run, the one whose
  worst run stayed furthest below ``lost_m`` (the smallest max error over that sigma's runs). The tan experiment
  runs it with its own, independent streams: the survey selects, the campaign confirms.
"""
from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..campaign import run_index
from ..tables import over_runs
from .experiment import TanConfig, aligned, named_stream, run_filter, sigma_name
from .scenario import CURRENTS, admissible_starts, get_map, nominal_path, simulate

EXTRA_COLUMNS: tuple[str, ...] = ()
#: drift-contour angle bins (deg) of the report
ANGLE_BINS = ((0.0, 20.0), (20.0, 35.0), (35.0, 50.0), (50.0, 90.0))


@dataclass(frozen=True)
class SurveyConfig:
    """The survey's set-up: the tan experiment's (TanConfig) for the filter and the truth, plus the grid."""

    duration_s: float = 30000.0
    n_particles: int = 1000
    sigmas: tuple[float, ...] = (2.0, 3.0)
    maps: tuple[str, ...] = ("arctic", "arctic_cells", "topobathy")
    current: str = "0.1"
    grid_km: float = 10.0
    lost_m: float = 1000.0
    map_seed: int = 0
    quick_run: bool = False

    def quick(self) -> "SurveyConfig":
        """3000 s runs (a tenth) on a 20 km grid, on the smooth synthetic map only: the pipeline as a smoke test, not
        evidence (the drift is ~420 m after 3000 s)."""
        return replace(self, duration_s=3000.0, grid_km=20.0, maps=("arctic",), quick_run=True)

    def tan(self) -> TanConfig:
        """The tan experiment's set-up these runs share (simulate, run_filter)."""
        return TanConfig(duration_s=self.duration_s, n_particles=self.n_particles, sigmas=self.sigmas, fuzzy=(),
                         maps=self.maps, currents=(self.current,), lost_m=self.lost_m, map_seed=self.map_seed,
                         oracle_sigma=None)

    def tracks(self, map_name: str) -> list[tuple[str, tuple[float, float, float], dict]]:
        """(label, start, terrain measures) of every admissible track of a map (scenario.admissible_starts)."""
        key = (map_name, self.map_seed, self.grid_km, self.duration_s)
        if key not in _TRACKS:
            speed = TanConfig().speed
            starts = admissible_starts(get_map(map_name, self.map_seed), self.duration_s, speed,
                                       (CURRENTS[self.current][0], CURRENTS["0.15"][0]), self.grid_km)
            _TRACKS[key] = [(track_label(start), start, terrain.as_dict()) for start, terrain in starts]
        return _TRACKS[key]

    def settings(self, runs: int, seed: int) -> str:
        return (f"abyssal reproduce tan-survey{' --quick' if self.quick_run else ''}: {runs} run(s) per track, "
                f"{self.duration_s:g} s per run, N = {self.n_particles}, {self.grid_km:g} km grid, seed {seed}")


Config = SurveyConfig
_TRACKS: dict = {}


def track_label(start) -> str:
    """x<km>_y<km>_h<deg>: the start's position and heading."""
    return f"x{start[0] / 1e3:g}_y{start[1] / 1e3:g}_h{math.degrees(start[2]):.0f}"


def survey_case(map_name: str, label: str) -> str:
    return f"{map_name}/{label}"


def run_one(config: SurveyConfig, seed: np.random.SeedSequence) -> list[dict]:
    """Every admissible track of every map, one truth each and every fixed sigma on it, as tidy rows."""
    from abyssal.generated import load

    bundle = load("tan3dof")
    tan = config.tan()
    run = run_index(seed)
    rows = []
    for m in config.maps:
        terrain = get_map(m, config.map_seed)
        for label, start, _ in config.tracks(m):
            case = survey_case(m, label)
            truth = simulate(bundle, terrain, tan, start, CURRENTS[config.current], named_stream(seed, case))
            for sigma in config.sigmas:
                name = sigma_name(sigma)
                result = run_filter(bundle, terrain, tan, truth, sigma, named_stream(seed, case, name),
                                    stop_beyond_m=config.lost_m)
                metrics = result.metrics(config.lost_m, tan.dt)
                # a lost run was stopped: its mean error is that of a truncated run
                kept = ("lost", "max_error_m", "lost_at_s") if metrics["lost"] else ("lost", "max_error_m", "mean_error_m")
                rows += [{"run": run, "case": case, "filter": name, "metric": k, "value": metrics[k]} for k in kept if k in metrics]
    return rows


# ------------------------------------------------------------------------------------- tables
def outcomes(rows, config: SurveyConfig) -> dict:
    """{map: [{label, start, terrain, runs, lost: {filter: k}, worst: {filter: max error over runs}, kept: [filters
    that kept every run]}]} over the configured tracks that have rows."""
    values = defaultdict(list)
    for r in rows:
        values[(r["case"], r["filter"], r["metric"])].append(r["value"])
    out = {}
    names = [sigma_name(s) for s in config.sigmas]
    for m in config.maps:
        entries = []
        for label, start, terrain in config.tracks(m):
            case = survey_case(m, label)
            if (case, names[0], "lost") not in values:
                continue
            lost = {f: int(round(sum(values[(case, f, "lost")]))) for f in names}
            worst = {f: float(max(values[(case, f, "max_error_m")])) for f in names}
            runs = len(values[(case, names[0], "lost")])
            entries.append({"label": label, "start": start, "terrain": terrain, "runs": runs, "lost": lost,
                            "worst": worst, "kept": [f for f in names if lost[f] == 0],
                            "mean_error": {f: over_runs(values[(case, f, "mean_error_m")]).mean
                                           for f in names if lost[f] == 0}})
        out[m] = entries
    return out


def pick(entries: list[dict]) -> dict | None:
    """The survey's pick of a map (module docstring): (entry, filter) with the smallest worst-run max error among
    the tracks where a fixed sigma kept every run; None when no track was kept."""
    kept = [(e["worst"][f], e["label"], e, f) for e in entries for f in e["kept"]]
    if not kept:
        return None
    _, _, entry, name = min(kept, key=lambda c: (c[0], c[1]))
    return {"label": entry["label"], "start": entry["start"], "filter": name, "worst_m": entry["worst"][name],
            "terrain": entry["terrain"]}


def _share(entries, test) -> str:
    k = sum(1 for e in entries if test(e))
    return f"{k}/{len(entries)}" if entries else "-"


def summary_table(res: dict, config: SurveyConfig) -> tuple[list[str], list[list[str]]]:
    """Per map: tracks surveyed, kept by each sigma and by either, the single runs each kept."""
    names = [sigma_name(s) for s in config.sigmas]
    header = ["map", "tracks"] + [f"kept by {n}" for n in names] + ["by either"] + [f"runs kept, {n}" for n in names]
    body = []
    for m, entries in res.items():
        runs_kept = [f"{sum(e['runs'] - e['lost'][n] for e in entries)}/{sum(e['runs'] for e in entries)}" for n in names]
        body.append([m, str(len(entries))] + [_share(entries, lambda e, n=n: n in e["kept"]) for n in names]
                    + [_share(entries, lambda e: bool(e["kept"]))] + runs_kept)
    return header, body


def split_table(res: dict, config: SurveyConfig) -> tuple[list[str], list[list[str]]]:
    """Per map and sigma: the tracks that lost all their runs and those that kept all, beside the count independent
    runs at the sigma's average rate would give (a track splitting rather than sharing a chance)."""
    header = ["map", "sigma", "runs kept (rate)", "tracks: all runs lost", "tracks: all runs kept",
              "all kept if runs were independent"]
    body = []
    for m, entries in res.items():
        for s in config.sigmas:
            n = sigma_name(s)
            runs = sum(e["runs"] for e in entries)
            kept = sum(e["runs"] - e["lost"][n] for e in entries)
            rate = kept / runs if runs else math.nan
            all_lost = sum(1 for e in entries if e["lost"][n] == e["runs"])
            all_kept = sum(1 for e in entries if e["lost"][n] == 0)
            expected = sum(rate ** e["runs"] for e in entries) if runs else math.nan
            body.append([m, f"{s:g} m", f"{kept}/{runs} ({rate:.2f})", str(all_lost), str(all_kept), f"{expected:.1f}"])
    return header, body


def terrain_table(res: dict) -> tuple[list[str], list[list[str]]]:
    """Per map: the tracks kept by either sigma, binned by the drift-contour angle and by the weakest slope."""
    header = ["map"] + [f"angle {lo:g}-{hi:g} deg" for lo, hi in ANGLE_BINS] + ["weakest slope: low third", "middle",
                                                                               "high third"]
    body = []
    for m, entries in res.items():
        row = [m]
        for lo, hi in ANGLE_BINS:
            row.append(_share([e for e in entries if lo <= e["terrain"]["drift_contour_angle_deg"] < hi], lambda e: bool(e["kept"])))
        weakest = np.array([e["terrain"]["weakest_slope_m_per_km"] for e in entries])
        edges = np.quantile(weakest, [1 / 3, 2 / 3]) if weakest.size else (0.0, 0.0)
        thirds = ([e for e in entries if e["terrain"]["weakest_slope_m_per_km"] < edges[0]],
                  [e for e in entries if edges[0] <= e["terrain"]["weakest_slope_m_per_km"] < edges[1]],
                  [e for e in entries if e["terrain"]["weakest_slope_m_per_km"] >= edges[1]])
        row += [_share(third, lambda e: bool(e["kept"])) for third in thirds]
        body.append(row)
    return header, body


def margins_table(res: dict) -> tuple[list[str], list[list[str]]]:
    """Per map, the five kept tracks whose worst run stayed furthest below the lost line."""
    header = ["map", "track", "sigma", "worst run max error m", "mean error m (mean of runs)", "angle deg", "slope m/km"]
    body = []
    for m, entries in res.items():
        kept = sorted(((e["worst"][f], e, f) for e in entries for f in e["kept"]), key=lambda c: (c[0], c[1]["label"]))
        for worst, e, f in kept[:5]:
            body.append([m, e["label"], f.removeprefix("sigma_") + " m", f"{worst:.0f}", f"{e['mean_error'][f]:.0f}",
                         f"{e['terrain']['drift_contour_angle_deg']:.0f}", f"{e['terrain']['slope_m_per_km']:.0f}"])
    return header, body


def picks_table(res: dict) -> tuple[list[str], list[list[str]]]:
    header = ["map", "the survey's pick", "sigma", "worst run max error m"]
    body = []
    for m, entries in res.items():
        p = pick(entries)
        body.append([m, p["label"], p["filter"].removeprefix("sigma_") + " m", f"{p['worst_m']:.0f}"] if p else
                    [m, "no track kept by a fixed sigma", "-", "-"])
    return header, body


def report(rows, config: SurveyConfig) -> str:
    res = outcomes(rows, config)
    runs = max((e["runs"] for entries in res.values() for e in entries), default=0)
    lines = [f"Terrain-aided navigation (seed 003), track survey{' -- QUICK run (smoke test, not evidence)' if config.quick_run else ''}: "
             f"every admissible track on a {config.grid_km:g} km grid (4 headings) at {config.current} m/s, "
             f"{config.duration_s:g} s per run, N = {config.n_particles}, {runs} run(s) per track",
             f"kept = every run's error stayed within {config.lost_m:g} m (a run is stopped once lost); tracks kept / "
             "tracks surveyed; runs kept = the single runs (track x run) that stayed within it;",
             "angle = drift vs depth contours (0 along, 90 across), weakest = the slope in the "
             "least-informative direction (scenario.characterise, no filter)", ""]
    lines += aligned(*summary_table(res, config), left=1) + [""]
    lines.append("TRACKS SPLIT RATHER THAN SHARE A CHANCE: tracks whose runs were all lost / all kept, and how many would "
                 "keep all runs if every run kept the track at the sigma's average rate")
    lines += aligned(*split_table(res, config), left=2) + [""]
    lines.append("KEPT BY EITHER SIGMA, by the track's terrain")
    lines += aligned(*terrain_table(res), left=1) + [""]
    lines.append("LARGEST MARGINS (per map, the five kept tracks whose worst run stayed furthest below the lost line)")
    lines += aligned(*margins_table(res), left=2) + [""]
    lines.append("THE SURVEY'S PICK per map (scenario.TRACKS['survey_pick']; the tan experiment confirms it on its own streams)")
    lines += aligned(*picks_table(res), left=2)
    return "\n".join(lines)


def markdown(rows, config: SurveyConfig, document: dict | None = None) -> dict[str, str]:
    """The survey's tables for docs/experiments/tan.md (`abyssal publish tan-survey`, publish.py)."""
    from ..publish import markdown_table

    res = outcomes(rows, config)
    return {"summary": markdown_table(*summary_table(res, config)), "split": markdown_table(*split_table(res, config)),
            "terrain": markdown_table(*terrain_table(res)), "margins": markdown_table(*margins_table(res), align="lllrrrr"),
            "picks": markdown_table(*picks_table(res), align="lllr")}


def document(rows, config: SurveyConfig, prepared=None) -> dict:
    res = outcomes(rows, config)
    return {"survey": {m: [{k: e[k] for k in ("label", "start", "terrain", "runs", "lost", "worst", "kept")} for e in entries]
                       for m, entries in res.items()},
            "picks": {m: pick(entries) for m, entries in res.items()}}


# ------------------------------------------------------------------------------------- figure
#: the two outcomes' looks (colour-blind safe, and told apart by line style as well): kept / lost by every sigma
KEPT_LOOK = {"color": "#0072B2", "linestyle": "-", "lw": 1.6}
LOST_LOOK = {"color": "#D55E00", "linestyle": (0, (3, 2)), "lw": 1.0}
#: km: tracks of one heading whose paths run along the same line (starts one grid step apart along it, the path
#: longer than the step) are drawn this far apart, alternately to either side, so no track hides another
LANE_KM = 0.9


def _lane_offset(start, grid_km: float) -> tuple[float, float]:
    """(dx, dy) in km that moves a track sideways by +-LANE_KM / 2, alternating with its start's place along its
    heading, so consecutive starts on one line are drawn in two lanes."""
    x, y, heading = start
    along = (x * math.cos(heading) + y * math.sin(heading)) / 1e3
    side = 0.5 * LANE_KM * (1 if int(round(along / grid_km)) % 2 else -1)
    return -side * math.sin(heading), side * math.cos(heading)


def figures(rows, out: Path, config: SurveyConfig, seed: int = 0, prepared=None, settings: str | None = None) -> list[Path]:
    """Every surveyed track over its map, one row per heading (tracks of four headings from one start would
    overlap as a cross, and opposite headings from neighbouring starts along one line): its path at the survey's
    current, solid blue where a fixed sigma kept every run, dashed vermillion where none did, an arrow at its end,
    tracks on one line drawn in two lanes (LANE_KM apart); the pick circled."""
    from ...extras import require

    require("matplotlib", "the experiment figures")
    from ...plots import plt, save_figure
    from .experiment import depth_image

    res = outcomes(rows, config)
    runs = max((e["runs"] for entries in res.values() for e in entries), default=0)
    settings = settings or config.settings(runs, seed)
    Path(out).mkdir(parents=True, exist_ok=True)
    headings = sorted({round(math.degrees(e["start"][2])) % 360 for entries in res.values() for e in entries})
    speed = TanConfig().speed
    paths, windows = {}, {}
    for m, entries in res.items():
        paths[m] = [nominal_path(e["start"], CURRENTS[config.current], config.duration_s, speed) for e in entries]
        x_min, x_max, y_min, y_max = (v / 1e3 for v in get_map(m, config.map_seed).extent)
        if paths[m]:  # the surveyed part of the map, 3 km around the paths
            x_min = max(x_min, min(x.min() for x, _ in paths[m]) / 1e3 - 3.0)
            x_max = min(x_max, max(x.max() for x, _ in paths[m]) / 1e3 + 3.0)
        windows[m] = (x_min, x_max, y_min, y_max)
    aspect = max((w[3] - w[2]) / (w[1] - w[0]) for w in windows.values())  # height / width of a panel's map
    width = min(5.6, 4.2 / aspect)
    fig, axes = plt.subplots(max(1, len(headings)), len(res), squeeze=False,
                             figsize=(max(12.0, (width + 0.9) * len(res)), (width * aspect + 0.8) * max(1, len(headings)) + 1.3))
    for col, (m, entries) in enumerate(res.items()):
        terrain = get_map(m, config.map_seed)
        x_min, x_max, y_min, y_max = windows[m]
        p = pick(entries)
        for row, heading in enumerate(headings):
            ax = axes[row, col]
            image, interval = depth_image(ax, terrain, window_km=(x_min, x_max, y_min, y_max), alpha=0.5)
            shown = [(e, xy) for e, xy in zip(entries, paths[m]) if round(math.degrees(e["start"][2])) % 360 == heading]
            for e, (x, y) in shown:
                dx, dy = _lane_offset(e["start"], config.grid_km)
                look = KEPT_LOOK if e["kept"] else LOST_LOOK
                xs, ys = x / 1e3 + dx, y / 1e3 + dy
                ax.plot(xs, ys, **look, alpha=0.9)
                ax.plot(xs[0], ys[0], "o", color=look["color"], ms=3)
                ax.annotate("", xy=(xs[-1], ys[-1]), xytext=(xs[-2], ys[-2]),
                            arrowprops={"arrowstyle": "-|>", "color": look["color"], "lw": 1.0, "mutation_scale": 9})
                if p and e["label"] == p["label"]:
                    ax.plot(xs[0], ys[0], "o", ms=12, mfc="none", mec="black", mew=2)
            kept = sum(1 for e, _ in shown if e["kept"])
            ax.set(xlim=(x_min, x_max), ylim=(y_min, y_max), xlabel="x (km)" if row == len(headings) - 1 else None,
                   ylabel=f"heading {heading} deg\ny (km)" if col == 0 else None)
            ax.set_title(f"{m}, heading {heading} deg: kept {kept}/{len(shown)}", fontsize=9)
        picked = f"pick {p['label']} ({p['filter']})" if p else "no pick"
        axes[0, col].set_title(f"{m}: kept {_share(entries, lambda e: bool(e['kept']))} tracks, {picked} (contours "
                               f"every {interval} m)\n{axes[0, col].get_title()}", fontsize=9)
    handles = [plt.Line2D([], [], marker="o", ms=3, label="kept: a fixed sigma held every run (dot: start, arrow: end)",
                          **KEPT_LOOK),
               plt.Line2D([], [], marker="o", ms=3, label="lost by every fixed sigma", **LOST_LOOK),
               plt.Line2D([], [], ls="none", marker="o", ms=10, mfc="none", mec="black", mew=2, label="the survey's pick")]
    fig.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, 0.965), fontsize=8, ncol=3, frameon=False)
    fig.suptitle(f"Track survey at {config.current} m/s, one row per heading (tracks on one line drawn "
                 f"{LANE_KM:g} km apart): {' or '.join(sigma_name(s) for s in config.sigmas)}", fontsize=11)
    return [save_figure(fig, Path(out) / "tan_survey_tracks.png", settings, rect=(0, 0.02, 1, 0.94))]
