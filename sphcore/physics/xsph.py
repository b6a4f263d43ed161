"""XSPH velocity smoothing (Monaghan 1989, "On the problem of penetration in particle methods",
eq. 2.6; Monaghan 1992 eq. 4.4).

Particles are moved with a smoothed velocity, which keeps the flow more ordered without changing
the momentum equation:

    dx_i/dt = v_i + eps * sum_j m_j / rho_ij (v_j - v_i) W_ij,   rho_ij = (rho_i + rho_j) / 2

Only the drift uses the correction; the velocity itself is unchanged.
"""
import math

from numba import njit
from sphcore.physics.kernels import w
from sphcore.physics.pairs import candidate, span_rows, spans, walk_start
from sphcore.physics.real import like


@njit(cache=True, inline="always")
def xsph_pair(m_j, rho_i, rho_j, w_ij):
    """Scalar f so that the correction contribution is f * (v_j - v_i) (times eps)."""
    return m_j / (like(rho_i, 0.5) * (rho_i + rho_j)) * w_ij


@njit(cache=True, inline="always")
def xsph_row(kernel, periodic, neighbours, prm, i, x, v, m, rho, nbr, counts, cells, cell_begin, cell_end, dv):
    """dv_i = eps sum_j m_j / rho_ij (v_j - v_i) W_ij (the drift uses v + dv).   (xsph.py)"""
    sx = like(prm.H, 0.0)
    sy = like(prm.H, 0.0)
    sz = like(prm.H, 0.0)
    home = walk_start(neighbours, x, i, cells)
    for span in range(spans(neighbours, cells)):
        k_lo, k_hi = span_rows(neighbours, span, home, i, counts, cells, cell_begin, cell_end)
        for k in range(k_lo, k_hi):
            j, dx, dy, dz, r2, inside = candidate(neighbours, periodic, x, nbr, i, k, prm, cells)
            if not inside:
                continue
            r_ij = math.sqrt(r2)
            f = xsph_pair(m[j], rho[i], rho[j], w(kernel, r_ij, prm.H, prm.s_w))
            sx += f * (v[j, 0] - v[i, 0])
            sy += f * (v[j, 1] - v[i, 1])
            sz += f * (v[j, 2] - v[i, 2])
    dv[i, 0] = prm.xsph_eps * sx
    dv[i, 1] = prm.xsph_eps * sy
    dv[i, 2] = prm.xsph_eps * sz
