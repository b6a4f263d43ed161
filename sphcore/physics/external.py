"""Body forces: gravity plus a constant external acceleration whose direction the scene sets, and an
optional central force field.

Seed 000 let the user turn the force direction with a slider; here the scene gives ``gravity`` and
``external`` (both m/s^2) and the total body acceleration g + f_ext is applied to every particle:
    a_i += zeta(t) (g + f_ext)

zeta(t) ramps the load in smoothly over ``ramp_time`` T (Adami, Hu & Adams 2012, section 4.1):
zeta = (sin((t/T - 1/2) pi) + 1) / 2 for t < T, 1 afterwards. A fluid that starts at rest density
then settles into hydrostatic balance without the acoustic ringing of a sudden load.

The central field a_i = -omega^2 (x_i - c) (Monaghan & Rafiee 2013, section 5.1: "a drop of fluid
in a central force field") holds a free drop together without surface tension; its rotating-ellipse
solution is the oscillating-drop validation case. It is evaluated only when omega > 0.
"""
import math


def ramp_factor(t: float, ramp_time: float) -> float:
    """zeta(t) of the module docstring."""
    if ramp_time <= 0.0 or t >= ramp_time:
        return 1.0
    return 0.5 * (math.sin((t / ramp_time - 0.5) * math.pi) + 1.0)
from numba import njit


@njit(cache=True, inline="always")
def body_acceleration(prm):
    """Total body acceleration (ax, ay, az) = gravity + external in m/s^2 (fields of Params)."""
    return prm.gravity_x + prm.external_x, prm.gravity_y + prm.external_y, prm.gravity_z + prm.external_z


@njit(cache=True, inline="always")
def body_acceleration_at(prm, x, y, z):
    """The body forces at (x, y, z): gravity + external, plus the central force where there is one."""
    bx, by, bz = body_acceleration(prm)
    if prm.central_omega2 > 0.0:
        cx, cy, cz = central_acceleration(prm, x, y, z)
        bx += cx
        by += cy
        bz += cz
    return bx, by, bz


@njit(cache=True, inline="always")
def central_acceleration(prm, x, y, z):
    """-omega^2 (x - c) at (x, y, z) in m/s^2."""
    return (-prm.central_omega2 * (x - prm.central_x), -prm.central_omega2 * (y - prm.central_y),
            -prm.central_omega2 * (z - prm.central_z))
