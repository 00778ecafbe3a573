"""Truth simulator of seed 004's helix run (the simulated world of experiment.py): REMUS100-SPEC.md sections 5-9.

    log = simulate(seed=1)          # 800 s, vehicle at 0.01 s, logged at 5 Hz
    log.t, log.x (T, 12), log.u (T, 3), log.z (T, 10)

The vehicle (abyssal's generated ``remus100_f``, 2 RK4 substeps per 0.01 s call) always runs
closed loop: the model is open-loop unstable at trim (spec 10). Per base step of 0.01 s the
helix point P(t) (spec 5), the PID outputs (held between their 0.4 s updates, spec 7) and the
feedback-linearising terms make the input, which is held over the step. The EWMA rpm
smoothing runs every base step. Sensors (spec 8): Gaussian noise redrawn every 0.1 s and held,
quantised with the per-channel LSBs, clipped and wrapped; channels [u v w p q r z phi theta psi].

Decisions (the spec's, each a field of :class:`HelixSetup`): D6 exact path and vehicle
velocities (no numerical derivatives); D7 ``feedback="true"`` (controllers see the true state;
"measured" feeds them the sensor values of nu, z and Theta); D8 the [S] LSBs ("12-bit" is
nominal); D9 logging every 20th base step. One departure: D9 asks for RK4 at 0.01 s; the
generated step does two RK4 substeps of 0.005 s per 0.01 s call (more accurate, not less).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ...numerics import wrap_to_pi as wrap

STATE_NAMES = ("u", "v", "w", "p", "q", "r", "x", "y", "z", "phi", "theta", "psi")
CHANNELS = ("u", "v", "w", "p", "q", "r", "z", "phi", "theta", "psi")
#: spec 8: sigma of the held noise samples and the quantisation step of each channel (0: none)
SENSOR_SIGMA = np.array([5.48e-4, 1.41e-3, 3.16e-4, 3.16e-4, 1e-3, 1e-3, 1e-3, 1e-4, 1e-3, 1e-2])
SENSOR_LSB = np.array([4 / 2**12, 4 / 2**12, 4 / 2**12, 0.0, 0.0, 0.0, 100 / 2**14, 2 * np.pi / 2**14,
                       2 * np.pi / 2**12, np.pi / 2**12])
#: measurement covariance a filter should use: the held noise plus uniform quantisation error LSB^2/12
SENSOR_R = np.diag(SENSOR_SIGMA**2 + SENSOR_LSB**2 / 12)


@dataclass(frozen=True)
class HelixSetup:
    """The run set-up of spec 5-9 (defaults are the spec's values and decisions)."""

    duration: float = 800.0             # s
    base_dt: float = 0.01               # s, vehicle and input update (D9)
    log_every: int = 20                 # base steps per logged sample: 5 Hz (D9)
    x0: tuple = (0.5, 0, 0, 0, 0, 0, 60, 3, 0, 0, 0, 3 * math.pi / 4)
    radius: float = 60.0                # m, spec 5
    omega: float = 0.02618              # rad/s of the ramped time t_r = 0.9 t
    depth0: float = 2.0                 # m
    descent: float = 0.01               # m per second of t_r
    ramp: float = 0.9
    k_y: float = 1.0                    # spec 6
    k_z: float = 1.0
    delta_y: float = 150.0              # m
    delta_z: float = 50.0               # m ([M] uses 150: not used)
    k_x: float = 0.05                   # 1/s ([M] uses 0.001: not used)
    U_max: float = 2.5                  # m/s
    pid_period: float = 0.4             # s, spec 7
    speed_pid: tuple = (100.0, 1.0, 2.0)
    elevator_pid: tuple = (2.0, 0.0, 0.5)
    rudder_pid: tuple = (3.0, 0.0, 1.0)
    ewma_lambda: float = 0.9
    feedback: str = "true"              # D7: "true" or "measured"
    noise_hold: float = 0.1             # s, spec 8
    model_params: tuple | None = None   # remus100 parameter vector; None: the defaults

    def __post_init__(self):
        if self.feedback not in ("true", "measured"):
            raise ValueError("feedback must be 'true' (D7, [S]) or 'measured'")


@dataclass
class HelixLog:
    """The 5 Hz record of one run."""

    t: np.ndarray        # (T,)
    x: np.ndarray        # (T, 12) true state
    u: np.ndarray        # (T, 3) inputs applied over [t_k, t_k + base_dt), held by the filters over the log step
    z: np.ndarray        # (T, 10) sensor readings
    reference: np.ndarray = field(default=None)  # (T, 3) helix point P(t)

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])


def helix_point(t: float, s: HelixSetup) -> tuple[np.ndarray, np.ndarray]:
    """P(t) and its exact time derivative (spec 5, D6)."""
    tr = s.ramp * t
    a = s.omega * tr
    P = np.array([s.radius * math.cos(a), s.radius * math.sin(a), s.depth0 + s.descent * tr])
    dP = s.ramp * np.array([-s.radius * s.omega * math.sin(a), s.radius * s.omega * math.cos(a), s.descent])
    return P, dP


def rotation(phi, theta, psi) -> np.ndarray:
    cf, sf, ct, st, cp, sp = math.cos(phi), math.sin(phi), math.cos(theta), math.sin(theta), math.cos(psi), math.sin(psi)
    return np.array([[cp * ct, cp * st * sf - sp * cf, cp * st * cf + sp * sf],
                     [sp * ct, sp * st * sf + cp * cf, sp * st * cf - cp * sf],
                     [-st, ct * sf, ct * cf]])


def los_guidance(t: float, nu, pos, euler, s: HelixSetup, path=helix_point) -> tuple[float, float, float, float, float]:
    """(u_d, chi_d, upsilon_d, chi, upsilon) of spec 6, along path(t, s) -> (P, dP/dt) (the helix by default)."""
    if t == 0.0:
        return 1.0 * nu[0] / max(math.sqrt(nu[0] ** 2 + nu[1] ** 2 + nu[2] ** 2), 1e-12), 0.0, 0.0, 0.0, 0.0
    pdot = rotation(*euler) @ nu[0:3]
    chi = math.atan2(pdot[1], pdot[0])
    horizontal = math.hypot(pdot[0], pdot[1])
    upsilon = math.atan(-pdot[2] / horizontal) if horizontal > 0 else 0.0
    P, dP = path(t, s)
    psi_p = math.atan2(dP[1], dP[0])
    theta_p = math.atan(-dP[2] / math.hypot(dP[0], dP[1]))
    d = pos - P
    cps, sps, ctp, stp = math.cos(psi_p), math.sin(psi_p), math.cos(theta_p), math.sin(theta_p)
    x_e = cps * ctp * d[0] + sps * ctp * d[1] - stp * d[2]
    y_e = -sps * d[0] + cps * d[1]
    z_e = cps * stp * d[0] + sps * stp * d[1] + ctp * d[2]
    psi_r = math.tanh(-s.k_y * y_e / s.delta_y)
    theta_r = math.tanh(s.k_z * z_e / s.delta_z)
    cpr, spr, ctr, strr = math.cos(psi_r), math.sin(psi_r), math.cos(theta_r), math.sin(theta_r)
    upsilon_d = math.asin(stp * ctr * cpr + ctp * strr)
    chi_d = math.atan2(cps * spr * ctr - stp * strr * sps + sps * cpr * ctp * ctr,
                       -sps * spr * ctr - stp * strr * cps + cps * cpr * ctp * ctr)
    U_d = (math.sqrt(float(dP @ dP)) - s.k_x * x_e) / (cpr * ctr)
    U_d = min(max(U_d, 0.0), s.U_max)
    speed = math.sqrt(nu[0] ** 2 + nu[1] ** 2 + nu[2] ** 2)
    u_d = U_d * nu[0] / speed if speed > 0 else U_d
    return u_d, chi_d, upsilon_d, chi, upsilon


class DiscretePID:
    """y_k = P e_k + I_k + D (e_k - e_{k-1}) / T_s; I_{k+1} = I_k + I T_s e_k (spec 7)."""

    def __init__(self, gains, period):
        self.kp, self.ki, self.kd = gains
        self.period = period
        self.integral = 0.0
        self.previous = 0.0

    def __call__(self, e: float) -> float:
        y = self.kp * e + self.integral + self.kd * (e - self.previous) / self.period
        self.integral += self.ki * self.period * e
        self.previous = e
        return y


class Autopilot:
    """The vehicle's controllers (spec 6-7): LOS guidance along path(t, s) and the three discrete PIDs, updated every
    pid_period and held, with the feedback-linearising terms and the EWMA of the rpm evaluated every base step.

        autopilot = Autopilot(setup)              # the helix; Autopilot(setup, path) for another path
        autopilot(k, nu, pos, euler, u)           # base step k: writes the input held over [k, k + 1) base steps into u
    """

    def __init__(self, s: HelixSetup, path=helix_point):
        self.s, self.path = s, path
        self.pid_every = int(round(s.pid_period / s.base_dt))
        self.speed_pid = DiscretePID(s.speed_pid, s.pid_period)
        self.elevator_pid = DiscretePID(s.elevator_pid, s.pid_period)
        self.rudder_pid = DiscretePID(s.rudder_pid, s.pid_period)
        self.y_u = self.y_ups = self.y_chi = 0.0
        self.ewma_w = self.ewma_s = 0.0

    def __call__(self, k: int, nu, pos, euler, u: np.ndarray) -> None:
        s = self.s
        if k % self.pid_every == 0:
            u_d, chi_d, ups_d, chi, ups = los_guidance(k * s.base_dt, nu, pos, euler, s, self.path)
            self.y_u = self.speed_pid(u_d - nu[0])
            self.y_ups = self.elevator_pid(ups_d - ups)
            self.y_chi = self.rudder_pid(math.atan2(math.sin(chi_d - chi), math.cos(chi_d - chi)))
        vu, vv, vw, vq, vr = nu[0], nu[1], nu[2], nu[4], nu[5]
        a = 31.40 * self.y_u - 65.97 * vv * vr + 65.97 * vw * vq
        self.ewma_w = s.ewma_lambda * self.ewma_w + 1.0
        self.ewma_s = (1.0 - 1.0 / self.ewma_w) * self.ewma_s + a / self.ewma_w
        u[0] = self.ewma_s
        u[1] = 8.33 * self.y_ups - 34.57 * vu * vw + 9.81 * 0.0196 * math.sin(euler[1])
        u[2] = 8.33 * self.y_chi + 34.57 * vu * vv


def sensor_noise(seed: int, s: HelixSetup) -> np.ndarray:
    """Held Gaussian noise samples, one row per 0.1 s (spec 8); seed = run index."""
    n_hold = int(math.ceil(s.duration / s.noise_hold)) + 2
    return np.random.default_rng(seed).normal(size=(n_hold, len(CHANNELS))) * SENSOR_SIGMA


def measure(x: np.ndarray, noise: np.ndarray) -> np.ndarray:
    """y = Q(h(x) + n): quantise, clip u v w to [-1, 3] m/s and z to +-100 m, wrap angles (spec 8)."""
    h = np.array([x[0], x[1], x[2], x[3], x[4], x[5], x[8], x[9], x[10], wrap(x[11])]) + noise
    h[9] = wrap(h[9])                     # psi wrapped before quantising
    q = SENSOR_LSB > 0
    h[q] = SENSOR_LSB[q] * np.round(h[q] / SENSOR_LSB[q])
    h[0:3] = np.clip(h[0:3], -1.0, 3.0)
    h[6] = np.clip(h[6], -100.0, 100.0)
    h[7:9] = wrap(h[7:9])                 # phi, theta wrapped after quantising
    return h


def simulate(seed: int, setup: HelixSetup | None = None, bundle=None) -> HelixLog:
    """One closed-loop helix run; the sensor noise stream is seeded with `seed` (the run index)."""
    from abyssal import generated

    s = setup or HelixSetup()
    bundle = bundle or generated.load("remus100")
    params = bundle.params() if s.model_params is None else bundle.params(np.asarray(s.model_params, dtype=float))
    noise = sensor_noise(seed, s)
    n_base = int(round(s.duration / s.base_dt))
    hold_every = int(round(s.noise_hold / s.base_dt))

    x = np.array(s.x0, dtype=float)
    x_next = np.zeros(12)
    u = np.zeros(3)
    step = bundle.functions["f"].bind([x, u, params, np.array([s.base_dt])], [x_next]).eval
    autopilot = Autopilot(s)

    n_log = n_base // s.log_every + 1
    T, X, Uo, Z, Ref = np.empty(n_log), np.empty((n_log, 12)), np.empty((n_log, 3)), np.empty((n_log, 10)), np.empty((n_log, 3))
    for k in range(n_base + 1):
        t = k * s.base_dt
        held = noise[k // hold_every]
        logged = k % s.log_every == 0
        if s.feedback == "measured" or logged:
            y = measure(x, held)
        # the state the controllers see (D7)
        if s.feedback == "true":
            nu, depth, euler = x[0:6], x[8], x[9:12]
        else:
            nu, depth, euler = y[0:6], y[6], y[7:10]
        autopilot(k, nu, np.array([x[6], x[7], depth]), euler, u)
        if logged:
            i = k // s.log_every
            T[i], X[i], Uo[i], Z[i] = t, x, u, y
            Ref[i] = helix_point(t, s)[0]
        if k == n_base:
            break
        step()
        x[:] = x_next
    return HelixLog(T, X, Uo, Z, Ref)
