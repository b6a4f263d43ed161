"""The mechanical energy of a particle, in integer units, for the energy watchdog (sphcore/health.py).

    e_i = m_i |v_i|^2 / 2 + m_i (u(x_i) - u_min),   u(x) = -b . x + omega^2 |x - c|^2 / 2

with b = g + f_ext the body force per unit mass, omega and c the central force field's rate and
centre (physics/external.py) and u_min the potential's least value in the grid's box, so that the
potential part is >= 0. v_i is the velocity at the full step (leapfrog stores the half step:
v + dt_prev a / 2, formed in the run's precision as the host's arrays did).

Each row's e_i is rounded to the nearest integer multiple of a quantum (2^-40 of the scene's energy
bound, health.py) and clamped at +-``cap`` units, so that the sum over rows and peers is an exact
integer whatever the order: every peer sees the same total. The energy is formed in float64 in every
precision (the quantum is 2^-40 of the bound: float32 could not resolve it); once per row.

A stage (stages.ENERGY) run every run.energy_check_every steps: on a GPU the state stays on the
device (the host's sum downloaded the whole state first: about 0.3 s at 4 M particles, 2026-12-04).
"""
from numba import njit

from sphcore.choices import Integrator
from sphcore.physics.real import like

_LEAPFROG = int(Integrator.LEAPFROG)

# energy_terms (float64): what the row reads beyond the state
BODY = 0        # b = g + f_ext (3), m/s^2
U_MIN = 3       # the potential's least value in the grid's box (m^2/s^2)
HALF_OMEGA2 = 4  # omega^2 / 2 of the central force (1/s^2)
CENTRE = 5      # c (3), m
QUANTUM = 8     # J (J/m in 2D) per integer unit
CAP = 9         # the clamp of one row's units (a blown-up run saturates the sum instead of overflowing)
TERMS = 10


@njit(cache=True, inline="always")
def energy_row(integrator, i, x, v, a, m, dt_prev, energy_terms, kinetic):
    """Row i's mechanical energy in integer units of energy_terms[QUANTUM] (module docstring); only the
    kinetic part if ``kinetic``."""
    t = energy_terms
    if integrator == _LEAPFROG:
        half = like(dt_prev, 0.5) * dt_prev
        vx, vy, vz = v[i, 0] + half * a[i, 0], v[i, 1] + half * a[i, 1], v[i, 2] + half * a[i, 2]
    else:
        vx, vy, vz = v[i, 0], v[i, 1], v[i, 2]
    mi = float(m[i])
    vx, vy, vz = float(vx), float(vy), float(vz)
    e = 0.5 * mi * (vx * vx + vy * vy + vz * vz)
    if not kinetic:
        x0, x1, x2 = float(x[i, 0]), float(x[i, 1]), float(x[i, 2])
        u = -(x0 * t[BODY] + x1 * t[BODY + 1] + x2 * t[BODY + 2]) - t[U_MIN]
        if t[HALF_OMEGA2] > 0.0:
            d0, d1, d2 = x0 - t[CENTRE], x1 - t[CENTRE + 1], x2 - t[CENTRE + 2]
            u += t[HALF_OMEGA2] * (d0 * d0 + d1 * d1 + d2 * d2)
        e += mi * u
    r = max(min(e / t[QUANTUM], t[CAP]), -t[CAP])
    if r >= 0.0:
        return int(r + 0.5)
    return -int(-r + 0.5)
