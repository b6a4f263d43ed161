"""Body forces: gravity plus a constant external acceleration whose direction the scene sets.

Seed 000 let the user turn the force direction with a slider; here the scene gives ``gravity`` and
``external`` (both m/s^2) and the total body acceleration g + f_ext is applied to every particle:
    a_i += g + f_ext
"""
from numba import njit


@njit(cache=True, inline="always")
def body_acceleration(prm):
    """Total body acceleration (ax, ay, az) = gravity + external in m/s^2 (fields of Params)."""
    return prm.gravity_x + prm.external_x, prm.gravity_y + prm.external_y, prm.gravity_z + prm.external_z
