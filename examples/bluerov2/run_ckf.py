"""Simulate a BlueROV2 Heavy dive and track it with the cubature and the extended Kalman filter.

Run after `abyssal regenerate --model bluerov2.py:bluerov2 --out gen` (see README.md):

    python run_ckf.py          # prints the RMSE and the mean NEES of each filter

The truth is the compiled model itself driven by the thrusts of a dive (sink for 40 s to ~9 m,
then run ahead through slow turns) plus a random generalised force held over each step (sigma
1 N, 0.05 N m in roll and pitch, 0.02 N m in yaw), entering the step through the compiled
G = df/dw (to first order). Sensors, each at its own rate (a NaN entry of Z is a sensor that did
not report at that step): depth 10 Hz (sigma 2 cm), AHRS 10 Hz (roll and pitch 0.5 deg, heading
2 deg), DVL 5 Hz (1 cm/s), USBL 1 Hz (0.5 m). Predictions at 10 Hz. The filters' Q is the same
force noise mapped onto the state by G at rest, so a consistent filter has a mean NEES near
n_x = 12. Seeded: the numbers repeat run to run.
"""
from pathlib import Path

import numpy as np

import abyssal

HERE = Path(__file__).resolve().parent
DT, STEPS = 0.1, 1500
FORCE_SIGMA = np.array([1.0, 1.0, 1.0, 0.05, 0.05, 0.02])  # N, N m: the truth's generalised-force noise
SENSOR_SIGMA = np.array([0.02, *np.radians([0.5, 0.5, 2.0]), 0.01, 0.01, 0.01, 0.5, 0.5])  # z, AHRS, DVL, USBL
SENSOR_EVERY = np.array([1, 1, 1, 1, 2, 2, 2, 10, 10])  # steps between reports of each output
HORIZONTAL, VERTICAL = np.array([1.0, 1.0, -1.0, -1.0]), np.ones(4)  # thruster mixes: ahead, down
TURN = np.array([-1.0, 1.0, 1.0, -1.0])  # the horizontal mix giving a yaw moment (positive: to starboard)


def thrusts(t: np.ndarray) -> np.ndarray:
    """(T, 8) thrust per thruster: 40 s sinking at 5 N per vertical thruster, then 3 N ahead per
    horizontal thruster with a +-0.02 N yaw mix swinging over 60 s, the vertical thrusters pushing
    0.85 N each down (the vehicle is ~1 N buoyant, and driven ahead it pitches ~15 deg nose up and
    climbs: its horizontal thrusters sit below CO)."""
    sink = np.where(t < 40.0, 5.0, 0.85)
    ahead = np.where(t < 40.0, 0.0, 3.0)
    turn = np.where(t < 40.0, 0.0, 0.02 * np.sin(2 * np.pi * (t - 40.0) / 60.0))
    return np.column_stack([ahead[:, None] * HORIZONTAL + turn[:, None] * TURN, sink[:, None] * VERTICAL])


def simulate(rov, rng):
    """Truth X (T, 12), thrusts U (T, 8), measurements Z (T, 9) with NaN where a sensor is silent."""
    U = thrusts(np.arange(STEPS) * DT)
    X, Z = np.empty((STEPS, 12)), np.full((STEPS, 9), np.nan)
    x = np.zeros(12)
    for k in range(STEPS):
        w = FORCE_SIGMA * rng.standard_normal(6)
        x = rov.f(x, U[k], None, DT) + rov.G(x, U[k], None, DT) @ w
        X[k] = x
        reports = k % SENSOR_EVERY == 0
        Z[k, reports] = (rov.h(x) + SENSOR_SIGMA * rng.standard_normal(9))[reports]
    return X, U, Z


def main():
    rov = abyssal.load(HERE / "gen" / "bluerov2")
    rng = np.random.default_rng(0)
    X, U, Z = simulate(rov, rng)
    G = rov.G(np.zeros(12), np.zeros(8), None, DT)  # (12, 6): state change per unit force noise
    Q = G @ np.diag(FORCE_SIGMA**2) @ G.T + 1e-10 * np.eye(12)
    R = np.diag(SENSOR_SIGMA**2)
    x0 = np.zeros(12)
    P0 = np.diag([1.0, 1.0, 0.1, 0.01, 0.01, 0.1, 0.01, 0.01, 0.01, 0.01, 0.01, 0.01])

    angles = (3, 4, 5)
    print(f"BlueROV2 Heavy dive: {STEPS * DT:.0f} s, final depth {X[-1, 2]:.1f} m, "
          f"{np.hypot(*X[-1, :2]):.1f} m from the start")
    for name, cls in (("CKF", abyssal.CKF), ("EKF", abyssal.EKF)):
        result = cls(rov, x0, P0, Q, R).run(U, Z, DT, truth=X)
        rmse = result.rmse(X, angle_states=angles)
        print(f"{name}  RMSE  position {np.hypot(rmse[0], rmse[1]):.3f} m  depth {rmse[2]:.3f} m  "
              f"roll/pitch/heading {' / '.join(f'{d:.2f}' for d in np.degrees(rmse[3:6]))} deg  "
              f"velocity {np.sqrt(np.mean(rmse[6:9] ** 2)):.4f} m/s   "
              f"mean NEES {np.nanmean(result.nees):.1f} (consistent: ~12)")


if __name__ == "__main__":
    main()
