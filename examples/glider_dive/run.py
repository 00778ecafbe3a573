"""A real Slocum glider dive through `abyssal replay`: from the last GPS fix before it to the first fix after it.

The dive is the one dbdreader ships (ammonite-2008-028-01-000.mbd: the glider ammonite off Toulon on 2008-01-29,
~1.6 h down to 608 m and back; depth, attitude, its own dead reckoning and GPS fixes, every 4 s). dbdreader is
GPL-3 and a test/example dependency only (pip install dbdreader, part of abyssal's test extra); this script reads
the file where dbdreader installed it and copies nothing of it into the repository.

    python run.py [--out glider_out] [--filter ekf|ukf|ckf] [--aoa DEG]

1. Looks at the log: the dive (depth beyond 2 m), the last fix before it, the first fix after surfacing.
2. Writes it as a CSV log (OUT/log: attitude.csv, depth.csv, gps.csv with latitude/longitude) and its sensor map
   (OUT/log/map.toml: x0 at the last fix before the dive, the local origin there, the heading made true with the
   log's own magnetic variation). The tables end at the first fix after surfacing: after it the glider drifts at
   the surface with the wind and starts its next dive, which this model does not describe; the samples before the
   map's t0 stay in the tables (the replay counts them as skipped).
3. Generates glider.py's model (OUT/gen/slocum_glider) and replays the log with --smooth (OUT/replay: track,
   report, figures): `abyssal replay OUT/log --model OUT/gen/slocum_glider --filter ekf --sensors OUT/log/map.toml
   --out OUT/replay --smooth` does the same from the command line.
4. Prints the position at surfacing against the first fix after the dive (before the filter uses it): the filter's
   state when the glider surfaced (as the glider's own dead reckoning is taken) and its prediction at the fix (after
   ~95 s floating at the surface, which the model does not describe), beside the glider's own dead-reckoning error at
   that fix (its m_dr_x_ini_err and m_dr_y_ini_err, and its m_lat/m_lon converted about the same origin), and the
   depth-averaged current the smoother finds against the one the glider computed (m_water_vx, m_water_vy).
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
DIVE_FILE = "ammonite-2008-028-01-000.mbd"
DIVE_DEPTH = 2.0           # m: the glider is diving beyond this depth
#: the filter's settings (map.toml): position from the fix (GPS ~5 m), the speed through the water and the current
#: unknown to +-0.2 and +-0.1 m/s; process noise as spectral densities of the model's noise inputs
P0_STD = [5.0, 5.0, 1.0, 0.2, 0.1, 0.1]
Q_STD = [0.01, 0.001, 0.001, 0.1]   # w_speed (m/s^2 sqrt(s)), w_current_n/e, w_heading (rad sqrt(s))


def dive_file() -> Path:
    """The dive's .mbd where dbdreader installed it (ImportError without dbdreader)."""
    import dbdreader

    path = Path(dbdreader.__file__).resolve().parent / "data" / DIVE_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path}: dbdreader {getattr(dbdreader, '__version__', '?')} does not ship {DIVE_FILE}")
    return path


def read_dive(path: Path) -> dict:
    """The variables the model uses and the glider's own estimates, as {name: (t (K,), values (K,))}."""
    import dbdreader

    dbd = dbdreader.DBD(str(path))
    names = ("m_depth", "m_pitch", "m_heading", "m_gps_lat", "m_gps_lon", "m_gps_mag_var", "m_lat", "m_lon",
             "m_dr_x_ini_err", "m_dr_y_ini_err", "m_water_vx", "m_water_vy", "x_lmc_xy_source")
    data = {name: dbd.get(name) for name in names}
    dbd.close()
    return data


def dive_times(data: dict) -> dict:
    """The dive (the samples beyond DIVE_DEPTH around the deepest one: the log also holds a spike before the first fix
    and the start of the next dive), the last fix before it and the first after it (Unix s)."""
    t, depth = data["m_depth"]
    deepest = int(np.argmax(depth))
    shallow = np.flatnonzero(depth <= DIVE_DEPTH)
    first = shallow[shallow < deepest][-1] + 1
    last = shallow[shallow > deepest][0] - 1
    start, end = t[first], t[last]
    fixes = data["m_gps_lat"][0]
    return {"start": float(start), "end": float(end), "fix_before": float(fixes[fixes < start][-1]),
            "fix_after": float(fixes[fixes > end][0])}


def write_log(data: dict, folder: Path, times: dict, aoa: float = 0.0) -> Path:
    """The dive as a CSV log with its sensor map (module docstring); returns the map's path."""
    folder.mkdir(parents=True, exist_ok=True)
    end = times["fix_after"]
    data = {name: (t[t <= end], v[t <= end]) for name, (t, v) in data.items()}
    t, pitch = data["m_pitch"]
    t_h, heading = data["m_heading"]
    assert np.array_equal(t, t_h), "pitch and heading are logged together"
    variation = float(np.median(data["m_gps_mag_var"][1][data["m_gps_mag_var"][1] != 0]))  # rad, + is west
    with open(folder / "attitude.csv", "w") as out:
        out.write("t,pitch,heading_magnetic\n")
        out.writelines(f"{a!r},{b!r},{c!r}\n" for a, b, c in zip(t.tolist(), pitch.tolist(), heading.tolist()))
    t, depth = data["m_depth"]
    with open(folder / "depth.csv", "w") as out:
        out.write("t,depth\n")
        out.writelines(f"{a!r},{b!r}\n" for a, b in zip(t.tolist(), depth.tolist()))
    t, lat = data["m_gps_lat"]
    t_lon, lon = data["m_gps_lon"]
    assert np.array_equal(t, t_lon), "latitude and longitude are logged together"
    with open(folder / "gps.csv", "w") as out:
        out.write("t,lat,lon\n")
        out.writelines(f"{a!r},{b!r},{c!r}\n" for a, b, c in zip(t.tolist(), lat.tolist(), lon.tolist()))
    k = int(np.flatnonzero(t == times["fix_before"])[0])
    map_path = folder / "map.toml"
    map_path.write_text(f"""# the Slocum dive of dbdreader's {DIVE_FILE}, written by examples/glider_dive/run.py
[log]
origin = [{float(lat[k])!r}, {float(lon[k])!r}, 0.0]   # the last fix before the dive: the local NED origin

[input]                                  # pitch and heading, held between their 4 s samples
table = "attitude.csv"
fields = ["pitch", "heading_magnetic"]
offset = [0.0, {-variation!r}]           # true = magnetic - m_gps_mag_var (Slocum: + is west)

[sensors.depth]
table = "depth.csv"
fields = ["depth"]

[sensors.gps]
table = "gps.csv"
latitude = "lat"
longitude = "lon"
fields = ["north", "east"]

[filter]
t0 = {times['fix_before']!r}             # the last fix before the dive
x0 = [0.0, 0.0, 0.0, 0.3, 0.0, 0.0]
P0_std = {P0_STD}
Q_std = {Q_STD}
noise = "inputs"
parameters = {{ aoa = {aoa!r} }}

[frames]
position = ["north", "east", "depth"]
fixes = ["gps"]
""")
    return map_path


def glider_dead_reckoning_error(data: dict, times: dict, origin) -> dict:
    """The glider's own dead-reckoning error at the first fix after the dive: its m_dr_*_ini_err (GPS minus DR,
    x east, y north, m) and its last DR position (m_lat/m_lon, x_lmc_xy_source = 2) against the fix."""
    from abyssal.runtime.frames import geodetic_to_ned

    t_err, x_err = data["m_dr_x_ini_err"]
    _, y_err = data["m_dr_y_ini_err"]
    k = int(np.argmin(np.abs(t_err - times["fix_after"])))
    t_src, source = data["x_lmc_xy_source"]
    t_lat, lat = data["m_lat"]
    _, lon = data["m_lon"]
    dr_times = t_src[(source == 2) & (t_src < times["fix_after"])]
    j = int(np.flatnonzero(t_lat == dr_times[-1])[0])
    t_fix, fix_lat = data["m_gps_lat"]
    _, fix_lon = data["m_gps_lon"]
    f = int(np.flatnonzero(t_fix == times["fix_after"])[0])
    dr = np.array(geodetic_to_ned(lat[j], lon[j], 0.0, origin)[:2])
    fix = np.array(geodetic_to_ned(fix_lat[f], fix_lon[f], 0.0, origin)[:2])
    return {"own_error_m": float(math.hypot(x_err[k], y_err[k])), "own_error_at": float(t_err[k]),
            "dr_minus_fix_ne": (dr - fix).tolist(), "dr_error_m": float(np.hypot(*(dr - fix))),
            "dr_time": float(t_lat[j]), "water_velocity_ne": [float(data["m_water_vy"][1][-1]),
                                                               float(data["m_water_vx"][1][-1])]}


def surfacing(result, times: dict) -> dict:
    """The filter against the first fix after the dive, before using it: its state when the glider surfaced (the last
    row at or before the dive's end, as the glider's own dead reckoning is taken) and its prediction at the fix."""
    t_fix = times["fix_after"] - result.log.epoch - result.t0
    t_end = times["end"] - result.log.epoch - result.t0
    fix = next(m for m in result.measurements if m.sensor == "gps" and abs(m.t - t_fix) < 1e-6)
    track = result.track
    rows = {"at_surface": int(np.flatnonzero(track.t <= t_end)[-1]),
            "at_fix": int(np.flatnonzero((np.abs(track.t - t_fix) < 1e-6) & (np.array(track.event) == "predict"))[0])}
    out = {"fix_status": fix.status, "t_fix": t_fix, "t_surface": float(track.t[rows["at_surface"]])}
    for name, k in rows.items():
        error = track.x[k, :2] - fix.z
        out[name] = {"predicted_minus_fix_ne": error.tolist(), "error_m": float(np.hypot(*error)),
                     "sigma_ne": np.sqrt(np.diag(track.P[k])[:2]).tolist()}
    return out


def smoothed_current(result, times: dict) -> dict:
    """The smoothed depth-averaged current at the middle of the dive (m/s, north and east) and its 1 sigma."""
    smoothed = result.smoothed
    middle = 0.5 * (times["start"] + times["end"]) - result.log.epoch - result.t0
    k = int(np.searchsorted(smoothed.t, middle))
    return {"current_ne": smoothed.x[k, 4:6].tolist(), "sigma_ne": np.sqrt(np.diag(smoothed.P[k])[4:6]).tolist(),
            "speed": float(smoothed.x[k, 3])}


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="glider_out", help="output folder (default: %(default)s)")
    parser.add_argument("--filter", default="ekf", choices=["ekf", "ukf", "ckf"])
    parser.add_argument("--aoa", type=float, default=0.0, help="angle of attack, degrees (default: %(default)s)")
    parser.add_argument("--no-figures", action="store_true")
    args = parser.parse_args(argv)

    import abyssal
    from abyssal.runtime.replay import replay

    sys.path.insert(0, str(HERE))
    from glider import slocum_glider

    out = Path(args.out)
    data = read_dive(dive_file())
    times = dive_times(data)
    map_path = write_log(data, out / "log", times, aoa=math.radians(args.aoa))
    folder = abyssal.generate(slocum_glider(), out / "gen")
    result = replay(out / "log", folder, filter=args.filter, sensors=map_path, out=out / "replay", smooth=True,
                    figures=not args.no_figures)
    at = surfacing(result, times)
    own = glider_dead_reckoning_error(data, times, result.log.origin)
    current = smoothed_current(result, times)
    dive = times["end"] - times["start"]
    print(f"dive {DIVE_FILE}: {dive:.0f} s below {DIVE_DEPTH:g} m; from the fix at {times['fix_before']:.1f} s to the "
          f"fix at {times['fix_after']:.1f} s (Unix time), {result.filter_name}, angle of attack {args.aoa:g} deg")
    for name, when in (("at_surface", f"when it surfaced ({at['t_fix'] - at['t_surface']:.0f} s before the fix)"),
                       ("at_fix", "predicted to the fix")):
        a = at[name]
        print(f"  filter {when}: {a['error_m']:.1f} m from the GPS fix (north {a['predicted_minus_fix_ne'][0]:+.1f}, "
              f"east {a['predicted_minus_fix_ne'][1]:+.1f} m); its own 1 sigma north {a['sigma_ne'][0]:.0f} m, east "
              f"{a['sigma_ne'][1]:.0f} m")
    depth = result.counts["depth"]
    print(f"  depth: {depth['used']} used, {depth['gated']} gated, P inflated {depth['inflations']} times after its "
          "gated streak")
    print(f"  glider's dead reckoning: {own['own_error_m']:.1f} m (its m_dr_x/y_ini_err); its last DR position "
          f"(m_lat/m_lon at {own['dr_time']:.1f} s) {own['dr_error_m']:.1f} m from the fix")
    print(f"  depth-averaged current: smoothed north {current['current_ne'][0]:+.3f} +- {current['sigma_ne'][0]:.3f}, "
          f"east {current['current_ne'][1]:+.3f} +- {current['sigma_ne'][1]:.3f} m/s; the glider's own "
          f"north {own['water_velocity_ne'][0]:+.3f}, east {own['water_velocity_ne'][1]:+.3f} m/s")
    print(f"  wrote {out / 'replay'} (report.md, track.csv, smoothed.csv, figures/)")
    return {"times": times, "surfacing": at, "glider": own, "current": current, "result": result}


if __name__ == "__main__":
    main()
