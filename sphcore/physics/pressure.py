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

**The gradient corrected to first order** (since 2026-12-06). On a disordered arrangement the
difference sum is exact for a uniform pressure but not for a linear one: a resting column's particle
pressures then settle to a gradient that is not rho g (around a held cylinder 9,594 Pa/m in the first
layer against 9,810), and the body's buoyancy, fitted from those pressures, came out 5 % short. So
the bulk form is multiplied by the inverse of the arrangement's gradient moment (Bonet & Lok 1999;
Randles & Libersky 1996):

    a_i = - 1 / rho_i  B_i^-1 sum_j V_j (p_j - p_i) grad_i W_ij,    B_i = sum_j V_j grad_i W_ij (x) (x_j - x_i)

which is exact for any linear pressure whatever the arrangement (B = I on the initial lattice, whose
gradient constant is calibrated so: boundaries.lattice_gradient_moment). The walls' virtual lattice
is in both sums: its hydrostatic push is the difference sum over it, -B_v b, and its moment B_v =
-(rho0 / rho_i)(G1 n n + G2 (I - n n)) comes from the same tables (walls.wall_difference_terms).
In the free surface's layer, where half of the neighbours are missing and B is far from I, the
correction fades with the symmetric form's share; where B is near singular (det B < MIN_MOMENT_DET)
the sum is used uncorrected.
"""
from numba import njit

from sphcore.physics.real import like

SURFACE_LAYER = (0.85, 0.95)  # C_i: below the first, the symmetric form; above the second, the difference form
MIN_MOMENT_DET = 0.1          # det B_i below this (1 on the lattice): the difference sum uncorrected


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


@njit(cache=True, inline="always")
def corrected_gradient(dim3, qx, qy, qz, bxx, bxy, bxz, byy, byz, bzz):
    """B^-1 q for the symmetric moment B (xx, xy, xz, yy, yz, zz) by Cramer's rule (2x2 in 2D), or q
    itself where det B < MIN_MOMENT_DET."""
    if dim3:
        cxx = byy * bzz - byz * byz
        cxy = bxz * byz - bxy * bzz
        cxz = bxy * byz - bxz * byy
        det = bxx * cxx + bxy * cxy + bxz * cxz
        if det < like(det, MIN_MOMENT_DET):
            return qx, qy, qz
        cyy = bxx * bzz - bxz * bxz
        cyz = bxy * bxz - bxx * byz
        czz = bxx * byy - bxy * bxy
        return ((cxx * qx + cxy * qy + cxz * qz) / det, (cxy * qx + cyy * qy + cyz * qz) / det,
                (cxz * qx + cyz * qy + czz * qz) / det)
    det = bxx * byy - bxy * bxy
    if det < like(det, MIN_MOMENT_DET):
        return qx, qy, qz
    return (byy * qx - bxy * qy) / det, (bxx * qy - bxy * qx) / det, qz
