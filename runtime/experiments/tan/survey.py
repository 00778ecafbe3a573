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


def report(rows, config: SurveyConfig) -> str:
    res = outcomes(rows, config)
    runs = max((e["runs"] for entries in res.values() for e in entries), default=0)
    names = [sigma_name(s) for s in config.sigmas]
    lines = [f"Terrain-aided navigation (seed 003), track survey{' -- QUICK run (smoke test, not evidence)' if config.quick_run else ''}: "
             f"every admissible track on a {config.grid_km:g} km grid (4 headings) at {config.current} m/s, "
             f"{config.duration_s:g} s per run, N = {config.n_particles}, {runs} run(s) per track",
             f"kept = every run's error stayed within {config.lost_m:g} m (a run is stopped once lost); tracks kept / "
             "tracks surveyed; runs kept = the single runs (track x run) that stayed within it;",
             "angle = drift vs depth contours (0 along, 90 across), weakest = the slope in the "
             "least-informative direction (scenario.characterise, no filter)", ""]
    header = ["map", "tracks"] + [f"kept by {n}" for n in names] + ["by either"] + [f"runs kept, {n}" for n in names]
    body = []
    for m, entries in res.items():
        runs_kept = [f"{sum(e['runs'] - e['lost'][n] for e in entries)}/{sum(e['runs'] for e in entries)}" for n in names]
        body.append([m, str(len(entries))] + [_share(entries, lambda e, n=n: n in e["kept"]) for n in names]
                    + [_share(entries, lambda e: bool(e["kept"]))] + runs_kept)
    lines += aligned(header, body, left=1) + [""]
    lines.append("KEPT BY EITHER SIGMA, by the track's terrain")
    header = ["map"] + [f"angle {lo:g}-{hi:g}" for lo, hi in ANGLE_BINS] + ["weakest: low third", "middle", "high third"]
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
    lines += aligned(header, body, left=1) + [""]
    lines.append("LARGEST MARGINS (per map, the five kept tracks whose worst run stayed furthest below the lost line)")
    header = ["map", "track", "sigma", "worst run max error m", "mean error m (mean of runs)", "angle deg", "slope m/km"]
    body = []
    for m, entries in res.items():
        kept = sorted(((e["worst"][f], e, f) for e in entries for f in e["kept"]), key=lambda c: (c[0], c[1]["label"]))
        for worst, e, f in kept[:5]:
            body.append([m, e["label"], f.removeprefix("sigma_") + " m", f"{worst:.0f}", f"{e['mean_error'][f]:.0f}",
                         f"{e['terrain']['drift_contour_angle_deg']:.0f}", f"{e['terrain']['slope_m_per_km']:.0f}"])
    lines += aligned(header, body, left=2) + [""]
    lines.append("THE SURVEY'S PICK per map (scenario.TRACKS['survey_pick']; the tan experiment confirms it on its own streams)")
    for m, entries in res.items():
        p = pick(entries)
        lines.append(f"  {m}: " + (f"{p['label']} with {p['filter']} (worst run {p['worst_m']:.0f} m)" if p else
                                   "no track kept by a fixed sigma"))
    return "\n".join(lines)


def document(rows, config: SurveyConfig, prepared=None) -> dict:
    res = outcomes(rows, config)
    return {"survey": {m: [{k: e[k] for k in ("label", "start", "terrain", "runs", "lost", "worst", "kept")} for e in entries]
                       for m, entries in res.items()},
            "picks": {m: pick(entries) for m, entries in res.items()}}


# ------------------------------------------------------------------------------------- figure
def figures(rows, out: Path, config: SurveyConfig, seed: int = 0, prepared=None, settings: str | None = None) -> list[Path]:
    """Every surveyed track over its map: its path at the survey's current, green where a fixed sigma kept every
    run, red where none did; the pick circled."""
    from ...extras import require

    require("matplotlib", "the experiment figures")
    from ...plots import plt, save_figure
    from .experiment import depth_image

    res = outcomes(rows, config)
    runs = max((e["runs"] for entries in res.values() for e in entries), default=0)
    settings = settings or config.settings(runs, seed)
    Path(out).mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(1, len(res), figsize=(max(9.0, 5.6 * len(res) + 1.0), 6.8), squeeze=False)
    speed = TanConfig().speed
    for ax, (m, entries) in zip(axes[0], res.items()):
        paths = [nominal_path(e["start"], CURRENTS[config.current], config.duration_s, speed) for e in entries]
        terrain = get_map(m, config.map_seed)
        x_min, x_max, y_min, y_max = (v / 1e3 for v in terrain.extent)
        if paths:  # the surveyed part of the map, 3 km around the paths
            x_min = max(x_min, min(x.min() for x, _ in paths) / 1e3 - 3.0)
            x_max = min(x_max, max(x.max() for x, _ in paths) / 1e3 + 3.0)
        image, interval = depth_image(ax, terrain, window_km=(x_min, x_max, y_min, y_max), alpha=0.6)
        fig.colorbar(image, ax=ax, label="depth (m)", shrink=0.7, orientation="horizontal", pad=0.1)
        for e, (x, y) in zip(entries, paths):
            colour = "tab:green" if e["kept"] else "tab:red"
            ax.plot(x / 1e3, y / 1e3, color=colour, lw=1.2, alpha=0.85)
            ax.plot(x[0] / 1e3, y[0] / 1e3, "o", color=colour, ms=3)
        p = pick(entries)
        if p:
            ax.plot(p["start"][0] / 1e3, p["start"][1] / 1e3, "o", ms=12, mfc="none", mec="black", mew=2)
        picked = f"pick {p['label']} ({p['filter']})" if p else "no pick"
        ax.set(xlabel="x (km)", ylabel="y (km)", xlim=(x_min, x_max), ylim=(y_min, y_max),
               title=f"{m}: kept {_share(entries, lambda e: bool(e['kept']))} tracks; {picked}\n"
                     f"(contours every {interval} m)")
    handles = [plt.Line2D([], [], color="tab:green", marker="o", ms=3, label="kept: a fixed sigma held every run"),
               plt.Line2D([], [], color="tab:red", marker="o", ms=3, label="lost by every fixed sigma"),
               plt.Line2D([], [], ls="none", marker="o", ms=10, mfc="none", mec="black", mew=2, label="the survey's pick")]
    fig.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, 0.95), fontsize=8, ncol=3, frameon=False)
    fig.suptitle(f"Track survey at {config.current} m/s (dot = start, line = the path): "
                 f"{' or '.join(sigma_name(s) for s in config.sigmas)}", fontsize=11)
    return [save_figure(fig, Path(out) / "tan_survey_tracks.png", settings, rect=(0, 0.03, 1, 0.9))]
