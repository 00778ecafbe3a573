"""A small AUV for the replay example: kinematics in NED, body velocities as random walks, five sensors.

State x = [north east down psi u v w] (NED position, m; heading, rad; body FRD velocity, m/s). Input u = [r], the
yaw rate from the IMU's gyro (rad/s), held between its samples. Noise inputs: the gyro's noise and the body
accelerations (white; the velocities are random walks).

    north_dot = u cos(psi) - v sin(psi)          east_dot = u sin(psi) + v cos(psi)          down_dot = w
    psi_dot   = r + w_r                          [u v w]_dot = [w_u w_v w_w]

Sensors (each with its rate; the USBL's fixes arrive 0.3-0.8 s after their stamp):

    depth     the pressure sensor's depth = down                         5 Hz, 0.05 m
    heading   the IMU's yaw = psi (an angle)                             10 Hz, 0.02 rad
    dvl       the body velocity [u v w] (no lever arm, bottom lock)      2 Hz, 0.02 m/s
    gps       north, east of a fix, at the surface only                  1 Hz, 2 m
    usbl      north, east, down of an acoustic fix                       every 4 s, 1 m (each fix its own covariance)
"""
import casadi as ca

from abyssal import Model, Quantity, Sensor, symbols

STATES = (
    Quantity("north", "m"), Quantity("east", "m"), Quantity("down", "m"), Quantity("psi", "rad", "heading"),
    Quantity("u", "m/s", "surge"), Quantity("v", "m/s", "sway"), Quantity("w", "m/s", "heave"),
)
INPUTS = (Quantity("r", "rad/s", "yaw rate (gyro)"),)
NOISES = (Quantity("w_r", "rad/s", "gyro noise"), Quantity("w_u", "m/s^2"), Quantity("w_v", "m/s^2"),
          Quantity("w_w", "m/s^2"))


def small_auv() -> Model:
    x, u, w = symbols("x", STATES), symbols("u", INPUTS), symbols("w", NOISES)
    north, east, down, psi, surge, sway, heave = (x[i] for i in range(7))
    xdot = ca.vertcat(surge * ca.cos(psi) - sway * ca.sin(psi), surge * ca.sin(psi) + sway * ca.cos(psi), heave,
                      u[0] + w[0], w[1], w[2], w[3])
    sensors = (
        Sensor(name="depth", outputs=(Quantity("down", "m"),), y=down, noise=(0.05,), rate=5.0),
        Sensor(name="heading", outputs=(Quantity("psi", "rad"),), y=psi, noise=(0.02,), angle_outputs=(0,), rate=10.0),
        Sensor(name="dvl", outputs=(Quantity("u", "m/s"), Quantity("v", "m/s"), Quantity("w", "m/s")),
               y=ca.vertcat(surge, sway, heave),
               noise=(0.02, 0.02, 0.02), rate=2.0),
        Sensor(name="gps", outputs=(Quantity("north", "m"), Quantity("east", "m")), y=ca.vertcat(north, east), noise=(2.0, 2.0),
               rate=1.0),
        Sensor(name="usbl", outputs=(Quantity("north", "m"), Quantity("east", "m"), Quantity("down", "m")),
               y=ca.vertcat(north, east, down), noise=(1.0, 1.0, 1.0), rate=0.25, latency=(0.3, 0.8)),
    )
    return Model(name="small_auv", states=STATES, inputs=INPUTS, noises=NOISES, x=x, u=u, w=w, xdot=xdot,
                 sensors=sensors, angle_states=(3,), discretisation="rk4")
