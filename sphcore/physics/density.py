"""Density by kernel summation (Monaghan 1992, eq. 2.4; Müller 2003, eq. 3).

    rho_i = sum_j m_j W(r_ij, H) + rho0 * Phi(d_i)

The sum runs over the particle itself and its neighbours; the second term is the share of the kernel
that lies behind the walls (``sphcore.physics.walls``), so that particles next to a wall see a full
kernel support instead of a density deficit.
"""
import math

from numba import njit

from sphcore.physics.continuity import density_rate_pair
from sphcore.physics.eos import pressure
from sphcore.physics.kernels import pair_dw_dr_over_r, w
from sphcore.physics.pairs import candidate, computed_mass_gradient, span_rows, spans, store_gradient, walk_start
from sphcore.physics.walls import fill_fraction, moving_wall_rate, near_wall, wall_density_gradient, wall_terms
from sphcore.physics.real import like


@njit(cache=True, inline="always")
def density_pair(kernel, m_j, r_ij, H, s_w):
    """Contribution m_j W(r_ij) of neighbour j to rho_i."""
    return m_j * w(kernel, r_ij, H, s_w)


@njit(cache=True, inline="always")
def density_row(kernel, eos, periodic, neighbours, pair_gradients, continuity, prm, i, x, v, m, nbr, counts, cells,
                cell_begin, cell_end, wall_kind, wall_data, wall_tables, wall_motion, wall_near, dt_prev, commit, rho_c,
                rho, p, fill, grad_w):
    """rho_i = m_i W(0) + sum_j m_j W_ij + theta_i rho0 Phi(d_i);  p_i = EOS(rho_i); fill_i = theta_i.
    With ``continuity``: rho_i = rho_c[i] + dt_prev D rho_i/Dt, the carried density advanced by the
    continuity equation over the previous step with the velocities that moved the particles here
    (relative to a moving wall's for its share, motion.py)
    (stored back if ``commit``; a carried 0 starts at rho0). Returns i's neighbour count twice (their
    sum and maximum over the rows are the step's neighbour statistics). (density.py, continuity.py,
    eos.py, walls.py). With ``pair_gradients`` (DFSPH, lists) it also stores m_j grad W_ij of every
    list entry, read by the DFSPH factor and solves (pairs.mass_gradient)."""
    rho_i = m[i] * prm.w0
    rate = like(rho_i, 0.0)
    found = 0  # neighbours of i (the step's neighbour statistics)
    home = walk_start(neighbours, x, i, cells)
    for span in range(spans(neighbours, cells)):
        k_lo, k_hi = span_rows(neighbours, span, home, i, counts, cells, cell_begin, cell_end)
        for k in range(k_lo, k_hi):
            j, dx, dy, dz, r2, inside = candidate(neighbours, periodic, x, nbr, i, k, prm, cells)
            if not inside:
                continue
            found += 1
            r_ij = math.sqrt(r2)
            rho_i += density_pair(kernel, m[j], r_ij, prm.H, prm.s_w)
            if pair_gradients:
                wx, wy, wz = computed_mass_gradient(kernel, m[j], dx, dy, dz, r2, prm)
                store_gradient(pair_gradients, grad_w, i, k, wx, wy, wz)
            if continuity:
                g = pair_dw_dr_over_r(kernel, r2, r_ij, prm.H, prm.s_g)  # 0 for coincident particles
                rate += density_rate_pair(m[j], v[i, 0] - v[j, 0], v[i, 1] - v[j, 1], v[i, 2] - v[j, 2],
                                          g * dx, g * dy, g * dz)
    # the walls' density share: geometry only (no frame: the motion argument, here wall_tables, is not read);
    # zero, and not evaluated, in a cell no wall reaches
    drho = like(rho_i, 0.0)
    near = near_wall(cells, wall_near, x, i)
    if near:
        drho, _, _, _ = wall_terms(kernel, prm, False, wall_kind, wall_data, wall_tables, wall_tables, False,
                                   x[i, 0], x[i, 1], x[i, 2], like(rho_i, 0.0), rho_i, like(rho_i, 0.0),
                                   like(rho_i, 0.0), like(rho_i, 0.0))
    theta = fill_fraction(rho_i, drho, prm.rho0)
    fill[i] = theta
    rho_i += theta * drho
    if continuity:
        if rho_c[i] <= 0.0:  # a new run: its lattice is at rest density (continuity.py)
            rho_c[i] = prm.rho0
            rho_i = rho_c[i]
        else:
            # the wall's share theta rho0 Phi(d) changes at its gradient . (v_i - u_wall); zero where no
            # wall reaches (every cell is flagged when a wall moves)
            r = rho_c[i]
            if near:
                wx, wy, wz = wall_density_gradient(kernel, prm, wall_kind, wall_data, wall_tables, x, i, r, theta)
                rate += wx * v[i, 0] + wy * v[i, 1] + wz * v[i, 2]
                rate -= moving_wall_rate(kernel, prm, wall_kind, wall_data, wall_tables, wall_motion, x, i, r, theta)
            # never below the particle's own share of its kernel sum, m_i W(0): the least summation
            # density a particle can have. In a spray the continuity equation (its rate does not
            # shrink with rho_i) drives a lone particle's density towards zero and past it, and the
            # diffusion's m_j / rho_j of such a neighbour then grows without bound (continuity.py)
            rho_i = max(r + dt_prev * rate, m[i] * prm.w0)
            if commit:
                rho_c[i] = rho_i
    rho[i] = rho_i
    p[i] = pressure(eos, rho_i, prm.rho0, prm.c0, prm.clamp_negative, prm.p_background)
    return found, found
