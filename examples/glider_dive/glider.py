"""A Slocum glider underwater, by dead reckoning: depth measured, attitude given, the current unknown.

What it is for: the position of a buoyancy-driven glider between its last GPS fix before a dive and its first fix
after surfacing, with an honest uncertainty. Underwater a Slocum knows its depth (pressure sensor), its attitude
(compass and inclinometer) and nothing about its position; it flies along a glide path at an unknown through-water
speed, carried by an unknown current. The depth rate and the pitch give the speed along the path; heading and speed
give the horizontal motion through the water; the current adds to it.

State x = [north east depth speed current_n current_e] (NED position about a local origin, m; the speed through the
water along the glide path, m/s; the depth-averaged current, m/s). Input u = [pitch heading] (the glider's own
inclinometer and compass, rad, held between their samples). Sensors: ``depth`` (the pressure sensor's depth) and
``gps`` (north and east of a fix at the surface, converted from latitude/longitude about the origin by pymap3d).

    glide-path angle   gamma = pitch - aoa * tanh(pitch / 0.05)                       (path steeper than the pitch)
    north_dot          = speed cos(gamma) cos(heading + w_heading) + current_n
    east_dot           = speed cos(gamma) sin(heading + w_heading) + current_e
    depth_dot          = -speed sin(gamma)                                          (pitch < 0: nose down, diving)
    speed_dot          = w_speed                                                    (random walk)
    current_dot        = [w_current_n, w_current_e]                                 (random walk)

Assumptions, each a choice a reader may want to change:
* Steady flight along the glide path. ``aoa`` is the angle of attack (the path is steeper than the pitch by it, on
  dives and climbs: lift must push the glider forward); the default 0 is what this glider's own flight software
  assumed (its logged m_speed equals |depth rate| / tan |pitch| to within 2e-6 degrees in the 2008 dive); Slocum
  literature values are 2-4 degrees. tanh(pitch / 0.05) is a smooth sign (the AoA changes side at an inflection).
* The heading is the compass heading corrected for the magnetic variation by the caller; its errors are white noise
  (w_heading); a compass bias is not modelled (a 2-degree bias over a 1 km dive is ~35 m).
* The current is one depth-averaged horizontal current, constant up to a slow random walk; the water's vertical
  motion, the surface drift (wind, waves) and the glider's sideslip are not modelled.
* No DVL, no acoustic fixes: underwater only the depth corrects the state (through the speed); the position and the
  current are corrected by GPS fixes at the surface.
"""
import casadi as ca

from abyssal import Envelope, Model, Parameter, Quantity, Sensor, symbols

STATES = (
    Quantity("north", "m", "north of the local origin"),
    Quantity("east", "m", "east of the local origin"),
    Quantity("depth", "m", "depth below the surface (down)"),
    Quantity("speed", "m/s", "speed through the water along the glide path"),
    Quantity("current_n", "m/s", "depth-averaged current, north"),
    Quantity("current_e", "m/s", "depth-averaged current, east"),
)
INPUTS = (
    Quantity("pitch", "rad", "pitch (nose up positive, Fossen's theta)"),
    Quantity("heading", "rad", "true heading (clockwise from north)"),
)
PARAMETERS = (Parameter("aoa", "rad", 0.0, "angle of attack: the glide path is steeper than the pitch by it"),)
NOISES = (
    Quantity("w_speed", "m/s^2", "change of the through-water speed"),
    Quantity("w_current_n", "m/s^2", "change of the current, north"),
    Quantity("w_current_e", "m/s^2", "change of the current, east"),
    Quantity("w_heading", "rad", "compass noise"),
)
SMOOTH_SIGN_WIDTH = 0.05  # rad: tanh(pitch / 0.05) is +-1 beyond ~6 degrees of pitch


def slocum_glider() -> Model:
    x, u, p, w = symbols("x", STATES), symbols("u", INPUTS), symbols("p", PARAMETERS), symbols("w", NOISES)
    north, east, depth, speed, current_n, current_e = (x[i] for i in range(6))
    pitch, heading = u[0], u[1]
    aoa = p[0]
    w_speed, w_current_n, w_current_e, w_heading = (w[i] for i in range(4))

    gamma = pitch - aoa * ca.tanh(pitch / SMOOTH_SIGN_WIDTH)
    horizontal = speed * ca.cos(gamma)
    xdot = ca.vertcat(
        horizontal * ca.cos(heading + w_heading) + current_n,
        horizontal * ca.sin(heading + w_heading) + current_e,
        -speed * ca.sin(gamma),
        w_speed,
        w_current_n,
        w_current_e,
    )
    sensors = (
        Sensor(name="depth", outputs=(Quantity("depth", "m", "pressure sensor depth"),), y=depth, noise=(0.5,),
               rate=0.25, description="the glider's pressure sensor, converted to depth by its own software"),
        Sensor(name="gps", outputs=(Quantity("north", "m"), Quantity("east", "m")), y=ca.vertcat(north, east),
               noise=(5.0, 5.0), description="a GPS fix at the surface, north and east of the local origin"),
    )
    return Model(
        name="slocum_glider",
        states=STATES, inputs=INPUTS, parameters=PARAMETERS, noises=NOISES,
        x=x, u=u, p=p, w=w,
        xdot=xdot,
        sensors=sensors,
        discretisation="rk4",
        envelope=Envelope(states={"north": (-3000.0, 3000.0), "east": (-3000.0, 3000.0), "depth": (0.0, 1000.0),
                                  "speed": (0.0, 1.0), "current_n": (-0.5, 0.5), "current_e": (-0.5, 0.5)},
                          inputs={"pitch": (-0.7, 0.7), "heading": (-3.2, 6.4)}, max_dt=10.0),
        notes=("steady glide-path kinematics (dead reckoning), not the glider's dynamics",),
    )
