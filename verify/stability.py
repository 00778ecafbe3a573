"""What `abyssal verify` finds about a model rather than its code: the longest step its discretisation is stable at.

A continuous model's f is ``substeps`` steps h = dt / substeps of an explicit Runge-Kutta scheme applied to its
xdot. Near a state x the flow is linear, A = d xdot / dx (central differences of the compiled xdot); over one
substep the scheme multiplies the mode of an eigenvalue lambda of A by R(h lambda), R the scheme's stability
polynomial (Euler 1 + z; RK4 1 + z + z^2/2 + z^3/6 + z^4/24), where the exact flow multiplies it by
exp(h lambda). A step dt is stable at x when the scheme amplifies no mode more than the flow does, or more than 1,
whichever is larger (give or take GROWTH_SLACK): |R(h lambda)| <= max(1, |exp(h lambda)|) + GROWTH_SLACK. So a
stiff damped mode (a 0.1 s propeller lag, lambda = -10 1/s: RK4 is stable up to h = 0.279 s) limits the step,
an integrator (lambda = 0) or a slow unstable mode (the exact flow grows too) does not.

``largest_stable_dt`` scans dt on a geometric grid up to a cap at the rest state (x = 0 and u = 0, each clipped
into the box) and at sampled states and inputs of the box, and returns the largest dt below which every grid step
is stable at every point, with the mode that limits it. ``abyssal verify`` samples dt below it when a model
declares no max_dt, and reports it as a NOTE (a fact about the model, never a failure of its code) when a
declared max_dt exceeds it. A discrete model (x_next given) has no xdot: nothing is derived for it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: the amplification beyond max(1, |exp(h lambda)|) a stable substep may have (an Euler step of an undamped
#: 1 rad/s oscillation grows by 1 % per substep at h = 0.14 s)
GROWTH_SLACK = 1e-2
#: states (besides the rest state) at which the Jacobian is taken
POINTS = 32
#: the grid of steps: GRID steps from cap / 10^4 to cap, geometrically
GRID = 400
SEED = 20240612


def stability_polynomial(scheme: str):
    """R(z) of an explicit scheme: one step of y' = lambda y multiplies y by R(h lambda)."""
    order = {"euler": 1, "rk4": 4}[scheme]
    return lambda z: sum(z**k / math.factorial(k) for k in range(order + 1))


@dataclass(frozen=True)
class StableStep:
    """The longest stable step found: dt over the whole box, dt_at_rest at the rest state alone, and the mode
    that limits dt (its eigenvalue and the state x, input u where it was found; None when nothing limits it
    below the cap)."""

    scheme: str
    substeps: int
    dt: float
    dt_at_rest: float
    cap: float
    eigenvalue: complex | None
    x: np.ndarray | None
    u: np.ndarray | None

    @property
    def limited(self) -> bool:
        """Whether a mode limits the step below the cap (else the scheme is stable up to the cap everywhere)."""
        return self.eigenvalue is not None

    def describe(self) -> str:
        """One sentence: e.g. "rk4 (2 substeps) is stable up to dt = 0.13 s across the box (its stiffest mode,
        lambda = -21.3 1/s, at x=[...], u=[...]) and up to 0.5 s at rest"."""
        from .models import point_text

        scheme = f"{self.scheme} ({self.substeps} substep{'s' if self.substeps != 1 else ''})"
        if not self.limited:
            return f"{scheme} is stable up to the largest step tried, dt = {self.cap:g} s, at rest and across the box"
        lam = self.eigenvalue
        mode = f"{lam.real:.3g} 1/s" if abs(lam.imag) < 1e-9 * max(1.0, abs(lam)) else f"{lam.real:.3g} {lam.imag:+.3g}j 1/s"
        rest = (f"up to {self.dt_at_rest:.3g} s at rest" if self.dt_at_rest < self.cap
                else f"up to the largest step tried ({self.cap:g} s) at rest")
        return (f"{scheme} is stable up to dt = {self.dt:.3g} s across the box (its stiffest mode, lambda = {mode}, at "
                f"{point_text(x=self.x, u=self.u)}) and {rest}")


def _jacobian(bundle, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
    """d xdot / dx at (x, u, p, w = 0), by central differences of the compiled xdot."""
    w = np.zeros(bundle.n_w)
    columns = []
    for i in range(x.size):
        h = 1e-6 * max(1.0, abs(x[i]))
        up, down = x.copy(), x.copy()
        up[i] += h
        down[i] -= h
        columns.append((bundle.xdot(up, u, p, w) - bundle.xdot(down, u, p, w)) / (up[i] - down[i]))
    return np.stack(columns, axis=-1)


def _largest_stable(eigenvalues: np.ndarray, grid: np.ndarray, polynomial, substeps: int) -> tuple[float, int]:
    """(the largest grid dt below which every grid dt is stable for every eigenvalue, the index of the eigenvalue
    that is first unstable, or -1)."""
    z = (grid[:, None] / substeps) * eigenvalues[None, :]
    with np.errstate(over="ignore", invalid="ignore"):
        allowed = np.maximum(1.0, np.abs(np.exp(z))) + GROWTH_SLACK
        unstable = ~(np.abs(polynomial(z)) <= allowed)
    rows = np.flatnonzero(unstable.any(axis=1))
    if rows.size == 0:
        return float(grid[-1]), -1
    first = int(rows[0])
    return (float(grid[first - 1]) if first > 0 else 0.0), int(np.argmax(unstable[first]))


def largest_stable_dt(bundle, x_low, x_high, u_low, u_high, cap: float, points: int = POINTS,
                      seed: int = SEED) -> StableStep | None:
    """The longest stable step of the bundle's discretisation at rest and across the box (module docstring);
    None for a discrete model."""
    scheme = bundle.manifest.get("discretisation")
    if bundle.is_discrete or scheme not in ("euler", "rk4"):
        return None
    substeps = int(bundle.manifest.get("substeps") or 1)
    polynomial = stability_polynomial(scheme)
    grid = cap * np.logspace(-4, 0, GRID)
    p = bundle.params()
    rng = np.random.default_rng(seed)
    rest = (np.clip(np.zeros(bundle.n_x), x_low, x_high), np.clip(np.zeros(bundle.n_u), u_low, u_high))
    candidates = [rest] + [(rng.uniform(x_low, x_high), rng.uniform(u_low, u_high)) for _ in range(points)]
    best, limit, dt_at_rest = cap, None, cap
    for k, (x, u) in enumerate(candidates):
        A = _jacobian(bundle, x, u, p)
        if not np.all(np.isfinite(A)):
            continue  # xdot is not finite around this state: nothing to say about a step there
        eigenvalues = np.linalg.eigvals(A)
        dt, which = _largest_stable(eigenvalues, grid, polynomial, substeps)
        if k == 0:
            dt_at_rest = dt
        if which >= 0 and (limit is None or dt < best):
            best, limit = dt, (complex(eigenvalues[which]), x, u)
    if limit is None:
        return StableStep(scheme, substeps, cap, dt_at_rest, cap, None, None, None)
    lam, x, u = limit
    return StableStep(scheme, substeps, best, dt_at_rest, cap, lam, x, u)
