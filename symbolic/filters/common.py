"""Symbols and model callables shared by the filter families."""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

from ..discretise import discrete_step, step_and_jacobian
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
    """f(x, u, p, dt) -> (x_next, F): the step and its state Jacobian (discretise.step_and_jacobian)."""
    x, u, p, dt = model.x, model.u, model.p, ca.SX.sym("dt")
    return ca.Function("f_and_F", [x, u, p, dt], list(step_and_jacobian(model, x, u, p, dt)))


def measurement(model: Model) -> ca.Function:
    """h(x, p)."""
    return ca.Function("h", [model.x, model.p], [model.y])
