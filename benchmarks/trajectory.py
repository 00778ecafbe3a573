"""A simulated rov4dof run for the per-step benches (bench_filters, step_times): inputs, measurements and noises.

It uses only a bundle's public ``f`` and ``h``, so step_times.py can import it when run against an older checkout
of abyssal (its before/after comparisons)."""
from __future__ import annotations

import numpy as np

DT = 0.1


def trajectory(bundle, steps: int, seed: int = 0):
    """x0, P0, Q, R, U (steps, n_u), Z (steps, n_y) of a simulated run."""
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
