"""Damping zones (a sponge layer, an absorbing beach): a_i += -k(x_i) v_i inside a box, with k
growing from 0 where the zone begins to its ``rate`` where it ends.

A wave that runs into a wall comes back; a numerical wave tank (a piston wave maker, a flume)
needs its far end to take the waves in instead. Israeli & Orszag's sponge layer damps the motion
over a stretch of the domain with a coefficient that rises smoothly from zero, so that the layer's
start reflects little (a jump in k would reflect like a wall) and the wave is spent before it
reaches the end:

    k(s) = rate s^2,   s = (x . e - start) / (end - start) in [0, 1],

e the zone's direction (one axis), start and end the zone's faces across it. It is the linear
drag of drag.py (a_i -= k v_i: energy leaves at 2 k E), confined to the zone and ramped across it.
SPH wave tanks damp this way (DualSPHysics' damping zones, Altomare et al. 2017); the quadratic ramp
is this code's choice. Symplectic Euler multiplies v by (1 - k dt) where nothing else acts: stable
and monotone for rate dt < 1, which the scene check requires of the largest step (time.dt).

- Israeli, Orszag, "Approximation of radiation boundary conditions", J. Comput. Phys. 41 (1981)
  115-135.
- Altomare, Domínguez, Crespo, González-Cao, Suzuki, Gómez-Gesteira, Troch, "Long-crested wave
  generation and absorption for SPH-based DualSPHysics model", Coastal Eng. 127 (2017) 37-54.

wall_damping: (nd, 10) rows [lo (3), hi (3), start, 1 / (end - start), axis, rate] (m, m, m, 1/m,
-, 1/s); 1 / (end - start) is negative for a zone that grows towards -e. A row holds particle i
when lo <= x < hi on every axis (an axis beyond the scene's dimension spans (-ZONE_FAR,
ZONE_FAR)); one padding row of rate 0 and an empty box for a scene without zones. Overlapping
zones add their k.
"""
from numba import njit

from sphcore.physics.real import like

DAMPING_COLUMNS = 10


@njit(cache=True, inline="always")
def damping_coefficient(i, x, wall_damping):
    """k(x_i) (1/s): the sum over the zones that hold row i of rate s^2."""
    k = like(x[i, 0], 0.0)
    for q in range(wall_damping.shape[0]):
        if (wall_damping[q, 0] <= x[i, 0] < wall_damping[q, 3] and wall_damping[q, 1] <= x[i, 1] < wall_damping[q, 4]
                and wall_damping[q, 2] <= x[i, 2] < wall_damping[q, 5]):
            axis = int(wall_damping[q, 8])
            s = (x[i, axis] - wall_damping[q, 6]) * wall_damping[q, 7]
            s = min(max(s, like(s, 0.0)), like(s, 1.0))  # round-off at the faces
            k += wall_damping[q, 9] * s * s
    return k


@njit(cache=True, inline="always")
def damping_row(i, x, v, wall_damping, a):
    """a_i += -k(x_i) v_i (row i inside a damping zone; nothing elsewhere)."""
    k = damping_coefficient(i, x, wall_damping)
    if k > 0.0:
        for c in range(3):
            a[i, c] -= k * v[i, c]
