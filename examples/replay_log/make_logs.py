"""Write a small simulated AUV log two ways, a rosbag2 (MCAP) bag and a folder of CSV tables, with their sensor maps.

    python make_logs.py [--out replay_demo] [--seconds 300] [--seed 0]

writes into OUT:

    gen/small_auv/     the model of auv.py, generated (abyssal.generate)
    auv_bag/           a rosbag2 bag (MCAP): /imu sensor_msgs/Imu (yaw and yaw rate, 10 Hz), /pressure
                       FluidPressure (5 Hz), /dvl TwistWithCovarianceStamped (2 Hz), /gps NavSatFix (1 Hz, at the
                       surface), /usbl PoseWithCovarianceStamped (every 4 s, recorded 0.3-0.8 s after its stamp)
    auv_csv/           the same samples as CSV tables (imu.csv, depth.csv, dvl.csv, gps.csv with latitude/longitude,
                       usbl.csv with its arrival time and standard deviations)
    map_bag.toml, map_csv.toml   the sensor maps of the two
    truth.csv          the simulated truth (t, north, east, down, psi, u, v, w)

then replay either one:

    abyssal replay OUT/auv_bag --model OUT/gen/small_auv --filter ckf --sensors OUT/map_bag.toml --out OUT/replay_bag --smooth
    abyssal replay OUT/auv_csv --model OUT/gen/small_auv --filter ckf --sensors OUT/map_csv.toml --out OUT/replay_csv --smooth

The truth is integrated in NumPy at 10 ms from the equations of auv.py (not from the generated model); the sensors
sample it with Gaussian noise at their rates. Every message carries what a ROS driver would put in it (REP-103:
ENU positions, FLU body axes, latitude/longitude about an origin off Toulon); the values the filter sees are decoded
from it (measurement_values) exactly as the replay decodes them, so a replay of either log equals the filter run
on these values in memory (tests/runtime/test_replay.py checks it to 1e-12).
"""
from __future__ import annotations

import argparse
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ORIGIN = (43.0, 6.0, 0.0)                 # latitude, longitude (deg), altitude (m) of the local NED origin
BASE_NS = 1_700_000_000_000_000_000       # the log's clock: ROS time of the first sample (2023-11-14)
SURFACE_PRESSURE, WATER_DENSITY, GRAVITY = 101325.0, 1025.0, 9.80665
STD = {"depth": 0.05, "heading": 0.02, "dvl": 0.02, "gps": 2.0, "usbl": 1.0}
PERIOD_NS = {"imu": 100_000_000, "depth": 200_000_000, "dvl": 500_000_000, "gps": 1_000_000_000, "usbl": 4_000_000_000}
STEP = 0.01                               # s: the truth's integration step


@dataclass
class Recording:
    """A simulated run: what each sensor put in its messages (raw, as a ROS driver would) and the truth."""

    truth_ns: np.ndarray
    truth: np.ndarray                          # (T, 7)
    imu: dict = field(default_factory=dict)    # t_ns, yaw (NED, rad), r (FRD yaw rate, rad/s)
    pressure: dict = field(default_factory=dict)   # t_ns, pressure (Pa)
    dvl: dict = field(default_factory=dict)    # t_ns, uvw (FRD, m/s)
    gps: dict = field(default_factory=dict)    # t_ns, lat, lon (deg)
    usbl: dict = field(default_factory=dict)   # t_ns, arrival_ns, ned (m), std (m)


def simulate(seed: int = 0, seconds: float = 300.0) -> Recording:
    """A dive: at the surface for the first and last fifth, down to 3 % of the duration in metres (10 m at most) at
    0.1 m/s between; weaving turns at ~1 m/s."""
    from abyssal.runtime.frames import ned_to_geodetic

    rng = np.random.default_rng(seed)
    T = int(round(seconds / STEP)) + 1
    t = np.arange(T) * STEP
    r = 0.06 * np.sin(2 * np.pi * t / 90.0)
    dive = min(10.0, 0.03 * seconds)                       # m, at 0.1 m/s down and up
    down_from, up_to = 0.2 * seconds, 0.8 * seconds
    ramp = 5.0                                             # s: heave changes over ~2 ramp (a depth controller)

    def between(a, b):
        return 0.05 * (np.tanh((t - a) / ramp) - np.tanh((t - b) / ramp))

    heave = between(down_from, down_from + dive / 0.1) - between(up_to - dive / 0.1, up_to)
    x = np.array([0.0, 0.0, 0.0, 0.3, 1.0, 0.0, 0.0])
    truth = np.empty((T, 7))
    for k in range(T):
        truth[k] = x
        north, east, down, psi, u, v, w = x
        x = x + STEP * np.array([u * math.cos(psi) - v * math.sin(psi), u * math.sin(psi) + v * math.cos(psi), w,
                                 r[k], 0.0, 0.0, 0.0])
        x[4:6] += math.sqrt(STEP) * rng.normal(scale=[0.01, 0.005])
        x[6] = heave[k] + 0.005 * rng.normal()
        x[2] = max(x[2], 0.0)
    truth_ns = BASE_NS + np.round(t * 1e9).astype(np.int64)
    rec = Recording(truth_ns, truth)

    def at(period_ns, offset_ns=0):
        stamps = np.arange(BASE_NS + offset_ns, truth_ns[-1] + 1, period_ns)
        return stamps, np.searchsorted(truth_ns, stamps)

    stamps, k = at(PERIOD_NS["imu"])
    rec.imu = {"t_ns": stamps, "yaw": truth[k, 3] + rng.normal(scale=STD["heading"], size=len(k)),
               "r": r[k] + rng.normal(scale=0.002, size=len(k))}
    stamps, k = at(PERIOD_NS["depth"], 20_000_000)
    depth = truth[k, 2] + rng.normal(scale=STD["depth"], size=len(k))
    rec.pressure = {"t_ns": stamps, "pressure": SURFACE_PRESSURE + WATER_DENSITY * GRAVITY * depth}
    stamps, k = at(PERIOD_NS["dvl"], 50_000_000)
    rec.dvl = {"t_ns": stamps, "uvw": truth[k, 4:7] + rng.normal(scale=STD["dvl"], size=(len(k), 3))}
    stamps, k = at(PERIOD_NS["gps"], 70_000_000)
    surface = truth[k, 2] < 0.3
    stamps, k = stamps[surface], k[surface]
    ne = truth[k, 0:2] + rng.normal(scale=STD["gps"], size=(len(k), 2))
    lat, lon, _ = ned_to_geodetic(ne[:, 0], ne[:, 1], np.zeros(len(k)), ORIGIN)
    rec.gps = {"t_ns": stamps, "lat": lat, "lon": lon}
    stamps, k = at(PERIOD_NS["usbl"], 2_000_000_000)
    latency = np.round(rng.uniform(0.3, 0.8, size=len(k)) * 1e9).astype(np.int64)
    rec.usbl = {"t_ns": stamps, "arrival_ns": stamps + latency,
                "ned": truth[k, 0:3] + rng.normal(scale=STD["usbl"], size=(len(k), 3)),
                "std": np.full((len(k), 3), STD["usbl"])}
    return rec


def measurement_values(rec: Recording) -> dict:
    """What the filter sees of each sensor, decoded from the raw values as the replay decodes a bag: {sensor: (stamps
    ns, arrivals ns, values (K, m), each sample's R or None)} and "input": (stamps, stamps, r (K, 1), None)."""
    from abyssal.runtime.frames import geodetic_to_ned

    depth = (rec.pressure["pressure"] - SURFACE_PRESSURE) / (WATER_DENSITY * GRAVITY)
    north, east, _ = geodetic_to_ned(rec.gps["lat"], rec.gps["lon"], np.zeros(len(rec.gps["lat"])), ORIGIN)
    usbl_R = np.array([np.diag(s ** 2) for s in rec.usbl["std"]])
    return {
        "input": (rec.imu["t_ns"], rec.imu["t_ns"], rec.imu["r"][:, None], None),
        "heading": (rec.imu["t_ns"], rec.imu["t_ns"], rec.imu["yaw"][:, None], None),
        "depth": (rec.pressure["t_ns"], rec.pressure["t_ns"], depth[:, None], None),
        "dvl": (rec.dvl["t_ns"], rec.dvl["t_ns"], rec.dvl["uvw"], None),
        "gps": (rec.gps["t_ns"], rec.gps["t_ns"], np.column_stack([north, east]), None),
        "usbl": (rec.usbl["t_ns"], rec.usbl["arrival_ns"], rec.usbl["ned"], usbl_R),
    }


# ---------------------------------------------------------------------------------------------- the bag

def write_bag(rec: Recording, path: Path, storage: str = "mcap") -> Path:
    """The recording as a rosbag2 bag (REP-103 frames; module docstring)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from abyssal.runtime.frames import euler_ned_to_quaternion, enu_to_ned_vector, flu_to_frd_vector

    store = get_typestore(Stores.ROS2_HUMBLE)
    T = store.types
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    Vector3, Quaternion, Point = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"], T["geometry_msgs/msg/Point"]

    def header(ns, frame="base_link"):
        return Header(stamp=Time(sec=int(ns) // 1_000_000_000, nanosec=int(ns) % 1_000_000_000), frame_id=frame)

    messages = []  # (record ns, topic, msgtype, message)
    for ns, yaw, r in zip(rec.imu["t_ns"], rec.imu["yaw"], rec.imu["r"]):
        q = euler_ned_to_quaternion([0.0, 0.0, yaw])
        cov = np.zeros(9)
        cov[8] = STD["heading"] ** 2
        msg = T["sensor_msgs/msg/Imu"](
            header=header(ns), orientation=Quaternion(*map(float, q)), orientation_covariance=cov,
            angular_velocity=Vector3(*map(float, flu_to_frd_vector([0.0, 0.0, r]))),
            angular_velocity_covariance=np.zeros(9), linear_acceleration=Vector3(0.0, 0.0, 0.0),
            linear_acceleration_covariance=np.array([-1.0] + [0.0] * 8))
        messages.append((int(ns), "/imu", "sensor_msgs/msg/Imu", msg))
    for ns, p in zip(rec.pressure["t_ns"], rec.pressure["pressure"]):
        msg = T["sensor_msgs/msg/FluidPressure"](header=header(ns), fluid_pressure=float(p),
                                                 variance=(WATER_DENSITY * GRAVITY * STD["depth"]) ** 2)
        messages.append((int(ns), "/pressure", "sensor_msgs/msg/FluidPressure", msg))
    for ns, uvw in zip(rec.dvl["t_ns"], rec.dvl["uvw"]):
        cov = np.zeros(36)
        cov[[0, 7, 14]] = STD["dvl"] ** 2
        twist = T["geometry_msgs/msg/Twist"](linear=Vector3(*map(float, flu_to_frd_vector(uvw))),
                                             angular=Vector3(0.0, 0.0, 0.0))
        msg = T["geometry_msgs/msg/TwistWithCovarianceStamped"](
            header=header(ns, "dvl"), twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=cov))
        messages.append((int(ns), "/dvl", "geometry_msgs/msg/TwistWithCovarianceStamped", msg))
    NavSatStatus = T["sensor_msgs/msg/NavSatStatus"]
    for ns, lat, lon in zip(rec.gps["t_ns"], rec.gps["lat"], rec.gps["lon"]):
        cov = np.diag([STD["gps"] ** 2, STD["gps"] ** 2, 16.0]).reshape(-1)
        msg = T["sensor_msgs/msg/NavSatFix"](header=header(ns, "gps"), status=NavSatStatus(status=0, service=1),
                                             latitude=float(lat), longitude=float(lon), altitude=0.0,
                                             position_covariance=cov, position_covariance_type=2)
        messages.append((int(ns), "/gps", "sensor_msgs/msg/NavSatFix", msg))
    for ns, arrival, ned, std in zip(rec.usbl["t_ns"], rec.usbl["arrival_ns"], rec.usbl["ned"], rec.usbl["std"]):
        cov = np.zeros((6, 6))
        cov[:3, :3] = np.diag(enu_to_ned_vector(std) ** 2)  # ENU: the east variance first
        pose = T["geometry_msgs/msg/Pose"](position=Point(*map(float, enu_to_ned_vector(ned))),
                                           orientation=Quaternion(0.0, 0.0, 0.0, 1.0))
        msg = T["geometry_msgs/msg/PoseWithCovarianceStamped"](
            header=header(ns, "map"), pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov.reshape(-1)))
        messages.append((int(arrival), "/usbl", "geometry_msgs/msg/PoseWithCovarianceStamped", msg))
    messages.sort(key=lambda m: m[0])
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        connections = {}
        for ns, topic, msgtype, msg in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], ns, store.serialize_cdr(msg, msgtype))
    return path


MAP_BAG = """# the sensor map of auv_bag (make_logs.py)
[input]
topic = "/imu"
fields = ["r"]                       # the gyro's yaw rate (FRD)

[sensors.heading]
topic = "/imu"
fields = ["yaw"]

[sensors.depth]
topic = "/pressure"
fields = ["depth"]

[sensors.dvl]
topic = "/dvl"
fields = ["u", "v", "w"]

[sensors.gps]
topic = "/gps"
fields = ["north", "east"]

[sensors.usbl]
topic = "/usbl"
fields = ["north", "east", "down"]
covariance = "message"               # each fix's own

[log]
origin = {origin}

{common}"""

MAP_CSV = """# the sensor map of auv_csv (make_logs.py)
[input]
table = "imu.csv"
fields = ["r"]

[sensors.heading]
table = "imu.csv"
fields = ["yaw"]

[sensors.depth]
table = "depth.csv"
fields = ["depth"]

[sensors.dvl]
table = "dvl.csv"
fields = ["u", "v", "w"]

[sensors.gps]
table = "gps.csv"
latitude = "lat"
longitude = "lon"
fields = ["north", "east"]

[sensors.usbl]
table = "usbl.csv"
arrival = "t_rx"                     # the fix reached the vehicle 0.3-0.8 s after its stamp
fields = ["north", "east", "down"]
std_columns = ["sd_north", "sd_east", "sd_down"]

[log]
origin = {origin}

{common}"""

COMMON = """[filter]
x0 = [0.0, 0.0, 0.0, 0.3, 1.0, 0.0, 0.0]
P0_std = [3.0, 3.0, 0.5, 0.1, 0.2, 0.2, 0.1]
Q_std = [0.002, 0.01, 0.005, 0.02]    # w_r (rad/s sqrt(s)), w_u, w_v, w_w (m/s sqrt(s))
noise = "inputs"
history_seconds = 2.0

[frames]
position = ["north", "east", "down"]
attitude = ["", "", "psi"]
body_velocity = ["u", "v", "w"]
fixes = ["gps", "usbl"]
"""


def write_csv(rec: Recording, folder: Path) -> Path:
    """The recording as CSV tables (times in seconds since the log's start; module docstring)."""
    folder.mkdir(parents=True, exist_ok=True)
    values = measurement_values(rec)

    def seconds(ns):
        return ((np.asarray(ns) - BASE_NS) * 1e-9).tolist()

    def table(name, header, columns):
        with open(folder / name, "w") as out:
            out.write(",".join(header) + "\n")
            for row in zip(*columns):
                out.write(",".join(repr(float(v)) for v in row) + "\n")

    table("imu.csv", ["t", "yaw", "r"], [seconds(rec.imu["t_ns"]), rec.imu["yaw"], rec.imu["r"]])
    table("depth.csv", ["t", "depth"], [seconds(values["depth"][0]), values["depth"][2][:, 0]])
    table("dvl.csv", ["t", "u", "v", "w"], [seconds(rec.dvl["t_ns"]), *rec.dvl["uvw"].T])
    table("gps.csv", ["t", "lat", "lon"], [seconds(rec.gps["t_ns"]), rec.gps["lat"], rec.gps["lon"]])
    table("usbl.csv", ["t", "t_rx", "north", "east", "down", "sd_north", "sd_east", "sd_down"],
          [seconds(rec.usbl["t_ns"]), seconds(rec.usbl["arrival_ns"]), *rec.usbl["ned"].T, *rec.usbl["std"].T])
    return folder


def write_maps(out: Path) -> tuple[Path, Path]:
    origin = repr(list(ORIGIN))
    (out / "map_bag.toml").write_text(MAP_BAG.format(origin=origin, common=COMMON))
    (out / "map_csv.toml").write_text(MAP_CSV.format(origin=origin, common=COMMON))
    return out / "map_bag.toml", out / "map_csv.toml"


def write_truth(rec: Recording, path: Path) -> None:
    with open(path, "w") as out:
        out.write("t,north,east,down,psi,u,v,w\n")
        for ns, x in zip(rec.truth_ns[::10], rec.truth[::10]):
            out.write(",".join([repr((int(ns) - BASE_NS) * 1e-9)] + [repr(float(v)) for v in x]) + "\n")


def main(argv=None) -> Path:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="replay_demo")
    parser.add_argument("--seconds", type=float, default=300.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    import sys

    import abyssal

    sys.path.insert(0, str(HERE))
    from auv import small_auv

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rec = simulate(args.seed, args.seconds)
    folder = abyssal.generate(small_auv(), out / "gen")
    bag = out / "auv_bag"
    if bag.exists():
        import shutil

        shutil.rmtree(bag)
    write_bag(rec, bag)
    write_csv(rec, out / "auv_csv")
    write_maps(out)
    write_truth(rec, out / "truth.csv")
    print(f"wrote {bag} (MCAP), {out / 'auv_csv'} (CSV tables), {out}/map_bag.toml, {out}/map_csv.toml, {folder}; "
          f"replay: abyssal replay {bag} --model {folder} --filter ckf --sensors {out}/map_bag.toml --out "
          f"{out}/replay_bag --smooth")
    return out


if __name__ == "__main__":
    main()
