"""`abyssal replay`: a recorded log through a filter of the model, and out: a tidy track, a report, figures.

    abyssal replay LOG --model NAME|DIR --filter ekf|ukf|ckf|pf --sensors MAP.toml --out DIR [--smooth]

    from abyssal.runtime.replay import replay
    result = replay("dive/", "gen/slocum_glider", filter="ekf", sensors="dive/map.toml", out="out/", smooth=True)
    result.track.x, result.smoothed.x, result.counts["gps"], result.measurements

LOG is a folder of CSV tables (csv_log.py) or a rosbag2 / MCAP bag (bag_log.py); MAP.toml says which stream is the
input and which feeds each sensor, and holds the filter's x0, P0, Q (sensor_map.py). The Kalman filters replay the
calls the vehicle would have made, in the order the measurements arrived (run.py), the particle filter runs on a
clock of its own (particle.py). The outputs (output.py, report.py, figures.py) are written all or nothing.

One concern per module:

    sensor_map.py   the map file, checked against the model
    log.py          what a reader makes of a log (Samples per stream), its checks
    csv_log.py      a folder of CSV tables
    bag_log.py      a rosbag2 / MCAP bag (rosbags), messages.py the common ROS message types in abyssal's frames
    run.py          the Kalman replay (and smoothing), particle.py the particle filter's
    report.py       per-sensor counts and NIS against its chi-square bounds; output.py the tables and the Odometry
                    bag; figures.py the figures; progress.py the progress bar of long logs
"""
from __future__ import annotations

from pathlib import Path

from .log import Log, LogError, Samples
from .run import KALMAN, Measurement, Replay, Track
from .sensor_map import MapError, SensorMap, load_sensor_map

FILTERS = (*KALMAN, "pf")

__all__ = ["FILTERS", "Log", "LogError", "MapError", "Measurement", "Replay", "Samples", "SensorMap", "Track",
           "load_sensor_map", "read_log", "replay", "write_outputs"]


def _model(model):
    if hasattr(model, "functions") and hasattr(model, "sensors"):
        return model
    from abyssal.generated import load

    return load(model)


def read_log(path, sensor_map: SensorMap, progress: bool = True) -> Log:
    """The mapped streams of the log at path: a rosbag2 folder or .mcap/.db3 file (a bag), else a folder of CSV
    tables."""
    from .bag_log import is_bag, read_bag_log
    from .csv_log import read_csv_log

    path = Path(path)
    if not path.exists():
        raise LogError(f"{path}: no such file or folder")
    if is_bag(path):
        return read_bag_log(path, sensor_map, progress)
    if path.is_dir():
        return read_csv_log(path, sensor_map)
    raise LogError(f"{path}: not a log: give a folder of CSV tables, a rosbag2 folder (with metadata.yaml) or an .mcap "
                   "file")


def replay(log, model, filter: str = "ekf", sensors=None, out=None, smooth: bool = False,
           progress: bool = True, figures: bool = True) -> Replay:
    """Replay log (a path) through `filter` of model (a name, a generated folder or a loaded bundle) as the sensor map
    says (a MAP.toml path, a dict or a SensorMap); with out, write the outputs there (all or nothing)."""
    if filter not in FILTERS:
        raise ValueError(f"--filter {filter!r}: choose one of {list(FILTERS)}")
    if sensors is None:
        raise ValueError("the sensor map is required (--sensors MAP.toml)")
    bundle = _model(model)
    sensor_map = sensors if isinstance(sensors, SensorMap) else load_sensor_map(sensors, bundle)
    if filter == "pf":
        from .particle import check_particle_replay, run_particle

        check_particle_replay(sensor_map, smooth)
    data = read_log(log, sensor_map, progress)
    if filter == "pf":
        result = run_particle(bundle, data, sensor_map, progress=progress)
    else:
        from .run import run_kalman

        result = run_kalman(bundle, data, sensor_map, filter, smooth=smooth, progress=progress)
    if out is not None:
        write_outputs(result, out, figures=figures)
    return result


def write_outputs(result: Replay, out, figures: bool = True) -> Path:
    """The tables, the report, the figures and (a bag) the Odometry bag into out, all or nothing (output.py)."""
    from .output import output_folder, write_measurements, write_odometry, write_track
    from .report import write_report

    out = Path(out)
    names = result.model.state_names
    stamp0 = result.log.epoch + result.t0
    with output_folder(out) as folder:
        write_track(folder / "track.csv", result.track, names, stamp0)
        if result.smoothed is not None:
            write_track(folder / "smoothed.csv", result.smoothed, names, stamp0)
        write_measurements(folder / "measurements.csv", result, stamp0)
        write_report(result, folder)
        if figures:
            from .figures import write_figures

            write_figures(result, folder / "figures")
        if result.log.kind == "bag":
            write_odometry(folder / "odometry", result)
    return out
