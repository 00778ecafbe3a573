"""Symbols, model callables and the call structure shared by the filter families.

Generated filter steps are built from *leaves*: plain SX Functions (the model's step f, its
measurement h, the sigma points of (x, P), the moments of the propagated points, an update's
algebra) that are emitted once per C file and called (``leaf``). A step that evaluates f at 2n
points holds one copy of f and 2n calls to it, so the generated C grows with the model plus the
O(n^3) dense algebra, not with (points x model); a fused step calls its family's predict and update
instead of repeating them. Each leaf has its divisions by a shared divisor turned into one
reciprocal (reciprocals.share_reciprocals).

A small step is the exception (``exported``): when its leaves inlined come to at most
FLAT_MAX_INSTRUCTIONS operations (a 2-4 state model such as cn2d), it is emitted as one flat SX
expression, because there the calls (arguments copied per call, u, p and dt copied per point) cost
more than the arithmetic they wrap (benchmarks/README.md, "Flat steps for small models").
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

from ..codegen import FUNCTION_OPTIONS
from ..discretise import discrete_step, step_and_jacobian
from ..model import Model
from .reciprocals import share_reciprocals

#: a generated step whose leaves, inlined, come to at most this many SX operations (``inlined_size``, before
#: CasADi's common-subexpression pass) is emitted flat (module docstring): every step of cn2d (at most 473) and
#: linear_cv's but its fused ckf_step (1551); rov4dof's steps are 4600-32000 and keep their calls
FLAT_MAX_INSTRUCTIONS = 1500


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


def leaf(name: str, inputs, outputs, names_in, names_out, dense: bool = True) -> ca.Function:
    """A plain SX Function, divisions shared, that generated steps call instead of inlining.

    dense=False keeps the outputs' structural sparsity (a Jacobian passed on to another leaf, which
    then skips its structural zeros); exported entry points always densify.
    """
    fn = ca.Function(name, list(inputs), [ca.densify(e) if dense else e for e in outputs], list(names_in),
                     list(names_out), FUNCTION_OPTIONS)
    return share_reciprocals(fn)


def step_inputs(model: Model, names, extra: dict[str, tuple[int, int]] | None = None) -> dict[str, ca.MX]:
    """MX symbols of an exported step's inputs, by name, in order: FilterSymbols fields in their
    shapes, then `extra` (name -> shape, e.g. a rule's abk)."""
    symbols = filter_symbols(model)
    inputs = {name: ca.MX.sym(name, *getattr(symbols, name).shape) for name in names}
    inputs.update({name: ca.MX.sym(name, *shape) for name, shape in (extra or {}).items()})
    return inputs


def exported(name: str, inputs: dict[str, ca.MX], outputs: dict[str, ca.MX]) -> ca.Function:
    """A generated entry point: an MX graph of calls to leaves, their buffers passed without copies, or, when
    its leaves inlined come to at most FLAT_MAX_INSTRUCTIONS operations, that one flat SX expression."""
    fn = ca.Function(name, list(inputs.values()), [ca.densify(e) for e in outputs.values()], list(inputs),
                     list(outputs), FUNCTION_OPTIONS)
    if inlined_size(fn) > FLAT_MAX_INSTRUCTIONS:
        return fn
    return fn.expand(name, FUNCTION_OPTIONS)


def inlined_size(fn: ca.Function) -> int:
    """The SX operations of fn with every call inlined (a serial map counted once per column), without inlining."""
    if fn.is_a("SXFunction"):
        return fn.n_instructions()
    if fn.is_a("Map"):
        inner = fn.get_function(fn.get_function()[0])
        repeats = max(fn.size2_in(i) // inner.size2_in(i) for i in range(fn.n_in()) if inner.size2_in(i))
        return repeats * inlined_size(inner)
    return sum(inlined_size(fn.instruction_MX(k).which_function()) if fn.instruction_id(k) == ca.OP_CALL else 1
               for k in range(fn.n_instructions()))


def call_columns(fn: ca.Function, X: ca.MX, *shared: ca.MX) -> ca.MX:
    """[fn(X[:, 0], *shared), fn(X[:, 1], *shared), ...] as one serial loop (Function.map); CasADi repeats
    the shared inputs for the loop (a copy of u, p, dt per point, cheap beside f)."""
    n_shared = len(shared)
    mapped = fn.map(f"{fn.name()}_columns", "serial", X.size2(), list(range(1, 1 + n_shared)), [])
    return mapped(X, *shared)


def transition(model: Model) -> ca.Function:
    """f(x, u, p, dt): one discrete step at zero noise input (the model's <m>_f), as a leaf."""
    x, u, p, w, dt = model.x, model.u, model.p, model.w, ca.SX.sym("dt")
    x_next = discrete_step(model, x, u, p, w, dt)
    if model.n_w:
        x_next = ca.substitute(x_next, w, ca.DM.zeros(w.shape))
    return leaf(f"{model.name}_step", [x, u, p, dt], [x_next], ["x", "u", "p", "dt"], ["x_next"])


def transition_with_jacobian(model: Model) -> ca.Function:
    """f(x, u, p, dt) -> (x_next, F): the step and its state Jacobian (discretise.step_and_jacobian), as a
    leaf; F keeps its structural sparsity."""
    x, u, p, dt = model.x, model.u, model.p, ca.SX.sym("dt")
    return leaf(f"{model.name}_step_and_jacobian", [x, u, p, dt], list(step_and_jacobian(model, x, u, p, dt)),
                ["x", "u", "p", "dt"], ["x_next", "F"], dense=False)


def measurement(model: Model) -> ca.Function:
    """h(x, p), as a leaf."""
    return leaf(f"{model.name}_measurement", [model.x, model.p], [model.y], ["x", "p"], ["y"])
