"""Analytic walls: signed distance, the kernel share behind a wall, and collision.

Boundaries are analytic primitives (planes, spheres, cylinders, boxes; ``sphcore.choices.WallKind``)
instead of boundary particles. Each primitive gives the signed distance d from a particle to the wall
(positive on the fluid side) and the unit normal n pointing into the fluid. Near a wall the kernel
support of particle i is cut; following the semi-analytical wall idea of Kulasegaram et al. 2004 and
Ferrand et al. 2013 (and the density maps of Koschier & Bender 2017), the missing part is treated as
fluid at rest beyond a locally flat wall:

    rho_i += rho0 * Phi(d_i),         Phi(d) = integral over the half-space beyond the wall of W
    a_i   += 2 max(p_i, 0) rho0 / rho_i^2 * |G(d_i)| n_i,
             G(d) = integral over that half-space of dW/dr * (normal component of x/r)

The second line is the symmetric pressure term of ``pressure.py`` with a mirrored neighbour (same
p and rho) integrated over the wall. Phi and G depend only on the kernel, the dimension and d/H;
they are tabulated once (``sphcore.boundaries.wall_tables``) and interpolated linearly.

As a last guard, a particle closer than ``wall_gap`` to a wall is put back to that distance, its
normal velocity reflected with restitution e and its tangential velocity reduced by the friction
factor. A particle found *behind* a wall (d < 0) after drifting counts as a leak.

Primitive data (one row of ``wall_data``, float, 16 entries): [0:3] a point (plane point, centre),
[3:6] plane normal, [6:15] rotation matrix local->world (row-major, cylinder/box), [15] radius.
Box obstacles keep half-extents in [3:6] (they have no plane normal).
"""
import math

from numba import njit


@njit(cache=True, inline="always")
def signed_distance(kind, wd, x, y, z):
    """(d, nx, ny, nz) for primitive ``kind`` with data row ``wd`` at point (x, y, z)."""
    one = 1.0
    if kind == 0:  # PLANE
        nx, ny, nz = wd[3], wd[4], wd[5]
        d = (x - wd[0]) * nx + (y - wd[1]) * ny + (z - wd[2]) * nz
        return d, nx * one, ny * one, nz * one
    rx = x - wd[0]
    ry = y - wd[1]
    rz = z - wd[2]
    if kind == 1 or kind == 3:  # SPHERE_INSIDE / SPHERE_OUTSIDE
        r = math.sqrt(rx * rx + ry * ry + rz * rz)
        if r > 0.0:
            ux, uy, uz = rx / r, ry / r, rz / r
        else:
            ux, uy, uz = 0.0 * one, one, 0.0 * one
        if kind == 1:
            return wd[15] - r, -ux, -uy, -uz
        return r - wd[15], ux, uy, uz
    # local coordinates l = R^T (x - c)
    lx = wd[6] * rx + wd[9] * ry + wd[12] * rz
    ly = wd[7] * rx + wd[10] * ry + wd[13] * rz
    lz = wd[8] * rx + wd[11] * ry + wd[14] * rz
    if kind == 2:  # CYLINDER_INSIDE, axis = local y
        rho = math.sqrt(lx * lx + lz * lz)
        if rho > 0.0:
            nlx, nly, nlz = -lx / rho, 0.0 * one, -lz / rho
        else:
            nlx, nly, nlz = one, 0.0 * one, 0.0 * one
        d = wd[15] - rho
    else:  # BOX_OUTSIDE, half extents wd[3:6]
        qx = abs(lx) - wd[3]
        qy = abs(ly) - wd[4]
        qz = abs(lz) - wd[5]
        sx = one if lx >= 0.0 else -one
        sy = one if ly >= 0.0 else -one
        sz = one if lz >= 0.0 else -one
        if qx > 0.0 or qy > 0.0 or qz > 0.0:
            ox, oy, oz = max(qx, 0.0), max(qy, 0.0), max(qz, 0.0)
            d = math.sqrt(ox * ox + oy * oy + oz * oz)
            nlx, nly, nlz = sx * ox / d, sy * oy / d, sz * oz / d
        else:  # inside the obstacle: the nearest face decides
            if qx >= qy and qx >= qz:
                d, nlx, nly, nlz = qx, sx, 0.0 * one, 0.0 * one
            elif qy >= qz:
                d, nlx, nly, nlz = qy, 0.0 * one, sy, 0.0 * one
            else:
                d, nlx, nly, nlz = qz, 0.0 * one, 0.0 * one, sz
    nx = wd[6] * nlx + wd[7] * nly + wd[8] * nlz
    ny = wd[9] * nlx + wd[10] * nly + wd[11] * nlz
    nz = wd[12] * nlx + wd[13] * nly + wd[14] * nlz
    return d, nx, ny, nz


@njit(cache=True, inline="always")
def table_lookup(table, d, H):
    """Linear interpolation of a wall table sampled on d in [0, H]; 0 beyond H, table[0] below 0."""
    if d >= H:
        return 0.0 * table[0]
    n = table.shape[0] - 1
    s = max(d, 0.0) / H * n
    k = min(int(s), n - 1)
    f = s - k
    return table[k] * (1.0 - f) + table[k + 1] * f


@njit(cache=True)
def min_wall_distance(kinds, data, x, out):
    """out[i] = min over walls of the signed distance of x[i] (used to carve initial particles)."""
    for i in range(x.shape[0]):
        best = 1.0e300
        for q in range(kinds.shape[0]):
            d, _, _, _ = signed_distance(kinds[q], data[q], x[i, 0], x[i, 1], x[i, 2])
            best = min(best, d)
        out[i] = best
