"""Balsara's switch for the artificial viscosity (Balsara 1995, J. Comput. Phys. 121, 357, eq. 4.1;
in SPH form as Monaghan 2005, Rep. Prog. Phys. 68, 1703, section 4.2)::

    f_i = |div v_i| / (|div v_i| + |curl v_i| + 1e-4 c0 / h)
    div v_i  = -(1 / rho_i) sum_j m_j v_ij . grad_i W_ij
    curl v_i =  (1 / rho_i) sum_j m_j v_ij x grad_i W_ij            (v_ij = v_i - v_j)

The forces pass multiplies each pair's artificial viscosity by (f_i + f_j) / 2 (symmetric in i and
j: momentum stays conserved). Why: Monaghan's viscosity acts on every approaching pair, also in a
shear flow, where it is a shear viscosity nu ~ alpha c0 h / 8 that falls only with the spacing; f
keeps it where the flow compresses or expands (|div v| dominates: impacts, the dissipation a weakly
compressible fluid needs there) and takes it out where the flow shears (|curl v| dominates). In the
dam break that shear viscosity couples the surge's layers to the floor's friction and slows the late
front (docs/VALIDATION.md). The 1e-4 c0 / h keeps f defined where the fluid is at rest (f -> 0: no
flow, nothing to damp).

Gather: a row reads its neighbours' x, v and m and its own rho; the ghosts' f comes with exchange 2.
"""
import math

from numba import njit

from sphcore.physics.kernels import pair_dw_dr_over_r
from sphcore.physics.pairs import candidate, span_rows, spans, walk_start
from sphcore.physics.real import like
from sphcore.physics.vorticity import curl_pair

REST = 1.0e-4  # Balsara's floor, in units of c0 / h


@njit(cache=True, inline="always")
def switch(div, curl, c0, h):
    """f = |div| / (|div| + |curl| + REST c0 / h), in [0, 1)."""
    d = abs(div)
    return d / (d + curl + like(d, REST) * c0 / h)


@njit(cache=True, inline="always")
def pair_factor(f_i, f_j):
    """The factor of a pair's artificial viscosity with the switch: (f_i + f_j) / 2."""
    return like(f_i, 0.5) * (f_i + f_j)


@njit(cache=True, inline="always")
def balsara_row(kernel, periodic, neighbours, prm, i, x, v, m, rho, nbr, counts, cells, cell_begin, cell_end, balsara):
    """balsara_i = f_i from i's SPH divergence and curl of v.   (balsara.py)"""
    dv = like(prm.H, 0.0)   # sum_j m_j v_ji . grad_i W_ij = rho_i div v_i
    ox = like(prm.H, 0.0)   # sum_j m_j grad_i W_ij x v_ji = rho_i curl v_i
    oy = like(prm.H, 0.0)
    oz = like(prm.H, 0.0)
    home = walk_start(neighbours, x, i, cells)
    for span in range(spans(neighbours, cells)):
        k_lo, k_hi = span_rows(neighbours, span, home, i, counts, cells, cell_begin, cell_end)
        for k in range(k_lo, k_hi):
            j, dx, dy, dz, r2, inside = candidate(neighbours, periodic, x, nbr, i, k, prm, cells)
            if not inside:
                continue
            g = m[j] * pair_dw_dr_over_r(kernel, r2, math.sqrt(r2), prm.H, prm.s_g)  # 0 for coincident rows
            vx = v[j, 0] - v[i, 0]
            vy = v[j, 1] - v[i, 1]
            vz = v[j, 2] - v[i, 2]
            dv += g * (vx * dx + vy * dy + vz * dz)
            cx, cy, cz = curl_pair(g, vx, vy, vz, dx, dy, dz)  # m_j grad_i W_ij x v_ji (vorticity.py)
            ox += cx
            oy += cy
            oz += cz
    inv_rho = like(prm.H, 1.0) / rho[i]
    balsara[i] = switch(dv * inv_rho, math.sqrt(ox * ox + oy * oy + oz * oz) * inv_rho, prm.c0, prm.h)
