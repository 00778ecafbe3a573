"""An AUV's navigation with sensors and time: EKF, UKF and CKF over simulated dives, delayed USBL fixes fused at their
stamp, at their arrival, or dropped, and the smoothed track beside the filtered one.

    python examples/auv_navigation/run.py                 # 20 seeds x 600 s: the table, auv_navigation.png, runs.csv
    python examples/auv_navigation/run.py --seeds 5 --duration 300 --jobs 2
    python examples/auv_navigation/run.py --quick         # 4 seeds x 200 s (the test's run)

Generates the model (auv.py) into gen/ beside this file on first use (abyssal.generate: unchanged files are not
rewritten, so the compiled library stays cached). Every seed is one dive (simulate.py) and every filter runs over
the same reports (navigate.py); the truth only scores (scoring.py). No number in the tables comes from a filter that
knows the truth: none is an oracle.
"""
from __future__ import annotations

import argparse
import csv
import os
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import abyssal  # noqa: E402

import auv  # noqa: E402
import navigate  # noqa: E402
from navigate import HANDLINGS  # noqa: E402
from scoring import score  # noqa: E402
from simulate import Mission, simulate  # noqa: E402

FILTERS = {"ekf": abyssal.EKF, "ukf": abyssal.UKF, "ckf": abyssal.CKF}
SENSORS = ("dvl", "depth", "ahrs", "usbl", "gnss")
LABELS = {"stamp": "at stamp", "arrival": "at arrival", "dropped": "dropped", "smoothed": "smoothed"}


def mission_for(duration: float, latency: tuple = (0.3, 1.0)) -> Mission:
    """The mission of a dive of this length: 60 s at the surface at each end (15 % of a dive shorter than 400 s),
    down to 10 m (5 m below 400 s), and the DVL's bottom lock lost for 60 s (a tenth of a shorter dive) mid-dive."""
    if duration >= 400:
        return Mission(duration=duration, lock_loss=(duration / 2, duration / 2 + 60.0), usbl_latency=tuple(latency))
    surface, lost = round(0.15 * duration, 2), round(duration / 10, 2)
    return Mission(duration=duration, surface_time=surface, max_depth=5.0,
                   lock_loss=(duration / 2, duration / 2 + lost), usbl_latency=tuple(latency))


def load_model():
    folder = abyssal.generate(auv.auv_navigation, HERE / "gen")
    return abyssal.load(folder)


def one_seed(seed: int, mission: Mission, filters: tuple[str, ...], keep_trace: bool) -> tuple[list, dict | None]:
    """Every filter and handling over one dive: tidy rows, and the tracks for the figure when asked."""
    bundle = load_model()
    dive = simulate(bundle, seed, mission)
    rows, trace = [], {"dive": dive, "tracks": {}} if keep_trace else None
    for name in filters:
        for handling in HANDLINGS:
            track = navigate.navigate(bundle, FILTERS[name], dive, handling, smoothing=handling == "stamp", seed=seed)
            truth = dive.truth_at(track.t)
            surfaced = np.array([mission.surfaced(t) for t in track.t])
            base = {"seed": seed, "filter": name.upper()}
            rows.append({**base, "track": handling, **score(track.x, track.P, truth, surfaced, track.nis)})
            if track.smoothed is not None:
                rows.append({**base, "track": "smoothed", **score(*track.smoothed, truth, surfaced)})
            if trace is not None:
                trace["tracks"][(name.upper(), handling)] = track
    return rows, trace


def campaign(seeds: list[int], mission: Mission, filters: tuple[str, ...], jobs: int = 1):
    """All seeds (in parallel over `jobs` processes); rows in seed order and the first seed's trace."""
    load_model()  # generate and compile once, before any worker
    flags = [seed == seeds[0] for seed in seeds]
    if jobs > 1:
        with ProcessPoolExecutor(jobs) as pool:
            results = list(pool.map(one_seed, seeds, [mission] * len(seeds), [filters] * len(seeds), flags))
    else:
        results = [one_seed(seed, mission, filters, flag) for seed, flag in zip(seeds, flags)]
    return [row for rows, _ in results for row in rows], results[0][1]


# ------------------------------------------------------------------------------------------------ the tables
def select(rows, **where):
    return [r for r in rows if all(r[k] == v for k, v in where.items())]


def wins(rows, filter_name, better, worse, key="rmse_xy") -> tuple[int, int]:
    a = {r["seed"]: r[key] for r in select(rows, filter=filter_name, track=better)}
    b = {r["seed"]: r[key] for r in select(rows, filter=filter_name, track=worse)}
    return sum(a[s] < b[s] for s in a), len(a)


def handling_table(rows, filters) -> str:
    head = (f"{'filter':6} {'USBL fixes':11} {'RMSE xy [m]':>14} {'submerged':>14} {'ANEES':>6} {'ANEES xy':>8}  "
            + "  ".join(f"{s:>12}" for s in SENSORS) + "  stamp < arrival")
    lines = [head, " " * 70 + "NIS/dof (share inside the 95 % chi-square interval)"]
    for name in filters:
        for handling in HANDLINGS:
            group = select(rows, filter=name.upper(), track=handling)
            rmse, sub = np.array([r["rmse_xy"] for r in group]), np.array([r["rmse_xy_submerged"] for r in group])
            cells = []
            for s in SENSORS:
                values = [r.get(f"nis_{s}", np.nan) for r in group]
                inside = [r.get(f"nis_{s}_in95", np.nan) for r in group]
                cells.append("—" if np.all(np.isnan(values)) else f"{np.nanmean(values):.2f} ({100 * np.nanmean(inside):2.0f}%)")
            won = f"{wins(rows, name.upper(), 'stamp', 'arrival')[0]}/{len(group)} seeds" if handling == "stamp" else ""
            lines.append(f"{name.upper():6} {LABELS[handling]:11} {rmse.mean():6.3f} ± {rmse.std():5.3f} "
                         f"{sub.mean():6.3f} ± {sub.std():5.3f} {np.mean([r['nees'] for r in group]):6.2f} "
                         f"{np.mean([r['nees_xy'] for r in group]):8.2f}  " + "  ".join(f"{c:>12}" for c in cells)
                         + f"  {won}")
    return "\n".join(lines)


def smoothing_table(rows, filters) -> str:
    lines = [f"{'filter':6} {'track':9} {'RMSE xy [m]':>14} {'submerged':>14} {'ANEES':>6} {'ANEES xy':>8}  smoothed < filtered"]
    for name in filters:
        for track, label in (("stamp", "filtered"), ("smoothed", "smoothed")):
            group = select(rows, filter=name.upper(), track=track)
            rmse, sub = np.array([r["rmse_xy"] for r in group]), np.array([r["rmse_xy_submerged"] for r in group])
            won = f"{wins(rows, name.upper(), 'smoothed', 'stamp')[0]}/{len(group)} seeds" if track == "smoothed" else ""
            lines.append(f"{name.upper():6} {label:9} {rmse.mean():6.3f} ± {rmse.std():5.3f} {sub.mean():6.3f} ± "
                         f"{sub.std():5.3f} {np.mean([r['nees'] for r in group]):6.2f} "
                         f"{np.mean([r['nees_xy'] for r in group]):8.2f}  {won}")
    return "\n".join(lines)


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, load {os.getloadavg()[0]:.2f}"


def write_rows(rows, path: Path) -> None:
    keys = list(dict.fromkeys(k for r in rows for k in r))
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, keys)
        writer.writeheader()
        writer.writerows(rows)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20, help="dives (seeds 1..N; default 20)")
    parser.add_argument("--duration", type=float, default=600.0, help="seconds per dive (default 600)")
    parser.add_argument("--filters", default="ekf,ukf,ckf", help="comma-separated: ekf, ukf, ckf")
    parser.add_argument("--jobs", type=int, default=1, help="processes (default 1)")
    parser.add_argument("--out", type=Path, default=HERE, help="folder for auv_navigation.png and runs.csv")
    parser.add_argument("--latency", type=float, nargs=2, default=(0.3, 1.0), metavar=("MIN", "MAX"),
                        help="the USBL fixes' delay, uniform in [MIN, MAX] s (default 0.3 1.0)")
    parser.add_argument("--quick", action="store_true", help="4 seeds x 200 s")
    args = parser.parse_args(argv)
    if args.quick:
        args.seeds, args.duration = 4, 200.0
    filters = tuple(f.strip().lower() for f in args.filters.split(","))
    unknown = sorted(set(filters) - set(FILTERS))
    low, high = args.latency
    if unknown or args.seeds < 1 or args.duration < 100 or not 0 <= low <= high < navigate.HISTORY_SECONDS:
        parser.error(f"filters must be among {sorted(FILTERS)} (got {unknown}), seeds >= 1, duration >= 100 s, "
                     f"0 <= latency MIN <= MAX < {navigate.HISTORY_SECONDS} s (the filters' history)")
    mission = mission_for(args.duration, (low, high))
    started = time.perf_counter()
    rows, trace = campaign(list(range(1, args.seeds + 1)), mission, filters, args.jobs)
    elapsed = time.perf_counter() - started
    args.out.mkdir(parents=True, exist_ok=True)
    write_rows(rows, args.out / "runs.csv")
    from figure import draw

    figure = draw(trace, rows, mission, args.out / "auv_navigation.png")
    command = "python examples/auv_navigation/run.py " + " ".join(argv if argv is not None else sys.argv[1:])
    print(f"AUV navigation (remus100 dynamics; DVL 5 Hz, depth 10 Hz, AHRS 20 Hz, USBL every {mission.usbl_period:g} s "
          f"{mission.usbl_latency[0]:g}-{mission.usbl_latency[1]:g} s late, GNSS 1 Hz at the surface): {args.seeds} seeds x "
          f"{mission.duration:g} s, bottom lock lost {mission.lock_loss[0]:g}-{mission.lock_loss[1]:g} s, at the surface "
          f"for the first and last {mission.surface_time:g} s")
    print(f"`{command.strip()}` on {machine()}, {elapsed:.0f} s")
    print("Oracles: none. The filters are given the sensors' reports with their declared noise (a USBL fix with its own "
          "quality figure), the autopilot's inputs, the force-noise spectral density as Q and a start drawn from P0; the "
          "truth only scores. RMSE: horizontal position, mean ± sd over the seeds; ANEES: NEES / dim (12 states; xy: 2), "
          "1 when consistent.\n")
    print("Delayed USBL fixes: fused at their stamp (the filter's history), at their arrival (the wrong time), or dropped")
    print(handling_table(rows, filters))
    print("\nSmoothed (RTS over the whole dive, filter.smooth()) vs filtered (real time), fixes fused at their stamp")
    print(smoothing_table(rows, filters))
    print(f"\nwrote {figure} and {args.out / 'runs.csv'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
