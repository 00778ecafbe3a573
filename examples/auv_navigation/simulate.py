"""The simulated truth of one dive and what the AUV's sensors report of it.

    dive = simulate(bundle, seed=1, mission=Mission())
    dive.t, dive.x (K+1, 12), dive.u (K+1, 3)       every base step of 0.01 s: the truth and the input held after it
    dive.measurements                              Measurement(stamp, arrival, sensor, z, R) in arrival order

The vehicle is the REMUS 100 under the autopilot of seed 004's simulator (runtime/experiments/remus/scenario.py:
LOS guidance and the three PIDs of REMUS100-SPEC 6-7, on the true state) along the spec's helix, here with a depth
profile: at the surface for `surface_time` s, down at `dive_rate` to `max_depth`, and back up to the surface for the
last `surface_time` s. Unknown body forces and moments w (white, power spectral density FORCE_PSD, held over each base
step) push it off its course; the model's own RK4 with w held (auv.truth_step) integrates it.

Sensors (auv.py): each a Gaussian noise of its declared standard deviation on h_k(x_true) at its own stamps on the
0.01 s clock. The DVL stays silent during the bottom-lock loss. GNSS reports only while the true depth is above
`gnss_depth` (the antenna out of the water). A USBL fix is pinged every `usbl_period` s (a random phase of up to 40 ms
off the 20 Hz clock of the AHRS), its noise grows with the slant range from the ship at `ship` (usbl_sigma), it
reports that quality figure (from the fix itself, not from the truth) and arrives 0.3-1.0 s after its ping.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from abyssal.runtime.experiments.remus.scenario import Autopilot, HelixSetup, helix_point
from abyssal.runtime.numerics import wrap_to_pi

#: base steps per second (the vehicle, the autopilot and every sensor stamp live on this clock)
CLOCK = 100
#: the truth's unknown body forces and moments: white noise with this power spectral density (N^2 s, N^2 m^2 s);
#: the filters are given it as their Q (noise="inputs")
FORCE_PSD = np.array([0.2, 0.5, 0.5, 0.002, 0.05, 0.05])
SENSOR_ORDER = ("dvl", "depth", "ahrs", "gnss", "usbl")


@dataclass(frozen=True)
class Mission:
    """What the dive does and when its sensors speak (seconds, metres)."""

    duration: float = 600.0
    surface_time: float = 60.0            # at the surface at the start and at the end
    max_depth: float = 10.0
    dive_rate: float = 0.1                # m/s down and up
    lock_loss: tuple = (300.0, 360.0)     # the DVL loses bottom lock (no measurement) over [start, end)
    gnss_depth: float = 0.3               # GNSS reports while the true depth is above this
    usbl_period: float = 4.0
    usbl_latency: tuple = (0.3, 1.0)
    ship: tuple = (0.0, 0.0, 0.0)         # the USBL transceiver, NED (above the helix centre)
    rates: dict = field(default_factory=lambda: {"dvl": 5, "depth": 10, "ahrs": 20, "gnss": 1})  # Hz

    def depth(self, t: float) -> tuple[float, float]:
        """The path's depth and its rate at t: a trapezoid between the surface phases."""
        down = (t - self.surface_time) * self.dive_rate
        up = (self.duration - self.surface_time - t) * self.dive_rate
        if min(down, up) <= 0.0:
            return 0.0, 0.0
        if min(down, up) >= self.max_depth:
            return self.max_depth, 0.0
        return (down, self.dive_rate) if down <= up else (up, -self.dive_rate)

    def surfaced(self, t: float) -> bool:
        return t < self.surface_time or t >= self.duration - self.surface_time


@dataclass(frozen=True)
class Measurement:
    """One sensor report: stamped at its measurement time, known to the navigator at its arrival time."""

    stamp: float
    arrival: float
    sensor: str
    z: np.ndarray
    R: np.ndarray | None = None           # the sensor's own covariance of this report (None: its declared noise)


@dataclass
class Dive:
    mission: Mission
    t: np.ndarray                         # (K+1,) the base clock
    x: np.ndarray                         # (K+1, 12) the true state
    u: np.ndarray                         # (K+1, 3) the input held over [t_k, t_k+1)
    measurements: list                    # Measurement, in arrival order

    def input_at(self, t: float) -> np.ndarray:
        """The input held at time t (the autopilot's output of the base step containing t)."""
        return self.u[min(int(math.floor(t * CLOCK + 1e-9)), len(self.u) - 1)]

    def truth_at(self, t: np.ndarray) -> np.ndarray:
        """The true state at times on the base clock."""
        return self.x[np.rint(np.asarray(t) * CLOCK).astype(int)]


def usbl_sigma(position, ship) -> float:
    """A USBL fix's standard deviation per axis: 0.2 m plus 1 % of the slant range."""
    return 0.2 + 0.01 * float(np.linalg.norm(np.asarray(position) - np.asarray(ship)))


def mission_setup(mission: Mission) -> HelixSetup:
    """The remus helix set-up for this mission: its duration, starting at the surface on the helix's start, and a
    depth lookahead Delta_z of 10 m instead of the helix's 50 m (seed 1 with 50 m: 0.82 m deep when the path reaches
    the surface at 540 s, 0.32 m at 570 s, 97 GNSS fixes instead of 128)."""
    x0 = (0.5, 0, 0, 0, 0, 0, 60, 3, 0, 0, 0, 3 * math.pi / 4)
    return HelixSetup(duration=mission.duration, x0=x0, delta_z=10.0)


def mission_path(mission: Mission):
    """The helix's horizontal track with the mission's depth profile: path(t, s) -> (P, dP/dt)."""
    def path(t: float, s: HelixSetup):
        P, dP = helix_point(t, s)
        P[2], dP[2] = mission.depth(t)
        return P, dP
    return path


def simulate(bundle, seed: int, mission: Mission | None = None) -> Dive:
    """One dive: the truth at every base step and the sensors' reports (seeded with `seed`)."""
    mission = mission or Mission()
    rng = np.random.default_rng(seed)
    setup = mission_setup(mission)
    K = int(round(mission.duration * CLOCK))
    p = bundle.params()
    x, x_next, u, w = np.array(setup.x0, dtype=float), np.zeros(12), np.zeros(3), np.zeros(6)
    dt = np.array([1.0 / CLOCK])
    step = bundle.function("truth_step").bind([x, u, p, w, dt], [x_next]).eval
    force_sigma = np.sqrt(FORCE_PSD * CLOCK)  # white noise held over one base step
    autopilot = Autopilot(setup, mission_path(mission))
    X, U = np.empty((K + 1, 12)), np.empty((K + 1, 3))
    for k in range(K + 1):
        autopilot(k, x[0:6], x[6:9], x[9:12], u)
        X[k], U[k] = x, u
        if k == K:
            break
        w[:] = force_sigma * rng.standard_normal(6)
        step()
        x[:] = x_next
    t = np.arange(K + 1) / CLOCK
    return Dive(mission, t, X, U, measure(bundle, mission, t, X, rng))


def measure(bundle, mission: Mission, t: np.ndarray, X: np.ndarray, rng) -> list:
    """Every sensor's reports of the true states X at the base-clock times t, in arrival order."""
    sigma = {s["name"]: np.sqrt(np.diag(s["noise"])) for s in bundle.sensors}
    lever = bundle.params()[bundle.parameter_names.index("dvl_lever_x"):][:3]
    out = []

    def report(k, sensor, h, R=None, arrival=None):
        stamp = t[k]
        out.append(Measurement(stamp, stamp if arrival is None else arrival, sensor, h, R))

    for name, rate in mission.rates.items():
        for k in range(0, len(t), CLOCK // rate):
            x = X[k]
            if name == "dvl":
                if mission.lock_loss[0] <= t[k] < mission.lock_loss[1]:
                    continue
                h = x[0:3] + np.cross(x[3:6], lever)
            elif name == "depth":
                h = x[8:9]
            elif name == "ahrs":
                h = x[9:12]
            else:
                if not x[8] < mission.gnss_depth:
                    continue
                h = x[6:8]
            z = h + sigma[name] * rng.standard_normal(h.size)
            report(k, name, wrap_to_pi(z) if name == "ahrs" else z)
    period = int(round(mission.usbl_period * CLOCK))
    for ping in range(period // 2, len(t), period):
        k = ping + int(rng.integers(1, 5))  # the ping's phase against the 20 Hz clock: 10-40 ms after an AHRS stamp
        if k >= len(t):
            break
        fix = X[k, 6:9] + usbl_sigma(X[k, 6:9], mission.ship) * rng.standard_normal(3)
        quality = usbl_sigma(fix, mission.ship)
        arrival = round(t[k] + rng.uniform(*mission.usbl_latency), 3)
        if arrival <= mission.duration:
            report(k, "usbl", fix, np.eye(3) * quality**2, arrival)
    order = {name: i for i, name in enumerate(SENSOR_ORDER)}
    return sorted(out, key=lambda m: (m.arrival, order[m.sensor], m.stamp))
