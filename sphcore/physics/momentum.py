"""The momentum equation of one particle: a_i = pressure + viscosity + body force + wall pressure.

The pair terms and their papers are in pressure.py (the symmetric pressure gradient, Monaghan 1992,
or the difference form with the symmetric one in the free surface's layer),
viscosity.py (artificial, Muller, Morris; Balsara's switch in balsara.py), external.py (body
forces) and walls.py (the analytic wall's pressure and no-slip drag); this file sums them over i's
neighbours."""

import math

from numba import njit

from sphcore.physics.balsara import pair_factor
from sphcore.physics.external import body_acceleration_at
from sphcore.physics.kernels import lap_w_viscosity, pair_dw_dr_over_r, w
from sphcore.physics.pairs import candidate, span_rows, spans, walk_start
from sphcore.physics.pressure import corrected_gradient, difference_pair, pressure_pair, symmetric_share
from sphcore.physics.real import like
from sphcore.physics.viscosity import artificial_pair, morris_pair, muller_pair
from sphcore.physics.walls import near_wall, wall_difference_terms, wall_terms, wall_viscosity


@njit(cache=True, inline="always")
def acceleration_row(kernel, viscosity, viscosity_switch, pressure_gradient, periodic, neighbours, prm, i, x, v, m, rho, p,
                     nbr, counts, cells, cell_begin, cell_end, wall_kind, wall_data, wall_tables, wall_motion, wall_near,
                     fill, balsara, a):
    """a_i = pressure + viscosity + body force + wall pressure.   (pressure.py, viscosity.py,
    external.py, walls.py; moving walls: motion.py; with ``viscosity_switch`` each pair's artificial
    viscosity scaled by Balsara's switch: balsara.py)

    With the difference form (pressure_gradient 1) the pass also sums the concentration C_i, the
    symmetric form's zeroth-order part z_i = symmetric - difference and the gradient moment B_i (the
    walls' virtual lattice in it too), adds z_i and the walls' uniform push in the share
    symmetric_share(C_i) (1 in the free surface's layer, 0 in the bulk), and the difference sum
    corrected by B_i^-1 in the rest (pressure.py)."""
    bx, by, bz = body_acceleration_at(prm, x[i, 0], x[i, 1], x[i, 2])
    ax = bx
    ay = by
    az = bz
    rho_i = rho[i]
    p_i = p[i]
    p_rho2_i = p_i / (rho_i * rho_i)
    zx = like(bx, 0.0)  # difference form: the symmetric form's zeroth-order part, sum (symmetric - difference)
    zy = like(bx, 0.0)
    zz = like(bx, 0.0)
    c_i = m[i] / prm.rho0 * prm.w0  # difference form: the concentration C_i (its self term)
    qx = like(bx, 0.0)  # difference form: sum -1/rho_i V_j (p_j - p_i) grad W, and its moment B (pressure.py)
    qy = like(bx, 0.0)
    qz = like(bx, 0.0)
    bxx = like(bx, 0.0)
    bxy = like(bx, 0.0)
    bxz = like(bx, 0.0)
    byy = like(bx, 0.0)
    byz = like(bx, 0.0)
    bzz = like(bx, 0.0)
    home = walk_start(neighbours, x, i, cells)
    for span in range(spans(neighbours, cells)):
        k_lo, k_hi = span_rows(neighbours, span, home, i, counts, cells, cell_begin, cell_end)
        for k in range(k_lo, k_hi):
            j, dx, dy, dz, r2, inside = candidate(neighbours, periodic, x, nbr, i, k, prm, cells)
            if not inside:
                continue
            r_ij = math.sqrt(r2)
            if pressure_gradient == 1:  # PressureGradient.DIFFERENCE
                c_i += m[j] / prm.rho0 * w(kernel, r_ij, prm.H, prm.s_w)
            # coincident particles add nothing (no direction): every term below is proportional to
            # dw_over_r, which is 0 for them (kernels.pair_dw_dr_over_r: a select, not a branch)
            dw_over_r = pair_dw_dr_over_r(kernel, r2, r_ij, prm.H, prm.s_g)
            if pressure_gradient == 1:  # PressureGradient.DIFFERENCE
                fd = difference_pair(m[j], p_i, rho_i, p[j], rho[j], dw_over_r)
                f0 = pressure_pair(m[j], p_rho2_i, p[j], rho[j], dw_over_r) - fd
                zx += f0 * dx
                zy += f0 * dy
                zz += f0 * dz
                qx += fd * dx
                qy += fd * dy
                qz += fd * dz
                vg = -m[j] / rho[j] * dw_over_r  # B += V_j grad_i W (x) (x_j - x_i) = -V_j W'/r x_ij x_ij
                bxx += vg * dx * dx
                bxy += vg * dx * dy
                bxz += vg * dx * dz
                byy += vg * dy * dy
                byz += vg * dy * dz
                bzz += vg * dz * dz
                f = like(fd, 0.0)
            elif pressure_gradient == 0:  # PressureGradient.SYMMETRIC
                f = pressure_pair(m[j], p_rho2_i, p[j], rho[j], dw_over_r)
            else:  # PressureGradient.SOLVED: DFSPH's solves apply the pressure (p = 0 here)
                f = like(dw_over_r, 0.0)
            if viscosity == 1:  # Viscosity.ARTIFICIAL
                vdotx = ((v[i, 0] - v[j, 0]) * dx + (v[i, 1] - v[j, 1]) * dy + (v[i, 2] - v[j, 2]) * dz)
                av = artificial_pair(m[j], vdotx, r2, rho_i, rho[j], dw_over_r, prm.alpha, prm.c0, prm.h)
                if viscosity_switch == 1:  # Balsara's switch (balsara.py); without it ``balsara`` has one row
                    av *= pair_factor(balsara[i], balsara[j])
                f += av
            ax += f * dx
            ay += f * dy
            az += f * dz
            if viscosity == 2:  # Viscosity.MULLER: along v_j - v_i
                g = muller_pair(m[j], rho_i, rho[j], lap_w_viscosity(r_ij, prm.H, prm.s_l), prm.mu)
                g = g if r2 > like(r2, 0.0) else like(g, 0.0)  # the Laplacian is not proportional to dw_over_r
                ax += g * (v[j, 0] - v[i, 0])
                ay += g * (v[j, 1] - v[i, 1])
                az += g * (v[j, 2] - v[i, 2])
            elif viscosity == 3:  # Viscosity.MORRIS: along v_i - v_j
                g = morris_pair(m[j], r2, rho_i, rho[j], dw_over_r, prm.mu, prm.h)
                ax += g * (v[i, 0] - v[j, 0])
                ay += g * (v[i, 1] - v[j, 1])
                az += g * (v[i, 2] - v[j, 2])
    near = near_wall(cells, wall_near, x, i)
    if pressure_gradient == 1:  # PressureGradient.DIFFERENCE: the symmetric part in the surface layer's share
        if near:  # the walls count as fluid: their share Phi(d_i) of a full lattice
            zero = like(p_i, 0.0)
            phi, _, _, _ = wall_terms(kernel, prm, False, wall_kind, wall_data, wall_tables, wall_tables, False,
                                      x[i, 0], x[i, 1], x[i, 2], zero, rho_i, zero, zero, zero)
            c_i += phi / prm.rho0
        share = symmetric_share(c_i)
        ax += share * zx
        ay += share * zy
        az += share * zz
        if near:  # the walls' uniform push in the layer's share; their hydrostatic part into q and B
            zero = like(p_i, 0.0)
            _, wx, wy, wz = wall_terms(kernel, prm, True, wall_kind, wall_data, wall_tables, wall_motion, False,
                                       x[i, 0], x[i, 1], x[i, 2], share * p_i, rho_i, zero, zero, zero)
            ax += fill[i] * wx
            ay += fill[i] * wy
            az += fill[i] * wz
            hx, hy, hz, vxx, vxy, vxz, vyy, vyz, vzz = wall_difference_terms(
                prm, wall_kind, wall_data, wall_tables, wall_motion, x[i, 0], x[i, 1], x[i, 2], rho_i, bx, by, bz)
            qx += fill[i] * hx
            qy += fill[i] * hy
            qz += fill[i] * hz
            bxx += fill[i] * vxx
            bxy += fill[i] * vxy
            bxz += fill[i] * vxz
            byy += fill[i] * vyy
            byz += fill[i] * vyz
            bzz += fill[i] * vzz
        cx, cy, cz = corrected_gradient(prm.dim3, qx, qy, qz, bxx, bxy, bxz, byy, byz, bzz)
        keep = like(share, 1.0) - share  # the correction fades in the free surface's layer
        ax += keep * cx + share * qx
        ay += keep * cy + share * qy
        az += keep * cz + share * qz
    elif near:  # elsewhere the walls' terms are zero
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
