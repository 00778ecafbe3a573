"""The explicit description of a vehicle model: what abyssal generates C from.

A model is a plain function returning a :class:`Model`: named states, inputs, runtime
parameters (with units and defaults), process-noise inputs, continuous dynamics
``xdot = f(x, u, p, w)`` and a measurement ``y = h(x, p)``, all as CasADi SX expressions.

Parameters are a runtime input of every generated function, so a user can change a
vehicle's mass or a leader vehicle's position without regenerating C; their defaults
are recorded in the manifest and used when the runtime is given ``p=None``.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import casadi as ca


@dataclass(frozen=True)
class Quantity:
    """A named scalar of a model (a state, input, noise input or output)."""

    name: str
    unit: str
    description: str = ""


@dataclass(frozen=True)
class Parameter:
    """A runtime parameter with its default value."""

    name: str
    unit: str
    default: float
    description: str = ""


@dataclass(frozen=True)
class Model:
    """Symbolic model of a vehicle.

    Fields
    ------
    name: identifier used for the generated folder and C symbol prefix.
    states, inputs, parameters, noises, outputs: descriptions, in vector order.
    x, u, p, w: the CasADi SX column symbols of those vectors (w may have 0 rows).
    xdot: continuous dynamics f(x, u, p, w), shape (n_x, 1).
    y: measurement h(x, p), shape (n_y, 1).
    discretisation: "rk4" or "euler"; substeps: steps of dt/substeps inside one call.
    angle_outputs: indices of outputs that are angles (innovations wrap to (-pi, pi]).
    notes: departures from the source paper, printed in the manifest.
    """

    name: str
    states: tuple[Quantity, ...]
    inputs: tuple[Quantity, ...]
    parameters: tuple[Parameter, ...]
    noises: tuple[Quantity, ...]
    outputs: tuple[Quantity, ...]
    x: ca.SX
    u: ca.SX
    p: ca.SX
    w: ca.SX
    xdot: ca.SX
    y: ca.SX
    discretisation: str = "rk4"
    substeps: int = 1
    angle_outputs: tuple[int, ...] = ()
    notes: tuple[str, ...] = field(default_factory=tuple)

    def __post_init__(self):
        sizes = {
            "x/states": (self.x, self.states),
            "u/inputs": (self.u, self.inputs),
            "p/parameters": (self.p, self.parameters),
            "w/noises": (self.w, self.noises),
            "y/outputs": (self.y, self.outputs),
        }
        for label, (sym, described) in sizes.items():
            if sym.shape != (len(described), 1) and not (len(described) == 0 and sym.numel() == 0):
                raise ValueError(
                    f"model {self.name!r}: {label} has shape {sym.shape}, expected ({len(described)}, 1)"
                )
        if self.xdot.shape != self.x.shape:
            raise ValueError(f"model {self.name!r}: xdot has shape {self.xdot.shape}, expected {self.x.shape}")
        if self.discretisation not in ("rk4", "euler"):
            raise ValueError(f"model {self.name!r}: discretisation must be 'rk4' or 'euler'")
        if self.substeps < 1:
            raise ValueError(f"model {self.name!r}: substeps must be >= 1")
        free_h = set(ca.symvar(self.y)) - set(ca.symvar(ca.vertcat(self.x, self.p)))
        if free_h:
            raise ValueError(f"model {self.name!r}: h may depend on x and p only, found {free_h}")

    @property
    def n_x(self) -> int:
        return len(self.states)

    @property
    def n_u(self) -> int:
        return len(self.inputs)

    @property
    def n_p(self) -> int:
        return len(self.parameters)

    @property
    def n_w(self) -> int:
        return len(self.noises)

    @property
    def n_y(self) -> int:
        return len(self.outputs)

    @property
    def parameter_defaults(self) -> list[float]:
        return [prm.default for prm in self.parameters]

    def equations_hash(self) -> str:
        """sha256 of the printed equations and discretisation: changes whenever the maths does."""
        text = "\n".join(
            [
                self.name,
                self.discretisation,
                str(self.substeps),
                str(self.angle_outputs),
                " ".join(q.name for q in self.states + self.inputs + self.noises + self.outputs),
                " ".join(f"{q.name}={q.default!r}" for q in self.parameters),
                str(self.xdot),
                str(self.y),
            ]
        )
        return hashlib.sha256(text.encode()).hexdigest()


def symbols(prefix: str, quantities) -> ca.SX:
    """Column SX vector with one named symbol per quantity (``prefix`` keeps names unique)."""
    if len(quantities) == 0:
        return ca.SX(0, 1)
    return ca.vertcat(*[ca.SX.sym(f"{prefix}_{q.name}") for q in quantities])
