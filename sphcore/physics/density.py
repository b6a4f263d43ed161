"""Density by kernel summation (Monaghan 1992, eq. 2.4; Müller 2003, eq. 3).

    rho_i = sum_j m_j W(r_ij, H) + rho0 * Phi(d_i)

The sum runs over the particle itself and its neighbours; the second term is the share of the kernel
that lies behind the walls (``sphcore.physics.walls``), so that particles next to a wall see a full
kernel support instead of a density deficit.
"""
from numba import njit

from sphcore.physics.kernels import w


@njit(cache=True, inline="always")
def density_pair(kernel, m_j, r_ij, H, s_w):
    """Contribution m_j W(r_ij) of neighbour j to rho_i."""
    return m_j * w(kernel, r_ij, H, s_w)
