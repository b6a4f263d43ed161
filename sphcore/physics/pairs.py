"""What every neighbour pass shares: row i's k-th neighbour j, the separation x_ij = x_i - x_j of
the pair (minimum image on periodic axes, grid.minimum_image) and its length."""

import math

from numba import njit

from sphcore.grid import minimum_image


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
def neighbour(periodic, x, nbr, i, k, prm):
    """(j, dx, dy, dz, r2, r) of row i's k-th neighbour j: x_ij = x_i - x_j, |x_ij|^2 and |x_ij| (m)."""
    j = nbr[i, k]
    dx, dy, dz = separation(periodic, x, i, j, prm)
    r2 = dx * dx + dy * dy + dz * dz
    return j, dx, dy, dz, r2, math.sqrt(r2)
