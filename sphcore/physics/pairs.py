"""What every neighbour pass shares: how row i finds its neighbours j and the separation
x_ij = x_i - x_j of a pair (minimum image on periodic axes, grid.minimum_image).

Every pass loops the same way, whichever the compile-time choice ``neighbours`` (stages.CHOICES):

    home = walk_start(neighbours, x, i, cells)
    for s in range(spans(neighbours, cells)):
        lo, hi = span_rows(neighbours, s, home, i, counts, cells, cell_begin, cell_end)
        for k in range(lo, hi):
            j, dx, dy, dz, r2, inside = candidate(neighbours, periodic, x, nbr, i, k, prm, cells)
            if not inside:
                continue

With ``NEIGHBOUR_LISTS`` there is one span, row i's list (k indexes it); with ``CELL_WALK`` there
are ``cells.spans``, the cells around i's own (27, or 125 with cells of H / 2: grid.cell_span; k is
the row itself) and a candidate counts when
|x_ij|^2 < H^2 and j != i, the test the list builder applies. Both visit the same j in the same order.

A pass that needs only the mass-weighted kernel gradient m_j grad W_ij of each pair (the DFSPH
solver's passes, a dozen a step: every term they sum carries m_j grad W_ij) calls ``mass_gradient``
instead of ``candidate``: with the compile-time choice ``pair_gradients`` it reads m_j grad W_ij from
``grad_w``, where an earlier pass of the same step (the density pass, which has r_ij already) stored
it per list entry with ``store_gradient``. Reading three numbers replaces the separation, the square
root, the division and the kernel polynomial: a solver pass on the 3D dam break at 49 k particles
took a third to a half of the time (docs/BENCHMARKS.md). Storing it with the mass in replaces one
more gather, m_j, in every pass that reads it (a fifth to a third of a pass, BENCHMARKS). Both ways
give the same numbers: the stored value is the one ``mass_gradient`` would compute.
"""

import math

from numba import njit

from sphcore.grid import CELL_WALK, cell_span, home_cell, minimum_image
from sphcore.physics.kernels import pair_dw_dr_over_r
from sphcore.physics.real import like


@njit(cache=True, inline="always")
def separation(periodic, x, i, j, prm):
    """x_ij = x_i - x_j with the minimum-image convention on periodic axes (grid.minimum_image)."""
    dx = x[i, 0] - x[j, 0]
    dy = x[i, 1] - x[j, 1]
    dz = x[i, 2] - x[j, 2]
    if periodic:
        if prm.period_x > 0.0:
            dx = minimum_image(dx, prm.period_x)
        if prm.period_y > 0.0:
            dy = minimum_image(dy, prm.period_y)
        if prm.period_z > 0.0:
            dz = minimum_image(dz, prm.period_z)
    return dx, dy, dz


@njit(cache=True, inline="always")
def walk_start(neighbours, x, i, cells):
    """Row i's home cell, position and cell faces for the walk (grid.home_cell); a placeholder for
    lists."""
    if neighbours == CELL_WALK:
        return home_cell(x, i, cells)
    z = like(x, 0.0)  # the positions' type
    return 0, 0, 0, z, z, z, z, z, z


@njit(cache=True, inline="always")
def spans(neighbours, cells):
    """The number of row ranges a pass visits: the walk's cells (cells.spans), or one list."""
    return cells.spans if neighbours == CELL_WALK else 1


@njit(cache=True, inline="always")
def span_rows(neighbours, s, home, i, counts, cells, cell_begin, cell_end):
    """[lo, hi) of span s: the rows of the s-th cell of the walk, or the positions of row i's list."""
    if neighbours == CELL_WALK:
        return cell_span(s, home, cells, cell_begin, cell_end)
    return 0, counts[i]


@njit(cache=True, inline="always")
def candidate(neighbours, periodic, x, nbr, i, k, prm, cells):
    """(j, dx, dy, dz, r2, inside) of the k-th candidate of row i: x_ij and |x_ij|^2 (m^2); inside is
    whether j is a neighbour (always, for a list entry). The square root is left to the caller, for
    the candidates that are inside only."""
    j = k if neighbours == CELL_WALK else nbr[i, k]
    dx, dy, dz = separation(periodic, x, i, j, prm)
    r2 = dx * dx + dy * dy + dz * dz
    inside = True
    if neighbours == CELL_WALK:
        inside = r2 < cells.H2 and j != i
    return j, dx, dy, dz, r2, inside


@njit(cache=True, inline="always")
def computed_mass_gradient(kernel, m_j, dx, dy, dz, r2, prm):
    """m_j grad W_ij = (m_j dW/dr / r) x_ij for a separation x_ij = (dx, dy, dz) with |x_ij|^2 = r2
    inside the support; 0 for coincident particles (r = 0: no direction). The mass goes into the
    scalar: three products a pair, not six."""
    g = m_j * pair_dw_dr_over_r(kernel, r2, math.sqrt(r2), prm.H, prm.s_g)
    return g * dx, g * dy, g * dz


@njit(cache=True, inline="always")
def mass_gradient(neighbours, pair_gradients, kernel, periodic, x, m, nbr, grad_w, i, k, prm, cells):
    """(j, gx, gy, gz, inside) of the k-th candidate of row i: m_j grad W_ij (kg/m^4 in 3D) if j is a
    neighbour (inside). With ``pair_gradients`` (lists only) it is read from the k-th entry that
    ``store_gradient`` wrote this step; otherwise computed from the positions."""
    if pair_gradients:
        return nbr[i, k], grad_w[0, i, k], grad_w[1, i, k], grad_w[2, i, k], True
    j, dx, dy, dz, r2, inside = candidate(neighbours, periodic, x, nbr, i, k, prm, cells)
    if not inside:
        z = like(dx, 0.0)
        return j, z, z, z, False
    gx, gy, gz = computed_mass_gradient(kernel, m[j], dx, dy, dz, r2, prm)
    return j, gx, gy, gz, True


@njit(cache=True, inline="always")
def store_gradient(pair_gradients, grad_w, i, k, gx, gy, gz):
    """With ``pair_gradients``: keep m_j grad W_ij = (gx, gy, gz) of row i's k-th list entry for the
    step's later passes (mass_gradient)."""
    if pair_gradients:
        grad_w[0, i, k] = gx
        grad_w[1, i, k] = gy
        grad_w[2, i, k] = gz
