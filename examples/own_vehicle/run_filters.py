"""Track CyberShip II with a cubature Kalman filter and a particle filter; write the figure.

Run after `abyssal regenerate --model cybership.py:cybership --out gen` (see README.md):

    python run_filters.py          # writes cybership_filters.png and prints the RMSE of each filter

The truth is simulated with the compiled model itself plus process noise (a weaving manoeuvre
at ~0.5 m/s), GNSS fixes (sigma 0.3 m) and compass readings (sigma 2 deg) at 1 Hz, predictions at
10 Hz (NaN rows of Z are steps without a measurement). Seeded: the numbers repeat run to run.
"""
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import abyssal  # noqa: E402

HERE = Path(__file__).resolve().parent
DT, STEPS, MEASURE_EVERY = 0.1, 1500, 10


def simulate(vessel, rng):
    """Truth X (T, 6), inputs U (T, 3), measurements Z (T, 3) with NaN rows between fixes."""
    Q = np.diag([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4])  # additive on the discrete state, per step
    R = np.diag([0.3**2, 0.3**2, np.radians(2.0) ** 2])
    t = np.arange(STEPS) * DT
    U = np.column_stack([0.4 + 0.0 * t, 0.02 * np.sin(0.05 * t), 0.06 * np.sin(2 * np.pi * t / 100)])
    X, Z = np.empty((STEPS, 6)), np.full((STEPS, 3), np.nan)
    x = np.zeros(6)
    for k in range(STEPS):
        x = vessel.f(x, U[k], None, DT) + rng.multivariate_normal(np.zeros(6), Q)
        X[k] = x
        if k % MEASURE_EVERY == 0:
            Z[k] = vessel.h(x) + rng.multivariate_normal(np.zeros(3), R)
    return X, U, Z, Q, R


def main():
    vessel = abyssal.load(HERE / "gen" / "cybership")
    rng = np.random.default_rng(0)
    X, U, Z, Q, R = simulate(vessel, rng)
    x0, P0 = np.zeros(6), np.diag([1.0, 1.0, 0.1, 0.05, 0.05, 0.01])

    ckf = abyssal.CKF(vessel, x0, P0, Q, R)
    ckf_x = np.array([(ckf.step(U[k], DT, Z[k]), ckf.x)[1] for k in range(STEPS)])

    pf = abyssal.ParticleFilter(vessel, x0, P0, abyssal.GaussianMixture.gaussian(np.zeros(6), Q),
                                abyssal.GaussianMixture.gaussian(np.zeros(3), R), n_particles=2000, rng=1)
    pf_x = np.array([(pf.step(U[k], DT, Z[k]), pf.x)[1] for k in range(STEPS)])

    for name, est in (("CKF", ckf_x), ("PF (2000 particles)", pf_x)):
        err = est - X
        err[:, 2] = np.angle(np.exp(1j * err[:, 2]))
        print(f"{name:<20} RMSE  position {np.sqrt(np.mean(err[:, :2] ** 2)):.3f} m   "
              f"heading {np.degrees(np.sqrt(np.mean(err[:, 2] ** 2))):.2f} deg")

    fig, (track, errors) = plt.subplots(1, 2, figsize=(11, 4.5))
    track.plot(X[:, 1], X[:, 0], "k-", lw=2, label="truth")
    track.plot(Z[:, 1], Z[:, 0], ".", color="0.6", label="GNSS fixes")
    track.plot(ckf_x[:, 1], ckf_x[:, 0], "-", label="CKF")
    track.plot(pf_x[:, 1], pf_x[:, 0], "--", label="PF")
    track.set(xlabel="east [m]", ylabel="north [m]", title="CyberShip II track", aspect="equal")
    track.legend()
    t = np.arange(STEPS) * DT
    for name, est in (("CKF", ckf_x), ("PF", pf_x)):
        err = np.hypot(*(est[:, :2] - X[:, :2]).T)
        errors.plot(t, err, label=name)
    errors.set(xlabel="time [s]", ylabel="position error [m]", title="estimation error")
    errors.legend()
    fig.tight_layout()
    out = HERE / "cybership_filters.png"
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
