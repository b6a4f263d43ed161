"""Vorticity confinement (Fedkiw, Stam & Jensen 2001; SPH form as in Macklin & Müller 2013, eq. 15-16).

Numerical dissipation damps small eddies; confinement puts the lost rotation back:

    omega_i = sum_j m_j / rho_j grad_i W_ij x (v_j - v_i)        (SPH curl of v, eq. 15)
    eta_i   = sum_j m_j / rho_j |omega_j| grad_i W_ij            (gradient of |omega|)
    N_i     = eta_i / |eta_i|,    a_i += eps (N_i x omega_i)

omega is in 1/s and N is a unit vector, so ``eps`` is in m/s. In 2D omega has only a z component
and the cross products reduce accordingly (vectors are always stored with 3 components, z = 0).
"""
from numba import njit
import math
from sphcore.physics.kernels import pair_dw_dr_over_r
from sphcore.physics.pairs import candidate, span_rows, spans, walk_start
from sphcore.physics.real import like


@njit(cache=True, inline="always")
def curl_pair(f, vjx, vjy, vjz, gx, gy, gz):
    """f * (grad W x v_ji) with v_ji = v_j - v_i and grad W = grad_i W_ij = (gx, gy, gz)."""
    return (f * (gy * vjz - gz * vjy), f * (gz * vjx - gx * vjz), f * (gx * vjy - gy * vjx))


@njit(cache=True, inline="always")
def confinement(eps, nx, ny, nz, ox, oy, oz):
    """eps * (N x omega) for a unit vector N = (nx, ny, nz) and vorticity omega."""
    return (eps * (ny * oz - nz * oy), eps * (nz * ox - nx * oz), eps * (nx * oy - ny * ox))


@njit(cache=True, inline="always")
def vorticity_row(kernel, periodic, neighbours, prm, i, x, v, m, rho, nbr, counts, cells, cell_begin, cell_end, omega):
    """omega_i = sum_j m_j / rho_j grad W_ij x (v_j - v_i).   (vorticity.py)"""
    ox = like(prm.H, 0.0)
    oy = like(prm.H, 0.0)
    oz = like(prm.H, 0.0)
    home = walk_start(neighbours, x, i, cells)
    for span in range(spans(neighbours, cells)):
        k_lo, k_hi = span_rows(neighbours, span, home, i, counts, cells, cell_begin, cell_end)
        for k in range(k_lo, k_hi):
            j, dx, dy, dz, r2, inside = candidate(neighbours, periodic, x, nbr, i, k, prm, cells)
            if not inside:
                continue
            g = pair_dw_dr_over_r(kernel, r2, math.sqrt(r2), prm.H, prm.s_g)  # 0 for coincident particles
            cx, cy, cz = curl_pair(m[j] / rho[j], v[j, 0] - v[i, 0], v[j, 1] - v[i, 1], v[j, 2] - v[i, 2],
                                   g * dx, g * dy, g * dz)
            ox += cx
            oy += cy
            oz += cz
    omega[i, 0] = ox
    omega[i, 1] = oy
    omega[i, 2] = oz


@njit(cache=True, inline="always")
def confinement_row(kernel, periodic, neighbours, prm, i, x, m, rho, omega, nbr, counts, cells, cell_begin, cell_end,
                    a):
    """a_i += eps N_i x omega_i, N = eta/|eta|, eta_i = sum_j m_j/rho_j |omega_j| grad W_ij."""
    ex = like(prm.H, 0.0)
    ey = like(prm.H, 0.0)
    ez = like(prm.H, 0.0)
    home = walk_start(neighbours, x, i, cells)
    for span in range(spans(neighbours, cells)):
        k_lo, k_hi = span_rows(neighbours, span, home, i, counts, cells, cell_begin, cell_end)
        for k in range(k_lo, k_hi):
            j, dx, dy, dz, r2, inside = candidate(neighbours, periodic, x, nbr, i, k, prm, cells)
            if not inside:
                continue
            wj = math.sqrt(omega[j, 0] ** 2 + omega[j, 1] ** 2 + omega[j, 2] ** 2)
            g = m[j] / rho[j] * wj * pair_dw_dr_over_r(kernel, r2, math.sqrt(r2), prm.H, prm.s_g)
            ex += g * dx
            ey += g * dy
            ez += g * dz
    norm = math.sqrt(ex * ex + ey * ey + ez * ez)
    if norm > 0.0:
        fx, fy, fz = confinement(prm.vorticity_eps, ex / norm, ey / norm, ez / norm,
                                 omega[i, 0], omega[i, 1], omega[i, 2])
        a[i, 0] += fx
        a[i, 1] += fy
        a[i, 2] += fz
