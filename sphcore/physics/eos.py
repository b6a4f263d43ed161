"""Equations of state for weakly compressible SPH.

* linear (the seeds; Desbrun & Gascuel 1996, Müller 2003 eq. 12 with rest density):
  p = k (rho - rho0), k = c0^2
* Tait (Batchelor 1967, used for SPH by Monaghan 1994 "Simulating free surface flows with SPH"):
  p = B ((rho/rho0)^gamma - 1), gamma = 7, B = rho0 c0^2 / gamma

With ``clamp_negative`` the pressure is floored at zero: free-surface particles with a partial
neighbourhood then do not attract each other (the usual remedy for tensile clumping at a free
surface); scenes without a free surface (Taylor-Green) keep negative pressures.
"""
from numba import njit

from sphcore.physics.real import like


@njit(cache=True, inline="always")
def pressure(eos, rho, rho0, c0, clamp_negative, p_b):
    """Pressure p(rho) in Pa for EOS code ``eos`` (sphcore.choices.EOS), plus the background pressure
    p_b (sph.background_pressure; Morris, Fox & Zhu 1997, J. Comput. Phys. 136: 214-226). A constant
    adds no force on a uniform lattice; on disordered particles the symmetric pressure term pushes
    them apart where they thin out, so a confined flow's corner where the pressure would fall
    below zero (a lid-driven cavity's upstream lid corner) is refilled instead of left empty."""
    if eos == 0:  # EOS.LINEAR
        p = c0 * c0 * (rho - rho0)
    else:  # EOS.TAIT with gamma = 7, unrolled power
        ratio = rho / rho0
        r2 = ratio * ratio
        r4 = r2 * r2
        p = rho0 * c0 * c0 / like(rho, 7.0) * (r4 * r2 * ratio - like(rho, 1.0))
    if clamp_negative and p < like(p, 0.0):
        p = like(p, 0.0)
    return p + p_b


@njit(cache=True, inline="always")
def sound_speed_sq(eos, rho, rho0, c0):
    """dp/drho at rho (m^2/s^2): c0^2 (linear), c0^2 (rho/rho0)^(gamma-1) (Tait)."""
    if eos == 0:  # EOS.LINEAR
        return c0 * c0 + like(rho, 0.0)
    ratio = rho / rho0
    r2 = ratio * ratio
    return c0 * c0 * (r2 * r2 * r2)
