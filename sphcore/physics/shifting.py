"""Fickian particle shifting (Lind, Xu, Stansby & Rogers 2012; diffusion coefficient of Skillen,
Lind, Stansby & Rogers 2013).

SPH particles following the flow's streamlines bunch up and leave gaps (in vortex cores and where
the pressure is negative), which ruins the kernel sums. Shifting moves each particle a little down
the gradient of the particle concentration C_i = sum_j V_j W_ij, like a diffusion:

    delta r_i = -D_i grad C_i,   grad C_i = sum_j V_j grad W_ij,   D_i = A h |v_i| dt,   V_j = m_j / rho0

with A of order 1-2 (the scene's ``terms.shifting``). The volumes are the lattice's, m_j / rho0 (Lind
et al. use m_j / rho_j in an incompressible scheme): with summation density, m_j / rho_j renormalises
C to ~1 even at a free surface, which would hide the surface from the test below. Here the shift is written as a drift velocity
dv_i = delta r_i / dt = -A h |v_i| grad C_i, added to the velocity that moves the particle (as XSPH's
correction is); the momentum equation is untouched. The drift diffuses the concentration with a
diffusivity ~A h |v|, so the step is limited to cfl h / (A max|v|) (sphcore/timestep.py): WCSPH's
acoustic step is smaller anyway, DFSPH's flow-speed step is not.

Walls count as fluid: C_i includes the walls' share Phi(d_i) of a full lattice (walls.py: the
virtual lattice behind an analytic wall) and grad C_i its gradient, so a lattice particle next to a
wall or in a corner sees a full neighbourhood (C = 1, no gradient) and a disordered one is shifted
towards the wall as readily as away from it. (Before 2026-12-05 only the fluid counted: C ~ 0.5 by a
wall put every particle within H of it in the surface layer below, unshifted, and the wall-normal
component was removed besides; a void by a wall, such as the lid-driven cavity's upstream corner,
could not be refilled.)

Near a free surface grad C points into the fluid because of the missing neighbours, not because
of disorder, and would push particles out of the fluid: in the free-surface layer (C_i below
``SURFACE_CONCENTRATION``) there is no shift (the simplest of the surface treatments of Lind et al.
2012, section 3.3). A closed flow (``sph.clamp_negative_pressure = false``: no free surface) has no
such layer; there a low C marks a void, and the shift draws the particles around it in.
"""
from numba import njit
import math
from sphcore.physics.kernels import pair_dw_dr_over_r, w
from sphcore.physics.pairs import candidate, span_rows, spans, walk_start
from sphcore.physics.walls import near_wall, wall_density_gradient, wall_terms
from sphcore.physics.real import like

SURFACE_CONCENTRATION = 0.9  # C_i below this marks a particle of the free-surface layer


@njit(cache=True, inline="always")
def concentration_gradient_pair(m_j, rho0, dw_over_r):
    """Scalar f so that the contribution of j to grad C_i is f * x_ij."""
    return m_j / rho0 * dw_over_r


@njit(cache=True, inline="always")
def shifting_row(kernel, periodic, neighbours, add, prm, i, x, v, m, rho, nbr, counts, cells, cell_begin, cell_end,
                 wall_kind, wall_data, wall_tables, wall_near, dv):
    """Particle shifting as a drift velocity, -A h |v_i| grad C_i, the walls' share in C and its
    gradient, none in a free surface's layer (shifting.py); added to dv if ``add`` (XSPH wrote it),
    else written."""
    gx = like(prm.H, 0.0)
    gy = like(prm.H, 0.0)
    gz = like(prm.H, 0.0)
    c = m[i] / prm.rho0 * prm.w0
    home = walk_start(neighbours, x, i, cells)
    for span in range(spans(neighbours, cells)):
        k_lo, k_hi = span_rows(neighbours, span, home, i, counts, cells, cell_begin, cell_end)
        for k in range(k_lo, k_hi):
            j, dx, dy, dz, r2, inside = candidate(neighbours, periodic, x, nbr, i, k, prm, cells)
            if not inside:
                continue
            r_ij = math.sqrt(r2)
            c += m[j] / prm.rho0 * w(kernel, r_ij, prm.H, prm.s_w)
            f = concentration_gradient_pair(m[j], prm.rho0, pair_dw_dr_over_r(kernel, r2, r_ij, prm.H, prm.s_g))
            gx += f * dx
            gy += f * dy
            gz += f * dz
    # the walls' share of C, Phi(d_i) (a full wall's: theta = 1), and its gradient; zero where no wall reaches
    if wall_kind.shape[0] > 0 and near_wall(cells, wall_near, x, i):
        zero = like(prm.H, 0.0)
        share, _, _, _ = wall_terms(kernel, prm, False, wall_kind, wall_data, wall_tables, wall_tables, False,
                                    x[i, 0], x[i, 1], x[i, 2], zero, rho[i], zero, zero, zero)
        c += share / prm.rho0
        wx, wy, wz = wall_density_gradient(kernel, prm, wall_kind, wall_data, wall_tables, x, i, rho[i],
                                           like(prm.H, 1.0))
        gx += wx / prm.rho0
        gy += wy / prm.rho0
        gz += wz / prm.rho0
    if prm.clamp_negative and c < like(c, SURFACE_CONCENTRATION):  # free-surface layer: grad C is the surface's
        gx = like(gx, 0.0)
        gy = like(gy, 0.0)
        gz = like(gz, 0.0)
    speed = math.sqrt(v[i, 0] * v[i, 0] + v[i, 1] * v[i, 1] + v[i, 2] * v[i, 2])
    s = -prm.shift_a * prm.h * speed
    if add:
        dv[i, 0] += s * gx
        dv[i, 1] += s * gy
        dv[i, 2] += s * gz
    else:
        dv[i, 0] = s * gx
        dv[i, 1] = s * gy
        dv[i, 2] = s * gz
