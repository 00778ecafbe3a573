"""Terrain-aided navigation AUV of seed paper 003: the 3-DOF velocity motion model (eqs. 1-3).

State [x, y, theta]: east and north position (m) and heading (rad, counter-clockwise from +x,
as in the paper's Fig. 1). Input u = [v, omega]: forward speed and turn rate. The step is given
directly (a discrete model): eq. 1, the exact arc of constant v and omega over dt,

    x_{k+1}     = x_k + v dt cos(theta + omega dt / 2) sinc(omega dt / 2) + d_x dt + e_x
    y_{k+1}     = y_k + v dt sin(theta + omega dt / 2) sinc(omega dt / 2) + d_y dt + e_y
    theta_{k+1} = theta_k + omega dt

with v and omega the noisy body velocities of eq. 2 (v + n_v, omega + n_omega).

* Eq. 1 as printed writes (v/w)(-sin theta + sin(theta + w dt)) and (v/w)(cos theta - sin(theta +
  w dt)); the arc gives -cos(theta + w dt) in the y row (a misprint), and both rows are 0/0 at
  w = 0. The chord form above is the same arc (2 sin(a) cos(b) identities) and is exact and
  smooth through omega = 0.
* sinc(a) = sin(a)/a is written branch-free, as a blend with a 0/1 flag: small (|a| < 1e-2) picks
  the Taylor series to a^6 (truncation error below a^8/9! < 3e-22; sin(a)/a's derivative would lose
  digits to cancellation there), else sin(a)/a. Both sides are finite (the series sees a * small,
  the division a + small, never 0) and one of them is multiplied by 0, so the blend is exactly one
  side. A select (``if_else``) instead made gcc sink the sin call into a branch and give up
  vectorising the particle loop.
* Noise inputs (the filter samples them; eqs. 2-3): n_v ~ N(0, a1 v^2 + a2 omega^2) and
  n_omega ~ N(0, a3 v^2 + a4 omega^2) (body noise, m/s and rad/s, held over the step) and
  e_x, e_y ~ N(0, sigma^2) (environment noise, m per step: the sigma the fuzzy logic sets).
* The ocean current (d_x, d_y) is a runtime parameter (m/s): the truth runs with the paper's
  currents, the filter with zero (the current is unknown to it).
* Output: the heading (compass). The altimeter's seabed depth is read from a bathymetry map
  (data, not equations: ``abyssal.runtime.terrain``), so it is not part of the model.

The bundle also carries the fuzzy process-noise logic of section 3.2 as the generated function
``fuzzy_sigma(gradient, gradient_rate) -> sigma`` (``abyssal.symbolic.fuzzy``), one of the Model's
``functions`` (generated into ``tan3dof_functions.c``).
"""
from __future__ import annotations

import math

import casadi as ca

from ..fuzzy import fuzzy_sigma_function
from ..model import Envelope, Model, Parameter, Quantity, symbols

#: Table 2 and section 4.1: body-noise coefficients (a1, a2, a3, a4) of eq. 2.
BODY_NOISE_COEFFICIENTS = (0.1, 0.1, 0.001, 0.1)

STATES = (
    Quantity("x", "m", "east position"),
    Quantity("y", "m", "north position"),
    Quantity("theta", "rad", "heading, counter-clockwise from +x"),
)
INPUTS = (Quantity("v", "m/s", "forward speed"), Quantity("omega", "rad/s", "turn rate"))
PARAMETERS = (
    Parameter("d_x", "m/s", 0.0, "ocean current along +x (unknown to the filter: 0)"),
    Parameter("d_y", "m/s", 0.0, "ocean current along +y (unknown to the filter: 0)"),
)
NOISES = (
    Quantity("n_v", "m/s", "body noise on the forward speed (eq. 2)"),
    Quantity("n_omega", "rad/s", "body noise on the turn rate (eq. 2)"),
    Quantity("e_x", "m", "environment noise in x over one step (eq. 3)"),
    Quantity("e_y", "m", "environment noise in y over one step (eq. 3)"),
)
OUTPUTS = (Quantity("heading", "rad", "compass heading"),)

SINC_SERIES_BELOW = 1e-2


def sinc(a: ca.SX) -> ca.SX:
    """sin(a)/a, exact and smooth through a = 0, without a branch (module docstring)."""
    small = ca.fabs(a) < SINC_SERIES_BELOW  # 0 or 1
    a2 = (a * small) ** 2
    series = 1 - a2 / 6 * (1 - a2 / 20 * (1 - a2 / 42))
    safe = a + small
    return small * series + (1 - small) * (ca.sin(safe) / safe)


def tan3dof() -> Model:
    x, u, p, w = symbols("x", STATES), symbols("u", INPUTS), symbols("p", PARAMETERS), symbols("w", NOISES)
    dt = ca.SX.sym("dt")
    v = u[0] + w[0]       # eq. 2
    omega = u[1] + w[1]
    half_turn = omega * dt / 2
    chord = v * dt * sinc(half_turn)  # length of the chord of the arc (eq. 1)
    heading_mid = x[2] + half_turn
    x_next = ca.vertcat(
        x[0] + chord * ca.cos(heading_mid) + p[0] * dt + w[2],  # eq. 1 + current + eq. 3
        x[1] + chord * ca.sin(heading_mid) + p[1] * dt + w[3],
        x[2] + omega * dt,
    )
    return Model(
        name="tan3dof",
        states=STATES,
        inputs=INPUTS,
        parameters=PARAMETERS,
        noises=NOISES,
        outputs=OUTPUTS,
        x=x,
        u=u,
        p=p,
        w=w,
        xdot=None,
        y=x[2],
        x_next=x_next,
        dt=dt,
        angle_states=(2,),
        angle_outputs=(0,),
        # section 4: tracks from the [20, 20] and [60, 10] km start postures at 0.5 m/s, an autopilot's turn rates, 1 Hz steps
        envelope=Envelope(states={"x": (0.0, 100_000.0), "y": (0.0, 100_000.0), "theta": (-math.pi, math.pi)},
                          inputs={"v": (0.0, 2.0), "omega": (-0.3, 0.3)}, max_dt=2.0),
        functions=(fuzzy_sigma_function("tan3dof_fuzzy_sigma"),),  # section 3.2
        notes=(
            "eq. 1's y row printed with sin(theta + w dt); the arc has -cos(theta + w dt): written as the exact "
            "chord form v dt cos/sin(theta + w dt/2) sinc(w dt/2), smooth through w = 0",
            "current (d_x, d_y) is a runtime parameter; body noise (eq. 2) and environment noise (eq. 3) are noise inputs",
        ),
    )
