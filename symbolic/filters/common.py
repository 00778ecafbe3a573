"""Symbols and model callables shared by the filter families."""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

from ..discretise import SCHEMES, discrete_step
from ..model import Model


@dataclass(frozen=True)
class FilterSymbols:
    """The runtime inputs of generated filter steps (names are the C argument names)."""

    x: ca.SX      # (n_x,) state mean
    P: ca.SX      # (n_x, n_x) state covariance
    u: ca.SX      # (n_u,) input
    p: ca.SX      # (n_p,) model parameters
    dt: ca.SX     # step length, s
    Q: ca.SX      # (n_x, n_x) additive process-noise covariance over dt
    z: ca.SX      # (n_y,) measurement
    R: ca.SX      # (n_y, n_y) measurement-noise covariance
    mask: ca.SX   # (n_y,) 1 = entry used, 0 = ignored


def filter_symbols(model: Model) -> FilterSymbols:
    n, m = model.n_x, model.n_y
    return FilterSymbols(
        x=ca.SX.sym("x", n), P=ca.SX.sym("P", n, n), u=ca.SX.sym("u", model.n_u), p=ca.SX.sym("p", model.n_p),
        dt=ca.SX.sym("dt"), Q=ca.SX.sym("Q", n, n), z=ca.SX.sym("z", m), R=ca.SX.sym("R", m, m),
        mask=ca.SX.sym("mask", m),
    )


def transition(model: Model) -> ca.Function:
    """f(x, u, p, dt): one discrete step at zero noise input (the model's <m>_f)."""
    x, u, p, w, dt = model.x, model.u, model.p, model.w, ca.SX.sym("dt")
    x_next = discrete_step(model, x, u, p, w, dt)
    if model.n_w:
        x_next = ca.substitute(x_next, w, ca.DM.zeros(w.shape))
    return ca.Function("f", [x, u, p, dt], [x_next])


def transition_with_jacobian(model: Model) -> ca.Function:
    """f(x, u, p, dt) -> (x_next, F = d x_next / d x), F by the discrete variational equation.

    The explicit scheme of the model (Euler or RK4, with its substeps) is applied to the
    augmented state (x, J) with J(0) = I and dJ/dt = A(x) J, A = d xdot / dx: differentiating an
    explicit Runge-Kutta step is the same scheme applied to the variational equation, so J after
    the step is exactly the Jacobian of x_next (up to rounding: the products are associated
    differently). Working with the small sparse A at each stage (30 nonzeros on rov4dof) instead
    of differentiating the whole unrolled step (``ca.jacobian`` of f) takes rov4dof's (f, F) from
    2358 to 1664 SX instructions. x_next is the same expression as in ``transition`` (bitwise).
    F keeps its structural sparsity (rov4dof: 53 of 144 entries).
    """
    n = model.n_x
    x, u, p, dt = model.x, model.u, model.p, ca.SX.sym("dt")
    w0 = ca.DM.zeros(model.w.shape)  # zero noise input, as in transition()
    rhs = ca.Function("rhs_and_jacobian", [model.x, model.u, model.p, model.w],
                      [model.xdot, ca.jacobian(model.xdot, model.x)])

    def variational(s):  # s = (x, vec J)
        xdot, A = rhs(s[:n], u, p, w0)
        return ca.vertcat(xdot, ca.vec(ca.mtimes(A, ca.reshape(s[n:], n, n))))

    s = SCHEMES[model.discretisation](variational, ca.vertcat(x, ca.vec(ca.SX.eye(n))), dt, model.substeps)
    return ca.Function("f_and_F", [x, u, p, dt], [s[:n], ca.reshape(s[n:], n, n)])


def measurement(model: Model) -> ca.Function:
    """h(x, p)."""
    return ca.Function("h", [model.x, model.p], [model.y])
