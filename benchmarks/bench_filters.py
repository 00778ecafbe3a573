"""Filter section of `abyssal bench`: per-step (predict + update) cost on rov4dof beside peers
measured in the same run.

Ours:   EKF, UKF, CKF runtime classes (abyssal.runtime.filters.kalman), ``step(u, dt, z)`` through a
        simulated trajectory (EKF and CKF: one fused generated call per step; UKF: predict and
        update calls), the CKF with separate predict() and update() calls, and the bare bound C
        evaluations of the CKF (no Python checks) to show the runtime's own overhead.
Peers:  filterpy's UnscentedKalmanFilter with MerweScaledSigmaPoints(1, 0, 0) (the same CKF)
        calling the compiled model through the bundle's f and h, and a vectorised NumPy CKF
        calling the compiled model through f_batch / h_batch (SIMD kernels) with NumPy algebra.

Targets: CKF step <= 6 us and >= 250x faster than filterpy; EKF step <= 2.5 us.
"""
from __future__ import annotations

import numpy as np

from abyssal import generated
from abyssal.runtime.filters.kalman import CKF, EKF, UKF

from bench import json_main, median_time, target

MODEL = "rov4dof"
DT = 0.1


def trajectory(bundle, steps: int, seed: int = 0):
    """Inputs, measurements and noise matrices of a simulated run."""
    rng = np.random.default_rng(seed)
    n = bundle.n_x
    Q = np.diag([1e-4] * 8 + [1e-2] * 4)
    R = np.diag([0.05, 0.05, 0.02, 0.01])
    t = DT * np.arange(steps)
    # surge, sway and heave thrust with a yaw moment swinging the heading back and forth
    U = np.column_stack([np.full(steps, 20.0), np.full(steps, 5.0), np.full(steps, 10.0), 0.5 * np.sin(0.2 * t)])
    U += 0.5 * rng.normal(size=U.shape)
    x = np.zeros(n)
    Z = np.empty((steps, bundle.n_y))
    for k in range(steps):
        x = bundle.f(x, U[k], None, DT) + rng.multivariate_normal(np.zeros(n), Q)
        Z[k] = bundle.h(x) + rng.multivariate_normal(np.zeros(bundle.n_y), R)
    return np.zeros(n), 0.3 * np.eye(n), Q, R, U, Z


def per_step(step, steps: int, reset, quick: bool) -> float:
    """Median seconds per step of step(k) over a sequence, restarting it with reset()."""
    def sequence():
        reset()
        for k in range(steps):
            step(k)
    return median_time(sequence, repeat=3 if quick else 7, min_time=0.02 if quick else 0.1) / steps


def numpy_ckf_step(bundle, Q, R):
    """A vectorised NumPy CKF step (seed 000 eqs. 22-29) calling the compiled model in batch."""
    n = bundle.n_x
    xi = np.sqrt(n) * np.hstack([np.eye(n), -np.eye(n)])

    def step(x, P, u, z):
        X = x[:, None] + np.linalg.cholesky(P) @ xi
        Y = bundle.f_batch(X, u, None, DT)
        x = Y.mean(axis=1)
        D = Y - x[:, None]
        P = D @ D.T / (2 * n) + Q
        X = x[:, None] + np.linalg.cholesky(P) @ xi
        Zs = bundle.h_batch(X)
        z_pred = Zs.mean(axis=1)
        DZ = Zs - z_pred[:, None]
        DZ[3] = (DZ[3] + np.pi) % (2 * np.pi) - np.pi
        S = DZ @ DZ.T / (2 * n) + R
        Pxz = (X - x[:, None]) @ DZ.T / (2 * n)
        K = np.linalg.solve(S, Pxz.T).T
        nu = z - z_pred
        nu[3] = (nu[3] + np.pi) % (2 * np.pi) - np.pi
        return x + K @ nu, P - K @ S @ K.T
    return step


def run(quick: bool = False, verbose: bool = True) -> dict:
    bundle = generated.load(MODEL)
    steps = 100 if quick else 400
    x0, P0, Q, R, U, Z = trajectory(bundle, steps)
    results: dict = {"model": MODEL, "steps": steps, "per_step_us": {}}
    times = results["per_step_us"]

    for cls in (EKF, UKF, CKF):
        flt = cls(bundle, x0, P0, Q, R)

        def step(k, flt=flt):
            flt.step(U[k], DT, Z[k])
        times[cls.__name__] = 1e6 * per_step(step, steps, lambda flt=flt: flt.reset(x0, P0), quick)

    ckf = CKF(bundle, x0, P0, Q, R)
    # the bound C calls alone (buffer set k reads, 1 - k receives), with the same inputs and no checks
    predict_eval, update_eval, step_eval = ckf._c_predict, ckf._c_update, ckf._c_step
    u_buffer, z_buffer, dt_buffer = ckf._u, ckf._z, ckf._dt

    def reset_bare():
        ckf.reset(x0, P0)
        dt_buffer[0] = DT

    def bare(k):
        u_buffer[:] = U[k]
        z_buffer[:] = Z[k]
        predict_eval[ckf._cur]()
        update_eval[1 - ckf._cur]()
    times["CKF, bound C predict + update only"] = 1e6 * per_step(bare, steps, reset_bare, quick)

    def bare_fused(k):
        u_buffer[:] = U[k]
        z_buffer[:] = Z[k]
        step_eval[(ckf._cur + k) % 2]()  # the state alternates between the two sets from the current one
    times["CKF, bound C fused step only"] = 1e6 * per_step(bare_fused, steps, reset_bare, quick)

    def separate(k):
        ckf.predict(U[k], DT)
        ckf.update(Z[k])
    times["CKF, predict() then update()"] = 1e6 * per_step(separate, steps, lambda: ckf.reset(x0, P0), quick)

    fp_steps = 10 if quick else 40
    try:
        from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter
    except ImportError:
        results["filterpy"] = "not installed (pip install 'abyssal[test]')"
    else:
        points = MerweScaledSigmaPoints(bundle.n_x, alpha=1.0, beta=0.0, kappa=0.0)
        ukf = UnscentedKalmanFilter(bundle.n_x, bundle.n_y, DT, hx=bundle.h, fx=None, points=points)
        ukf.Q, ukf.R = Q, R

        def reset_filterpy():
            ukf.x, ukf.P = x0.copy(), P0.copy()

        def filterpy_step(k):
            ukf.predict(fx=lambda s, dt: bundle.f(s, U[k], None, dt))
            ukf.update(Z[k])
        times["filterpy UKF (cubature points)"] = 1e6 * per_step(filterpy_step, fp_steps, reset_filterpy, quick)

    np_step = numpy_ckf_step(bundle, Q, R)
    state = {}

    def reset_numpy():
        state["x"], state["P"] = x0.copy(), P0.copy()

    def numpy_step(k):
        state["x"], state["P"] = np_step(state["x"], state["P"], U[k], Z[k])
    times["NumPy CKF (f_batch, h_batch)"] = 1e6 * per_step(numpy_step, fp_steps, reset_numpy, quick)

    ckf_us = times["CKF"]
    ratios = {"NumPy CKF / CKF": times["NumPy CKF (f_batch, h_batch)"] / ckf_us,
              "CKF / its bound C fused step": ckf_us / times["CKF, bound C fused step only"]}
    if "filterpy UKF (cubature points)" in times:
        ratios["filterpy / CKF"] = times["filterpy UKF (cubature points)"] / ckf_us
    results["ratios"] = ratios

    if verbose:
        print(f"per step (predict + update) on {MODEL}, median:")
        for name, us in times.items():
            print(f"  {name:<34} {us:10.2f} us")
        for name, ratio in ratios.items():
            print(f"  {name:<34} {ratio:10.1f} x")

    targets = [
        target("CKF step (rov4dof)", ckf_us, 6.0, "us"),
        target("EKF step (rov4dof)", times["EKF"], 2.5, "us"),
    ]
    if "filterpy / CKF" in ratios:
        targets.append(target("CKF speed-up over filterpy", ratios["filterpy / CKF"], 250.0, "x", higher_is_better=True))
    return {"results": results, "targets": targets}


if __name__ == "__main__":  # python benchmarks/bench_filters.py [--quick]: this section alone, as JSON
    json_main(run, __doc__)
