"""Cooperative-navigation AUV of seed paper 002 (eqs. 2-3), as continuous dynamics.

State [x, y]: east and north position of the follower AUV. Input u = [c, s, theta]: forward
and starboard speed from the DVL and heading from the compass. Measurement: acoustic range
to a leader vehicle (CNA) whose position [x_r, y_r] is the runtime parameter p, so one
compiled model serves any number of leaders.

    x_dot = c cos(theta) + s sin(theta) + w_x        (eq. 2, divided by dt)
    y_dot = c sin(theta) - s cos(theta) + w_y
    z     = sqrt((x - x_r)^2 + (y - y_r)^2)          (eq. 3)

With u held over a step, explicit Euler is exact and reproduces eq. 2 to the letter.
Heading theta is measured as printed in eq. 2 (counter-clockwise from east, starboard to
the right of the forward axis); we keep the paper's convention rather than the NED one.
"""
from __future__ import annotations

import math

import casadi as ca

from ..model import Envelope, Model, Parameter, Quantity, symbols

STATES = (Quantity("x", "m", "east position"), Quantity("y", "m", "north position"))
INPUTS = (
    Quantity("c", "m/s", "forward speed (DVL)"),
    Quantity("s", "m/s", "starboard speed (DVL)"),
    Quantity("theta", "rad", "heading (compass), counter-clockwise from east"),
)
PARAMETERS = (
    Parameter("x_r", "m", 0.0, "leader (CNA) east position"),
    Parameter("y_r", "m", 0.0, "leader (CNA) north position"),
)
NOISES = (Quantity("w_x", "m/s", "east velocity noise"), Quantity("w_y", "m/s", "north velocity noise"))
OUTPUTS = (Quantity("range", "m", "acoustic range to the leader"),)


def cn2d() -> Model:
    x, u, p, w = symbols("x", STATES), symbols("u", INPUTS), symbols("p", PARAMETERS), symbols("w", NOISES)
    c, s, theta = u[0], u[1], u[2]
    xdot = ca.vertcat(c * ca.cos(theta) + s * ca.sin(theta), c * ca.sin(theta) - s * ca.cos(theta)) + w
    rng = ca.sqrt((x[0] - p[0]) ** 2 + (x[1] - p[1]) ** 2)
    return Model(
        name="cn2d",
        states=STATES,
        inputs=INPUTS,
        parameters=PARAMETERS,
        noises=NOISES,
        outputs=OUTPUTS,
        x=x,
        u=u,
        p=p,
        w=w,
        xdot=xdot,
        y=rng,
        discretisation="euler",
        substeps=1,
        # reference_models.cn2d_state/input (a 4 km square, DVL 0.5-2 m/s); the flow is exact for any dt, pings every 5 s
        envelope=Envelope(states={"x": (-2000.0, 2000.0), "y": (-2000.0, 2000.0)},
                          inputs={"c": (0.5, 2.0), "s": (-0.6, 0.6), "theta": (-math.pi, math.pi)}, max_dt=10.0),
        notes=("heading convention of eq. 2 kept (counter-clockwise from east)",),
    )
