"""XSPH velocity smoothing (Monaghan 1989, "On the problem of penetration in particle methods",
eq. 2.6; Monaghan 1992 eq. 4.4).

Particles are moved with a smoothed velocity, which keeps the flow more ordered without changing
the momentum equation:

    dx_i/dt = v_i + eps * sum_j m_j / rho_ij (v_j - v_i) W_ij,   rho_ij = (rho_i + rho_j) / 2

Only the drift uses the correction; the velocity itself is unchanged.
"""
from numba import njit


@njit(cache=True, inline="always")
def xsph_pair(m_j, rho_i, rho_j, w_ij):
    """Scalar f so that the correction contribution is f * (v_j - v_i) (times eps)."""
    return m_j / (0.5 * (rho_i + rho_j)) * w_ij
