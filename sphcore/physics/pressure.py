"""Symmetric, momentum-conserving pressure acceleration (Monaghan 1992, eq. 3.3).

    a_i = - sum_j m_j (p_i / rho_i^2 + p_j / rho_j^2) grad_i W(r_ij)

The pair term is antisymmetric in i and j, so the total linear momentum is conserved to round-off;
because it acts along x_ij, angular momentum is conserved as well.
"""
from numba import njit


@njit(cache=True, inline="always")
def pressure_pair(m_j, p_rho2_i, p_j, rho_j, dw_over_r):
    """Scalar factor f so that the pair acceleration is f * x_ij; p_rho2_i = p_i / rho_i^2 and
    dw_over_r = (dW/dr) / r_ij."""
    return -m_j * (p_rho2_i + p_j / (rho_j * rho_j)) * dw_over_r
