"""Discretisations of continuous dynamics, with the step dt a symbolic (runtime) input."""
from __future__ import annotations

from typing import Callable

import casadi as ca

Rhs = Callable[[ca.SX], ca.SX]


def euler_step(rhs: Rhs, x: ca.SX, dt, substeps: int = 1) -> ca.SX:
    """Explicit Euler over dt in `substeps` equal steps; rhs(x) is the continuous derivative."""
    h = dt / substeps
    for _ in range(substeps):
        x = x + h * rhs(x)
    return x


def rk4_step(rhs: Rhs, x: ca.SX, dt, substeps: int = 1) -> ca.SX:
    """Classic fourth-order Runge-Kutta over dt in `substeps` equal steps (inputs held constant)."""
    h = dt / substeps
    for _ in range(substeps):
        k1 = rhs(x)
        k2 = rhs(x + h / 2 * k1)
        k3 = rhs(x + h / 2 * k2)
        k4 = rhs(x + h * k3)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


SCHEMES = {"euler": euler_step, "rk4": rk4_step}


def discrete_step(model, x, u, p, w, dt) -> ca.SX:
    """x_{k+1} of `model` with u, p and the noise input w held constant over dt."""
    rhs_fn = ca.Function("rhs", [model.x, model.u, model.p, model.w], [model.xdot])
    return SCHEMES[model.discretisation](lambda s: rhs_fn(s, u, p, w), x, dt, model.substeps)
