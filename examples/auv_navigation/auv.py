"""An AUV's navigation model: the REMUS 100 dynamics of abyssal's built-in model with the sensors a real AUV carries.

The vehicle is abyssal's ``remus100`` (symbolic/models/remus100.py, REMUS100-SPEC: Prestero's 6-DOF equations,
RK4 with 2 substeps), reused as it is: its states, inputs, parameters, process-noise inputs and xdot. What this file
adds is how the vehicle is measured. With x = [u v w p q r x y z phi theta psi] (body FRD velocities and rates about
the centre of buoyancy, NED position, ZYX Euler angles), nu_1 = [u v w], omega = [p q r]:

    dvl    v_dvl = nu_1 + omega x r_dvl        5 Hz, sigma 1 cm/s; r_dvl the lever arm from the CB (its parameters)
    depth  z                                    10 Hz, sigma 5 cm (a pressure gauge at the CB)
    ahrs   [phi, theta, psi]                    20 Hz, sigma 0.2, 0.2, 0.5 deg (all three angle outputs)
    usbl   [x, y, z]                            one fix every 4 s, 0.3-1.0 s late (stamped at the ping); each fix
                                                carries its own quality figure (update(..., R=)); declared 1 m
    gnss   [x, y]                               1 Hz, sigma 1.5 m, only while the vehicle is at the surface

The DVL is aligned with the body axes; a bottom-lock loss is a gap in its measurements (the filter is simply not
given any). The USBL's transceiver is on a ship; its fix is the vehicle's NED position with a noise that grows with
the slant range (simulate.py). Frames: NED and body FRD as Fossen's. ``truth_step`` is generated with the model for
the simulator only (the same RK4 with the force noise w held over the step); no filter calls it.

    abyssal regenerate --model auv.py:auv_navigation --out gen       # or run.py, which generates it
"""
from __future__ import annotations

import dataclasses
import math

import casadi as ca

from abyssal.symbolic import Envelope, Model, Parameter, Quantity, Sensor, discretise, symbols
from abyssal.symbolic.models.remus100 import ENVELOPE_INPUTS, ENVELOPE_STATES, remus100

NAME = "auv_navigation"

#: the DVL's mounting point from the centre of buoyancy, body FRD (m): forward of the CB and below it
DVL_LEVER = (Parameter("lever_x", "m", 0.40, "DVL lever arm, forward"),
             Parameter("lever_y", "m", 0.0, "DVL lever arm, starboard"),
             Parameter("lever_z", "m", 0.08, "DVL lever arm, down"))
#: the sensors' declared noise: standard deviations in their outputs' units
DVL_SIGMA = (0.01, 0.01, 0.01)                        # m/s
DEPTH_SIGMA = (0.05,)                                  # m
AHRS_SIGMA = tuple(math.radians(d) for d in (0.2, 0.2, 0.5))  # rad
USBL_SIGMA = (1.0, 1.0, 1.0)                           # m (a fix brings its own, see simulate.usbl_sigma)
GNSS_SIGMA = (1.5, 1.5)                                # m
#: the mission's extent (the 60 m helix, 10 m deep, from the surface): remus100's envelope with x, y, z widened
ENVELOPE = Envelope(states={**ENVELOPE_STATES, "x": (-70.0, 70.0), "y": (-70.0, 70.0), "z": (-1.0, 12.0)},
                    inputs={name: ENVELOPE_INPUTS[name] for name in ("n_rpm", "tau_M", "tau_N")})


def auv_sensors(x: ca.SX) -> tuple[Sensor, ...]:
    """The five sensors of the AUV, each h_k(x, p_k) of the state x of remus100."""
    nu_1, omega = x[0:3], x[3:6]
    position, attitude = x[6:9], x[9:12]
    lever = symbols("dvl", DVL_LEVER)
    return (
        Sensor(name="dvl", outputs=(Quantity("u", "m/s", "DVL bottom-track surge"),
                                    Quantity("v", "m/s", "DVL bottom-track sway"),
                                    Quantity("w", "m/s", "DVL bottom-track heave")),
               y=nu_1 + ca.cross(omega, lever), parameters=DVL_LEVER, q=lever, noise=DVL_SIGMA, rate=5.0,
               description="Doppler velocity log: the body-frame velocity of its mounting point over the sea floor"),
        Sensor(name="depth", outputs=(Quantity("z", "m", "depth"),), y=position[2:3], noise=DEPTH_SIGMA, rate=10.0,
               description="pressure gauge"),
        Sensor(name="ahrs", outputs=(Quantity("phi", "rad", "roll"), Quantity("theta", "rad", "pitch"),
                                     Quantity("psi", "rad", "heading")),
               y=attitude, noise=AHRS_SIGMA, angle_outputs=(0, 1, 2), rate=20.0,
               description="attitude and heading reference system"),
        Sensor(name="usbl", outputs=(Quantity("x", "m", "north"), Quantity("y", "m", "east"),
                                     Quantity("z", "m", "depth")),
               y=position, noise=USBL_SIGMA, rate=0.25, latency=(0.3, 1.0),
               description="ultra-short baseline fix from the ship, stamped at the ping, arriving 0.3-1.0 s later"),
        Sensor(name="gnss", outputs=(Quantity("x", "m", "north"), Quantity("y", "m", "east")),
               y=position[0:2], noise=GNSS_SIGMA, rate=1.0, description="GNSS fix, only at the surface"),
    )


def truth_step(model: Model) -> ca.Function:
    """The simulator's step, generated with the model but never called by a filter: the model's own RK4 (with its
    substeps) with the force noise w held over dt, x_next = truth_step(x, u, p, w, dt)."""
    dt = ca.SX.sym("dt")
    x_next = discretise.discrete_step(model, model.x, model.u, model.p, model.w, dt)
    return ca.Function(f"{model.name}_truth_step", [model.x, model.u, model.p, model.w, dt], [x_next],
                       ["x", "u", "p", "w", "dt"], ["x_next"])


def auv_navigation() -> Model:
    """The REMUS 100 of remus100() measured by auv_sensors(), and the simulator's truth_step."""
    vehicle = remus100(name=NAME)
    model = dataclasses.replace(
        vehicle, y=None, outputs=(), angle_outputs=(), sensors=auv_sensors(vehicle.x), envelope=ENVELOPE,
        notes=vehicle.notes + ("examples/auv_navigation: remus100's dynamics with a DVL (lever arm), depth, AHRS, "
                               "USBL and GNSS as separate sensors; truth_step is the simulator's",))
    return dataclasses.replace(model, functions=(truth_step(model),))
