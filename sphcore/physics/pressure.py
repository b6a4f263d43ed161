"""The pressure acceleration: the symmetric form (Monaghan 1992) and the difference form.

Symmetric (``sph.pressure_gradient = "symmetric"``, the default; Monaghan 1992, eq. 3.3):

    a_i = - sum_j m_j (p_i / rho_i^2 + p_j / rho_j^2) grad_i W(r_ij)

The pair term is antisymmetric in i and j, so the total linear momentum is conserved to round-off;
because it acts along x_ij, angular momentum is conserved as well. But it is exact for a uniform
pressure only where sum_j V_j grad W_ij = 0, on a regular lattice: written as

    symmetric = difference - 2 p_i / rho_i  sum_j V_j grad_i W_ij      (V_j = m_j / rho_j; equal densities)

it carries a zeroth-order term proportional to the pressure itself. That term orders the particles
(a disordered neighbourhood is pushed back towards the lattice with a stiffness ~ p_i) and, at a
free surface, where half of the neighbours are missing, it is what sets p = 0 outside the fluid
(Colagrossi, Antuono & Le Touze 2009). In slow viscous flow under a hydrostatic head it is also
a resistance to the particles' rearrangement around a moving body that grows with the pressure
level: a cylinder settling at Re 0.04 under 245 Pa of water settled at two thirds of Faxen's speed,
at a tenth of that pressure at its speed (docs/VALIDATION.md, the settling cylinder).

Difference (``sph.pressure_gradient = "difference"``):

    a_i = - 1 / rho_i  sum_j V_j (p_j - p_i) grad_i W(r_ij)              in the bulk
    a_i = symmetric                                                      in the free surface's layer

A uniform pressure does not enter the bulk form, whatever the arrangement. It does not conserve
momentum pair by pair, and it does not order the particles: particle shifting has to
(``terms.shifting`` > 0 is required; Lind et al. 2012 pair the difference form with shifting for
that reason). At a free surface it would hold the missing neighbours at p_i instead of 0 and pull
a surface particle with p_i > 0 into the fluid, which compresses it further: so the layer keeps the
symmetric form. The layer is found by the particle concentration with the walls counted as fluid,
C_i = sum_j V_j W_ij + Phi_walls(d_i) (as particle shifting finds it, physics/shifting.py): the
share of the symmetric form is 1 for C_i <= SURFACE_LAYER[0], 0 for C_i >= SURFACE_LAYER[1], linear
between, so that nothing jumps as a particle crosses it. The walls' pressure term follows the same
share (physics/walls.py: its uniform push -2 p_i G0 n is the walls' share of the zeroth-order term;
their hydrostatic part is the difference form's). So in the bulk the walls no longer push with the
particles' pressure, and the reaction to their push (physics/bodies.py) is no force on a floating
body: with floating bodies the difference form needs sph.body_force = "traction", the surface
integral of the fitted pressure and viscous stress (physics/traction.py).
"""
from numba import njit

from sphcore.physics.real import like

SURFACE_LAYER = (0.85, 0.95)  # C_i: below the first, the symmetric form; above the second, the difference form


@njit(cache=True, inline="always")
def pressure_pair(m_j, p_rho2_i, p_j, rho_j, dw_over_r):
    """Scalar factor f so that the symmetric form's pair acceleration is f * x_ij; p_rho2_i = p_i / rho_i^2
    and dw_over_r = (dW/dr) / r_ij."""
    return -m_j * (p_rho2_i + p_j / (rho_j * rho_j)) * dw_over_r


@njit(cache=True, inline="always")
def difference_pair(m_j, p_i, rho_i, p_j, rho_j, dw_over_r):
    """Scalar factor f so that the difference form's pair acceleration is f * x_ij."""
    return -m_j * (p_j - p_i) / (rho_i * rho_j) * dw_over_r


@njit(cache=True, inline="always")
def symmetric_share(c_i):
    """The share of the symmetric form at concentration C_i: 1 in the free surface's layer, 0 in the
    bulk, linear over SURFACE_LAYER."""
    lo = like(c_i, SURFACE_LAYER[0])
    hi = like(c_i, SURFACE_LAYER[1])
    return min(max((hi - c_i) / (hi - lo), like(c_i, 0.0)), like(c_i, 1.0))
