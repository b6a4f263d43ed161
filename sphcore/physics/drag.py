"""Linear drag (Rayleigh damping): a_i += -k v_i.

A body force proportional to the velocity removes kinetic energy at the rate 2 k E without
changing where the fluid comes to rest; SPH codes use it to settle an initial particle lattice
under gravity before the measured run (the dynamic-relaxation step of e.g. Adami, Hu & Adams 2012,
"A generalized wall boundary condition for smoothed particle hydrodynamics", J. Comput. Phys.
231, 7057, initialise their tanks this way). With symplectic Euler and no other force a velocity
decays as v_n = v_0 (1 - k dt)^n: stable and monotone for k dt < 1.

This term is also the worked example of docs/ARCHITECTURE.md "Adding a term": this file, one
``Stage`` in sphcore/stages.py and the scene key ``terms.drag``.
"""
from numba import njit


@njit(cache=True, inline="always")
def drag_row(i, v, coefficient, a):
    """a_i += -k v_i (k = ``coefficient``, 1/s)."""
    for c in range(3):
        a[i, c] -= coefficient * v[i, c]
