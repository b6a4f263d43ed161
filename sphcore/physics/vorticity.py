"""Vorticity confinement (Fedkiw, Stam & Jensen 2001; SPH form as in Macklin & Müller 2013, eq. 15-16).

Numerical dissipation damps small eddies; confinement puts the lost rotation back:

    omega_i = sum_j m_j / rho_j grad_i W_ij x (v_j - v_i)        (SPH curl of v, eq. 15)
    eta_i   = sum_j m_j / rho_j |omega_j| grad_i W_ij            (gradient of |omega|)
    N_i     = eta_i / |eta_i|,    a_i += eps (N_i x omega_i)

omega is in 1/s and N is a unit vector, so ``eps`` is in m/s. In 2D omega has only a z component
and the cross products reduce accordingly (vectors are always stored with 3 components, z = 0).
"""
from numba import njit


@njit(cache=True, inline="always")
def curl_pair(f, vjx, vjy, vjz, gx, gy, gz):
    """f * (grad W x v_ji) with v_ji = v_j - v_i and grad W = grad_i W_ij = (gx, gy, gz)."""
    return (f * (gy * vjz - gz * vjy), f * (gz * vjx - gx * vjz), f * (gx * vjy - gy * vjx))


@njit(cache=True, inline="always")
def confinement(eps, nx, ny, nz, ox, oy, oz):
    """eps * (N x omega) for a unit vector N = (nx, ny, nz) and vorticity omega."""
    return (eps * (ny * oz - nz * oy), eps * (nz * ox - nx * oz), eps * (nx * oy - ny * ox))
