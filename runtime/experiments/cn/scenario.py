"""A simulated lake trial for cooperative navigation (seed 002, section 4): the real one is not public.

The authors' September 2014 Lake Thai data (one AUV, two surface leaders with GPS, ATM-885
modems, DS-99 DVL, HZ001 compass) was never published, so every number abyssal reports for seed
002 comes from this simulation. What is simulated, and which choices are ours:

* Follower AUV (truth at 1 Hz, T = 1760 s): 1.5 m/s forward, a lawnmower of five legs (east,
  north, west, north, east; 60 s turns at a constant rate), a small sway speed (AR(1), 0.05 m/s).
  Its path lies between the two leaders, as in the paper's Fig. 6.
* Leaders (CNAs): two surface vessels, one north and one south of the AUV's path (the paper's Fig. 6: "AUV
  was between two leaders"), each keeping a fixed offset from (the AUV's smoothed east position, the survey's
  centre line) and broadcasting its GPS position with every packet (OEMV-2RT-2, 1.8 m CEP: sigma = 1.8 /
  1.1774 = 1.53 m per axis, ours from the CEP). The paper does not publish the geometry (its text gives no
  positions, and its Fig. 6 is not in our copy), and the geometry decides how well a range pair fixes the AUV:
  ``GEOMETRIES`` names three layouts, and ``crossing_angles`` / ``gdop`` measure each trial's. "collinear"
  (the default, this scenario's first layout: leader 0 250 m ahead and 400 m north, leader 1 250 m behind
  and 400 m south) puts both leaders on one line through the AUV at the centre line: over the pings of 10
  trials the two range lines cross at a median 12 deg (10th percentile 0.3 deg, never above 18 deg; 2-range
  GDOP median 6.7, 90th percentile 260), so the direction along the range lines is barely observed.
  "crossing60" and "crossing90" put both leaders ahead of the AUV, one north and one south: the lines cross
  at a median 62 deg (55-68) and 88 deg (85-90), GDOP 1.6 and 1.4.
* Acoustic channel: one range every 5 s, the two leaders alternating (time-division: leader 0 at
  t = 5, 15, 25 ... s, leader 1 at t = 10, 20, ...), so each leader pings every 10 s. Each leader is a
  sensor of its own in cn2d (``leader0``, ``leader1``: one range each, the leader's broadcast position its own
  parameters p_k): a ping is that sensor's update alone (``Trial.ping``). The stacked form (``Trial.Z``: both
  sensors' entries, NaN for the leader that did not ping; ``Trial.params``: both leaders' positions, the silent
  one's last broadcast held) is what the filters without a per-sensor update consume.
* Dead reckoning from the DVL and compass at 1 Hz (Table 4): DVL forward/starboard speed with a
  per-run scale-factor error drawn uniformly in 0.1-0.3 % (random sign) and 0.3 % white noise;
  compass white noise 0.3 deg plus -- our assumption for a "realistic DR drift" -- a per-run
  magnetic deviation delta(theta) = A + B sin(theta) + C cos(theta), A, B, C ~ N(0, (2 deg)^2),
  which Table 4's accuracy does not include (a heading-dependent deviation does not cancel on
  the lawnmower's reversed legs). It gives DR errors of tens of metres over the 2.6 km run.
* Filter input: the filters step once per ping (dt = 5 s) with u = [c, 0, theta] chosen so that
  eq. 2 reproduces the dead-reckoned displacement over the 5 s exactly (c = |d| / dt, theta =
  atan2(d_y, d_x)); so every filter's prediction is the DR track and Q = diag(10^2, 10^2) m^2 is
  per 5 s step, as printed.
* Range noise (the true errors, R_true = 1 m^2: sigma = 1 m, ours; the paper gives no value):
  ``gaussian`` N(0, R_true); ``eps0.1`` / ``eps0.3`` eq. (1) v ~ (1 - eps) N(0, R_true) +
  eps N(0, 10 R_true); ``multipath`` N(0, R_true) plus, at 5 % of pings, a late arrival adding
  U(10, 60) m (always positive, the heavy right tail of the paper's Fig. 5).
* Start: the AUV dives at a GPS fix; x0 = truth + N(0, (1.53 m)^2 I), P0 = (3 m)^2 I.
* APE (eq. 46) is averaged over the 352 ping times (the filters' steps), not over 1760 samples.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NOISE_CASES = ("gaussian", "eps0.1", "eps0.3", "multipath")
GPS_SIGMA = 1.8 / 1.1774  # 1.8 m CEP -> per-axis sigma
#: leader layouts: each leader's (east, north) offset in m from (the AUV's smoothed east position, the centre
#: line of the survey); at the centre line the range lines cross at 0, 60 and 90 deg (the AUV's north-south
#: legs move it +-150 m off that line, which spreads the angle over a run: ``crossing_angles``)
GEOMETRIES = {
    "collinear": ((250.0, 400.0), (-250.0, -400.0)),
    "crossing60": ((400.0 / np.sqrt(3.0), 400.0), (400.0 / np.sqrt(3.0), -400.0)),
    "crossing90": ((400.0, 400.0), (400.0, -400.0)),
}


@dataclass(frozen=True)
class CnScenario:
    """Set-up of the simulated trial (defaults: module docstring)."""

    duration: float = 1760.0
    ping_period: float = 5.0
    speed: float = 1.5
    leg_seconds: tuple = (520.0, 60.0, 500.0, 60.0, 500.0)  # east, north, west, north, east (+ turns)
    turn_seconds: float = 30.0
    leaders: tuple = GEOMETRIES["collinear"]  # ((east, north) of leader 0, of leader 1), m (GEOMETRIES)
    range_variance: float = 1.0  # R_true, m^2
    outlier_scale: float = 10.0  # eq. (1): N(0, 10 R)
    multipath_rate: float = 0.05
    multipath_delay: tuple = (10.0, 60.0)
    dvl_scale: tuple = (0.001, 0.003)
    dvl_noise: float = 0.003
    compass_noise_deg: float = 0.3
    compass_bias_deg: float = 2.0
    gps_sigma: float = GPS_SIGMA
    initial_sigma: float = 3.0


@dataclass
class Trial:
    """One simulated trial, sampled at the K ping times (step k: predict with U[k], update with Z[k])."""

    t: np.ndarray        # (K,) ping times, s
    truth: np.ndarray    # (K, 2) true AUV position
    U: np.ndarray        # (K, 3) filter input [c, s, theta] reproducing the DR displacement
    Z: np.ndarray        # (K, 2) the sensors leader0, leader1 stacked: the ping's range, NaN for the silent leader
    params: np.ndarray   # (K, 4) both leaders' broadcast (GPS) positions: the pinging one's, the other's last held
    leader: np.ndarray   # (K,) which leader pinged
    ranges: np.ndarray   # (K,) the ping's measured range (to leader[k])
    gps: np.ndarray      # (K, 2) the pinging leader's broadcast position (its sensor's own p at that ping)
    dr: np.ndarray       # (K, 2) dead-reckoned position
    x0: np.ndarray
    P0: np.ndarray
    dt: float
    leaders_true: np.ndarray  # (2, K, 2)
    range_error: np.ndarray   # (K,) the true range noise drawn


def _headings(sc: CnScenario, t: np.ndarray) -> np.ndarray:
    """True heading (counter-clockwise from east) at times t: legs joined by constant-rate turns."""
    targets = [0.0, np.pi / 2, np.pi, np.pi / 2, 0.0]
    bounds = np.cumsum(sc.leg_seconds)
    theta = np.zeros_like(t)
    for i in range(1, len(targets)):
        start = bounds[i - 1]
        frac = np.clip((t - start) / sc.turn_seconds, 0.0, 1.0)
        theta += np.where(t >= start, frac * (targets[i] - targets[i - 1]), 0.0)
    return theta


def simulate(sc: CnScenario, case: str, rng: np.random.Generator) -> Trial:
    """One trial of noise case `case` (NOISE_CASES). The leaders' layout draws no random numbers, so one rng
    state gives the same AUV, sensors and range noise under every layout."""
    if case not in NOISE_CASES:
        raise ValueError(f"unknown noise case {case!r}; choose one of {NOISE_CASES}")
    if np.shape(sc.leaders) != (2, 2) or not np.all(np.isfinite(sc.leaders)):
        raise ValueError(f"leaders must be two finite (east, north) offsets, got {sc.leaders!r}")
    n = int(round(sc.duration))
    t = np.arange(n + 1, dtype=float)  # 1 Hz
    theta = _headings(sc, t)
    sway = np.zeros(n + 1)
    for i in range(1, n + 1):
        sway[i] = 0.98 * sway[i - 1] + 0.05 * np.sqrt(1 - 0.98**2) * rng.standard_normal()
    c = np.full(n + 1, sc.speed)
    vel = np.stack([c * np.cos(theta) + sway * np.sin(theta), c * np.sin(theta) - sway * np.cos(theta)], axis=1)
    truth = np.vstack([[0.0, 0.0], np.cumsum(vel[:-1], axis=0)])  # x_{i+1} = x_i + v_i (1 s)
    # sensors
    scale = rng.uniform(*sc.dvl_scale) * rng.choice([-1.0, 1.0])
    c_m = c * (1 + scale) + sc.dvl_noise * sc.speed * rng.standard_normal(n + 1)
    s_m = sway * (1 + scale) + sc.dvl_noise * sc.speed * rng.standard_normal(n + 1)
    A, B, C = np.deg2rad(sc.compass_bias_deg) * rng.standard_normal(3)
    bias = A + B * np.sin(theta) + C * np.cos(theta)
    th_m = theta + bias + np.deg2rad(sc.compass_noise_deg) * rng.standard_normal(n + 1)
    v_m = np.stack([c_m * np.cos(th_m) + s_m * np.sin(th_m), c_m * np.sin(th_m) - s_m * np.cos(th_m)], axis=1)
    x0 = truth[0] + sc.gps_sigma * rng.standard_normal(2)
    dr = np.vstack([x0, x0 + np.cumsum(v_m[:-1], axis=0)])
    # leaders: follow the AUV's east position (smoothed), north/south of the centre line
    centre_y = 0.5 * (truth[:, 1].max() + truth[:, 1].min())
    lead_x = np.convolve(np.pad(truth[:, 0], 60, mode="edge"), np.ones(121) / 121, mode="valid")
    leaders = np.stack([np.stack([lead_x + dx, np.full(n + 1, centre_y + dy)], 1) for dx, dy in sc.leaders])
    # pings
    step = int(round(sc.ping_period))
    idx = np.arange(step, n + 1, step)
    K = idx.size
    which = np.arange(K) % 2
    lead_true = leaders[which, idx]
    true_range = np.linalg.norm(truth[idx] - lead_true, axis=1)
    sd = np.sqrt(sc.range_variance)
    noise = sd * rng.standard_normal(K)
    if case.startswith("eps"):
        eps = float(case[3:])
        outlier = rng.random(K) < eps
        noise = np.where(outlier, np.sqrt(sc.outlier_scale) * sd * rng.standard_normal(K), noise)
    elif case == "multipath":
        late = rng.random(K) < sc.multipath_rate
        noise = noise + np.where(late, rng.uniform(*sc.multipath_delay, K), 0.0)
    ranges = true_range + noise
    gps = lead_true + sc.gps_sigma * rng.standard_normal((K, 2))
    Z = np.full((K, 2), np.nan)
    Z[np.arange(K), which] = ranges
    params = np.empty((K, 4))
    for j in range(2):  # each leader's broadcast, held between its pings (and its first one before it)
        mine = np.flatnonzero(which == j)
        held = mine[np.clip(np.searchsorted(mine, np.arange(K), side="right") - 1, 0, None)]
        params[:, 2 * j:2 * j + 2] = gps[held]
    d = dr[idx] - dr[idx - step]
    dt = float(step)
    U = np.stack([np.linalg.norm(d, axis=1) / dt, np.zeros(K), np.arctan2(d[:, 1], d[:, 0])], axis=1)
    return Trial(t=t[idx], truth=truth[idx], U=U, Z=Z, params=params, leader=which, ranges=ranges, gps=gps, dr=dr[idx], x0=x0,
                 P0=np.eye(2) * sc.initial_sigma**2, dt=dt, leaders_true=leaders[:, idx], range_error=noise)


def ping(trial: Trial, k: int) -> tuple[str, np.ndarray, np.ndarray]:
    """(sensor, z, p) of ping k: the cn2d sensor of the leader that pinged, its range and its broadcast position."""
    return f"leader{int(trial.leader[k])}", trial.ranges[k:k + 1], trial.gps[k]


def position_errors(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """PE(k) of eq. 45 (K,)."""
    return np.linalg.norm(np.asarray(estimate)[:, :2] - truth[:, :2], axis=1)


def ape(estimate: np.ndarray, truth: np.ndarray) -> float:
    """APE of eq. 46: the mean position error."""
    return float(position_errors(estimate, truth).mean())


def line_of_sight(trial: Trial) -> np.ndarray:
    """(2, K, 2) unit vectors from the AUV's true position to each leader's true position at every ping."""
    d = trial.leaders_true - trial.truth[None]
    return d / np.linalg.norm(d, axis=2, keepdims=True)


def crossing_angles(trial: Trial) -> np.ndarray:
    """(K,) the acute angle (deg) at which the two range lines (circles about the leaders) cross at the AUV's
    true position, at every ping: 90 deg observes both axes equally, 0 deg leaves the direction along the
    range lines unobserved."""
    u = line_of_sight(trial)
    cos = np.clip(np.abs(np.sum(u[0] * u[1], axis=1)), 0.0, 1.0)
    return np.degrees(np.arccos(cos))


def gdop(trial: Trial) -> np.ndarray:
    """(K,) geometric dilution of precision of the two ranges at the AUV's true position: sqrt(trace((H^T H)^-1))
    with H the two unit lines of sight, = sqrt(2) / sin(crossing angle) (1.41 at 90 deg; inf when collinear)."""
    s = np.sin(np.radians(crossing_angles(trial)))
    with np.errstate(divide="ignore"):
        return np.where(s > 0, np.sqrt(2.0) / s, np.inf)
