"""Cooperative-navigation AUV of seed paper 002 (eqs. 2-3), as continuous dynamics.

State [x, y]: east and north position of the follower AUV. Input u = [c, s, theta]: forward
and starboard speed from the DVL and heading from the compass. Measurements: one acoustic-range sensor per leader vehicle
(CNA), ``leader0`` and ``leader1`` (the paper's two leaders), each with its own parameters, the
leader's broadcast position [x_r, y_r] (``update("leader0", z, t, p=[x_r, y_r])``), and its own
noise; a ping from one leader is that sensor's update alone.

    x_dot = c cos(theta) + s sin(theta) + w_x        (eq. 2, divided by dt)
    y_dot = c sin(theta) - s cos(theta) + w_y
    z_k   = sqrt((x - x_r,k)^2 + (y - y_r,k)^2)      (eq. 3, leader k = 0, 1)

With u held over a step, explicit Euler is exact and reproduces eq. 2 to the letter.
Heading theta is measured as printed in eq. 2 (counter-clockwise from east, starboard to
the right of the forward axis); we keep the paper's convention rather than the NED one.
"""
from __future__ import annotations

import math

import casadi as ca

from ..model import Envelope, Model, Parameter, Quantity, Sensor, symbols

STATES = (Quantity("x", "m", "east position"), Quantity("y", "m", "north position"))
INPUTS = (
    Quantity("c", "m/s", "forward speed (DVL)"),
    Quantity("s", "m/s", "starboard speed (DVL)"),
    Quantity("theta", "rad", "heading (compass), counter-clockwise from east"),
)
#: each leader sensor's own parameters: the position the leader broadcasts with its ping
LEADER_PARAMETERS = (
    Parameter("x_r", "m", 0.0, "leader (CNA) east position"),
    Parameter("y_r", "m", 0.0, "leader (CNA) north position"),
)
LEADERS = ("leader0", "leader1")
#: the range noise the sensors declare (sigma, m; the scenario's R_true = 1 m^2 -- the paper gives no value); a
#: filter is given its own R
RANGE_SIGMA = 1.0
NOISES = (Quantity("w_x", "m/s", "east velocity noise"), Quantity("w_y", "m/s", "north velocity noise"))


def _leader(name: str, x) -> Sensor:
    q = symbols(name, LEADER_PARAMETERS)
    return Sensor(name=name, outputs=(Quantity("range", "m", f"acoustic range to {name}"),),
                  y=ca.sqrt((x[0] - q[0]) ** 2 + (x[1] - q[1]) ** 2), parameters=LEADER_PARAMETERS, q=q,
                  noise=(RANGE_SIGMA,), description=f"acoustic range to {name} (a surface CNA broadcasting its GPS "
                                                     "position with the ping)")


def cn2d() -> Model:
    x, u, w = symbols("x", STATES), symbols("u", INPUTS), symbols("w", NOISES)
    c, s, theta = u[0], u[1], u[2]
    xdot = ca.vertcat(c * ca.cos(theta) + s * ca.sin(theta), c * ca.sin(theta) - s * ca.cos(theta)) + w
    return Model(
        name="cn2d",
        states=STATES,
        inputs=INPUTS,
        noises=NOISES,
        sensors=tuple(_leader(name, x) for name in LEADERS),
        x=x,
        u=u,
        w=w,
        xdot=xdot,
        discretisation="euler",
        substeps=1,
        # reference_models.cn2d_state/input (a 4 km square, DVL 0.5-2 m/s); the flow is exact for any dt, pings every 5 s
        envelope=Envelope(states={"x": (-2000.0, 2000.0), "y": (-2000.0, 2000.0)},
                          inputs={"c": (0.5, 2.0), "s": (-0.6, 0.6), "theta": (-math.pi, math.pi)}, max_dt=10.0),
        notes=("heading convention of eq. 2 kept (counter-clockwise from east)",),
    )
