"""Discretisations of continuous dynamics, with the step dt a symbolic (runtime) input.

``discrete_step`` and ``step_and_jacobian`` are the only way the rest of abyssal (codegen, every
filter family) reaches a model's step, so a discrete model (x_next given directly) and a
discretised continuous one are interchangeable from here on.
"""
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


def given_step(model) -> ca.Function:
    """The step of a discrete model as a Function of (x, u, p, w, dt)."""
    return ca.Function("x_next", [model.x, model.u, model.p, model.w, model.dt], [model.x_next])


def discrete_step(model, x, u, p, w, dt) -> ca.SX:
    """x_{k+1} of `model` with u, p and the noise input w held constant over dt."""
    if model.is_discrete:
        return given_step(model)(x, u, p, w, dt)
    rhs_fn = ca.Function("rhs", [model.x, model.u, model.p, model.w], [model.xdot])
    return SCHEMES[model.discretisation](lambda s: rhs_fn(s, u, p, w), x, dt, model.substeps)


def _variational_step(model, x, u, p, dt, wrt: str) -> tuple[ca.SX, ca.SX]:
    """(x_{k+1}, J) at zero noise input, J = d x_{k+1} / d x_k (wrt="x") or d x_{k+1} / d w (wrt="w").

    The model's explicit scheme (Euler or RK4, with its substeps) applied to the augmented state
    (x, J): differentiating an explicit Runge-Kutta step is the same scheme applied to the
    variational equation dJ/dt = A(x) J (+ B(x) for w, which enters every stage directly),
    A = d xdot / dx, B = d xdot / dw, with J(0) = I for x and 0 for w. A discrete model's given
    step is differentiated by AD instead.
    """
    n = model.n_x
    w0 = ca.DM.zeros(model.w.shape)
    target = model.x if wrt == "x" else model.w
    if model.is_discrete:
        jac = ca.Function("x_next_and_jacobian", [model.x, model.u, model.p, model.w, model.dt],
                          [model.x_next, ca.jacobian(model.x_next, target)])
        return jac(x, u, p, w0, dt)
    cols = target.numel()
    forcing = [ca.jacobian(model.xdot, model.w)] if wrt == "w" else []
    rhs = ca.Function("rhs_and_jacobians", [model.x, model.u, model.p, model.w],
                      [model.xdot, ca.jacobian(model.xdot, model.x), *forcing])

    def variational(s):  # s = (x, vec J)
        xdot, A, *B = rhs(s[:n], u, p, w0)
        dJ = ca.mtimes(A, ca.reshape(s[n:], n, cols))
        return ca.vertcat(xdot, ca.vec(dJ + B[0] if B else dJ))

    J0 = ca.SX.eye(n) if wrt == "x" else ca.SX.zeros(n, cols)
    s = SCHEMES[model.discretisation](variational, ca.vertcat(x, ca.vec(J0)), dt, model.substeps)
    return s[:n], ca.reshape(s[n:], n, cols)


def step_and_jacobian(model, x, u, p, dt) -> tuple[ca.SX, ca.SX]:
    """(x_{k+1}, F = d x_{k+1} / d x_k) at zero noise input, F by the discrete variational equation.

    The explicit scheme of the model (Euler or RK4, with its substeps) is applied to the
    augmented state (x, J) with J(0) = I and dJ/dt = A(x) J, A = d xdot / dx (_variational_step):
    J after the step is exactly the Jacobian of x_{k+1} (up to rounding: the products associate
    differently). Working with the small sparse A at each stage (30 nonzeros on rov4dof) instead
    of differentiating the whole unrolled step takes rov4dof's (f, F) from 2358 to 1664 SX
    instructions; x_{k+1} is the same expression as ``discrete_step``'s, and F keeps its
    structural sparsity.
    """
    return _variational_step(model, x, u, p, dt, "x")


def noise_jacobian(model, x, u, p, dt) -> ca.SX:
    """G = d x_{k+1} / d w at w = 0, the noise input held over the step, by the variational equation.

    dJ_w/dt = A(x) J_w + B(x), J_w(0) = 0 (_variational_step) is exactly the derivative of the
    scheme's step in w. It works with the small sparse A and B instead of differentiating the
    unrolled step (rov4dof's G: 4122 -> 2903 SX instructions, remus100's 21520 -> 14925).
    """
    return _variational_step(model, x, u, p, dt, "w")[1]
