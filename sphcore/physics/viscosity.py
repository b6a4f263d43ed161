"""Viscous accelerations, three variants (``sphcore.choices.Viscosity``).

* Artificial viscosity, Monaghan 1992 (eq. 4.1)::

      a_i += - sum_j m_j Pi_ij grad_i W_ij,   Pi_ij = -alpha c0 mu_ij / rho_ij   if v_ij . x_ij < 0
      mu_ij = h v_ij . x_ij / (r_ij^2 + 0.01 h^2),  rho_ij = (rho_i + rho_j) / 2,  h = H / 2

* Müller, Charypar & Gross 2003 (eq. 14) with the viscosity-kernel Laplacian (kernels.py)::

      a_i += (mu / rho_i) sum_j m_j (v_j - v_i) / rho_j lap W_visc(r_ij),   mu = rho0 nu

* Morris, Fox & Zhu 1997 (eq. 8), laminar viscosity with the gradient kernel::

      a_i += sum_j m_j (mu_i + mu_j) x_ij . grad_i W_ij / (rho_i rho_j (r_ij^2 + 0.01 h^2)) v_ij,
      mu_i = mu_j = rho0 nu

All three are symmetric in i and j and antisymmetric in v_ij, so they conserve linear momentum.
"""
from numba import njit

from sphcore.physics.real import like


@njit(cache=True, inline="always")
def artificial_pair(m_j, vdotx, r2, rho_i, rho_j, dw_over_r, alpha, c0, h):
    """Monaghan AV: scalar f so that the pair acceleration is f * x_ij (dw_over_r = dW/dr / r).

    Written without a branch on the sign of v_ij . x_ij (min(., 0) instead): the sign is random from
    pair to pair, and a mispredicted branch per pair cost more than the arithmetic it skips.
    -m_j Pi_ij = 2 m_j alpha c0 h min(v.x, 0) / ((r^2 + 0.01 h^2)(rho_i + rho_j))."""
    approaching = min(vdotx, like(vdotx, 0.0))
    return (like(m_j, 2.0) * m_j * alpha * c0 * h * approaching * dw_over_r
            / ((r2 + like(h, 0.01) * h * h) * (rho_i + rho_j)))


@njit(cache=True, inline="always")
def muller_pair(m_j, rho_i, rho_j, lap, mu):
    """Müller viscosity: scalar f so that the pair acceleration is f * (v_j - v_i)."""
    return mu / rho_i * m_j / rho_j * lap


@njit(cache=True, inline="always")
def morris_pair(m_j, r2, rho_i, rho_j, dw_over_r, mu, h):
    """Morris viscosity: scalar f so that the pair acceleration is f * v_ij (v_ij = v_i - v_j).

    x_ij . grad_i W_ij = dW/dr * r, so the factor is 2 mu m_j r^2 (dW/dr / r) / (rho_i rho_j (r^2 + eta^2)).
    """
    return m_j * like(mu, 2.0) * mu * r2 * dw_over_r / (rho_i * rho_j * (r2 + like(h, 0.01) * h * h))
