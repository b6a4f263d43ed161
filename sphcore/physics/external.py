"""Body forces: gravity plus a constant external acceleration whose direction the scene sets.

Seed 000 let the user turn the force direction with a slider; here the scene gives ``gravity`` and
``external`` (both m/s^2) and the total body acceleration g + f_ext is applied to every particle:
    a_i += zeta(t) (g + f_ext)

zeta(t) ramps the load in smoothly over ``ramp_time`` T (Adami, Hu & Adams 2012, section 4.1):
zeta = (sin((t/T - 1/2) pi) + 1) / 2 for t < T, 1 afterwards. A fluid that starts at rest density
then settles into hydrostatic balance without the acoustic ringing of a sudden load.
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
