"""Constant-velocity target in the plane: a linear-Gaussian model, the exact Kalman filter's home.

State [p_x, p_y, v_x, v_y]; input [a_x, a_y] (commanded acceleration); position measured
relative to a sensor at the runtime parameter [s_x, s_y]:

    p_dot = v,   v_dot = a + w        (w: white acceleration noise)
    y     = p - s

Dynamics and measurement are linear, and RK4 with the input held over dt is exact for this
polynomial flow, so x_{k+1} = A x_k + B u_k with A = [[I, dt I], [0, I]], B = [dt^2/2 I; dt I].
Used by `abyssal verify` and the tests: EKF, UKF and CKF must all equal the Kalman filter here.
"""
from __future__ import annotations

import casadi as ca

from ..model import Envelope, Model, Parameter, Quantity, symbols

STATES = (
    Quantity("p_x", "m", "east position"),
    Quantity("p_y", "m", "north position"),
    Quantity("v_x", "m/s", "east velocity"),
    Quantity("v_y", "m/s", "north velocity"),
)
INPUTS = (Quantity("a_x", "m/s^2", "commanded acceleration, east"), Quantity("a_y", "m/s^2", "commanded acceleration, north"))
PARAMETERS = (Parameter("s_x", "m", 0.0, "sensor east position"), Parameter("s_y", "m", 0.0, "sensor north position"))
NOISES = (Quantity("w_x", "m/s^2", "acceleration noise, east"), Quantity("w_y", "m/s^2", "acceleration noise, north"))
OUTPUTS = (Quantity("d_x", "m", "east position relative to the sensor"), Quantity("d_y", "m", "north position relative to the sensor"))


def linear_cv() -> Model:
    x, u, p, w = symbols("x", STATES), symbols("u", INPUTS), symbols("p", PARAMETERS), symbols("w", NOISES)
    return Model(
        name="linear_cv",
        states=STATES,
        inputs=INPUTS,
        parameters=PARAMETERS,
        noises=NOISES,
        outputs=OUTPUTS,
        x=x,
        u=u,
        p=p,
        w=w,
        xdot=ca.vertcat(x[2:4], u + w),
        y=x[0:2] - p,
        discretisation="rk4",
        substeps=1,
        # +-3 sigma of reference_models.linear_cv_state/input; RK4 is exact for this flow at any dt
        envelope=Envelope(states={"p_x": (-300.0, 300.0), "p_y": (-300.0, 300.0), "v_x": (-6.0, 6.0), "v_y": (-6.0, 6.0)},
                          inputs={"a_x": (-1.5, 1.5), "a_y": (-1.5, 1.5)}),
        notes=("linear-Gaussian reference model (not from a seed paper)",),
    )
