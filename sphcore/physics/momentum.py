"""The momentum equation of one particle: a_i = pressure + viscosity + body force + wall pressure.

The pair terms and their papers are in pressure.py (symmetric pressure gradient, Monaghan 1992),
viscosity.py (artificial, Muller, Morris), external.py (body forces) and walls.py (the analytic
wall's pressure and no-slip drag); this file sums them over i's neighbours."""

import math

from numba import njit

from sphcore.physics.external import body_acceleration_at
from sphcore.physics.kernels import dw_dr_over_r, lap_w_viscosity
from sphcore.physics.pairs import candidate, span_rows, spans, walk_start
from sphcore.physics.pressure import pressure_pair
from sphcore.physics.viscosity import artificial_pair, morris_pair, muller_pair
from sphcore.physics.walls import near_wall, wall_terms, wall_viscosity


@njit(cache=True, inline="always")
def acceleration_row(kernel, viscosity, periodic, neighbours, prm, i, x, v, m, rho, p, nbr, counts, cells, cell_begin,
                     cell_end, wall_kind, wall_data, wall_tables, wall_motion, wall_near, fill, a):
    """a_i = pressure + viscosity + body force + wall pressure.   (pressure.py, viscosity.py,
    external.py, walls.py; moving walls: motion.py)"""
    bx, by, bz = body_acceleration_at(prm, x[i, 0], x[i, 1], x[i, 2])
    ax = bx
    ay = by
    az = bz
    rho_i = rho[i]
    p_i = p[i]
    p_rho2_i = p_i / (rho_i * rho_i)
    home = walk_start(neighbours, x, i, cells)
    for span in range(spans(neighbours, cells)):
        k_lo, k_hi = span_rows(neighbours, span, home, i, counts, cells, cell_begin, cell_end)
        for k in range(k_lo, k_hi):
            j, dx, dy, dz, r2, inside = candidate(neighbours, periodic, x, nbr, i, k, prm, cells)
            if not inside:
                continue
            r_ij = math.sqrt(r2)
            if r2 == 0.0:
                continue  # coincident particles: no direction, no pressure force
            dw_over_r = dw_dr_over_r(kernel, r_ij, prm.H, prm.s_g)
            f = pressure_pair(m[j], p_rho2_i, p[j], rho[j], dw_over_r)
            if viscosity == 1:  # Viscosity.ARTIFICIAL
                vdotx = ((v[i, 0] - v[j, 0]) * dx + (v[i, 1] - v[j, 1]) * dy + (v[i, 2] - v[j, 2]) * dz)
                f += artificial_pair(m[j], vdotx, r2, rho_i, rho[j], dw_over_r, prm.alpha, prm.c0, prm.h)
            ax += f * dx
            ay += f * dy
            az += f * dz
            if viscosity == 2:  # Viscosity.MULLER: along v_j - v_i
                g = muller_pair(m[j], rho_i, rho[j], lap_w_viscosity(r_ij, prm.H, prm.s_l), prm.mu)
                ax += g * (v[j, 0] - v[i, 0])
                ay += g * (v[j, 1] - v[i, 1])
                az += g * (v[j, 2] - v[i, 2])
            elif viscosity == 3:  # Viscosity.MORRIS: along v_i - v_j
                g = morris_pair(m[j], r2, rho_i, rho[j], dw_over_r, prm.mu, prm.h)
                ax += g * (v[i, 0] - v[j, 0])
                ay += g * (v[i, 1] - v[j, 1])
                az += g * (v[i, 2] - v[j, 2])
    near = near_wall(cells, wall_near, x, i)
    if near:  # elsewhere the walls' terms are zero
        _, wx, wy, wz = wall_terms(kernel, prm, True, wall_kind, wall_data, wall_tables, wall_motion, True,
                                   x[i, 0], x[i, 1], x[i, 2], p_i, rho_i, bx, by, bz)
        ax += fill[i] * wx
        ay += fill[i] * wy
        az += fill[i] * wz
    if viscosity == 3 and near:  # Viscosity.MORRIS: no-slip walls (none within reach elsewhere)
        kv, ux, uy, uz = wall_viscosity(prm, wall_kind, wall_data, wall_tables, wall_motion, x[i, 0], x[i, 1],
                                        x[i, 2], rho_i)
        ax += fill[i] * (kv * v[i, 0] - ux)
        ay += fill[i] * (kv * v[i, 1] - uy)
        az += fill[i] * (kv * v[i, 2] - uz)
    a[i, 0] = ax
    a[i, 1] = ay
    a[i, 2] = az
