"""Analytic walls: signed distance, the kernel share behind a wall, and collision.

Boundaries are analytic primitives (planes, spheres, cylinders, boxes; ``sphcore.choices.WallKind``)
instead of boundary particles. Each primitive gives the signed distance d from a particle to the wall
(positive on the fluid side) and the unit normal n pointing into the fluid. Near a wall the kernel
support of particle i is cut. In the spirit of semi-analytical walls (Kulasegaram et al. 2004,
Ferrand et al. 2013) and density maps (Koschier & Bender 2017), the missing part is filled with
*virtual* fluid: the continuation of the initial particle lattice beyond a locally flat wall (rows
at normal distances z = d + (k + 1/2) dx from the particle, lattice columns aligned with it), so a
particle of the initial lattice next to a wall sees exactly the bulk density. With u_j = x_j - x_i,
S the full-lattice kernel sum (mass m = rho0 / S) and virtual pressures extrapolated
hydrostatically, p_j = p_i + rho_i b . u_j (b = g + f_ext; Adami, Hu & Adams 2012, eq. 27):

    rho_i += rho0/S sum_virtual W(r_j)
    a_i   += rho0/(S rho_i^2) sum_virtual (2 p_i + rho_i b . u_j) W'(r_j) u_j / r_j

which is the symmetric pressure term of ``pressure.py`` summed over the virtual particles. For one
flat wall the sums reduce to tables of d (``sphcore.boundaries.wall_tables``):

    rho_i += rho0 Phi(d)
    a_i   += rho0/rho_i^2 (-2 p_i G0(d) n + rho_i (b_n G1(d) n + G2(d) b_t)),   b_n = b . n, b_t = b - b_n n

With the Morris viscosity a wall is also no-slip: the virtual particles move with
v_j = -(d_j / d_i) v_i (d_j their depth behind the wall; Morris, Fox & Zhu 1997, section 3.2), so
v_i - v_j = beta v_i, beta = min(3, z/d) (boundaries.BETA_MAX), and the Morris pair term summed over them is

    a_i += 2 mu / rho_i Gv(d) v_i          (``wall_viscosity``; Gv < 0: it drags towards rest)

Where the fluid side is not full — a free surface meeting a wall, a splash reaching it — there is
no fluid to continue behind the wall either. The wall terms are therefore scaled by the fill
fraction theta_i = min(1, rho_fluid_i / (rho0 - rho_wall_i)): the fluid-side density over what a
full lattice would give there (theta = 1 for the lattice at rest, so nothing changes in the bulk).

Where a particle is near two or three mutually perpendicular walls (edges and corners of a box,
the rim of a cylinder) the virtual regions overlap; inclusion-exclusion removes the overlap
(pair sums subtracted, the triple sum added back), each summed directly over its few virtual
points. The normal part of a wall's push is floored at zero: walls never pull.

As a last guard, a particle closer than ``wall_gap`` to a wall is put back to that distance, its
normal velocity reflected with restitution e and its tangential velocity reduced by the friction
factor. A particle found *behind* a wall (d < 0) after drifting counts as a leak.

Primitive data (one row of ``wall_data``, float, 16 entries): [0:3] a point (plane point, centre),
[3:6] plane normal, [6:15] rotation matrix local->world (row-major, cylinder/box), [15] radius.
Box obstacles keep half-extents in [3:6] (they have no plane normal). A mesh obstacle's row goes on
with its signed distance grid ([16:] as laid out in ``sphcore.mesh_sdf``), and every row of the
table is then that long (zero padded).
"""
import math

from numba import njit

from sphcore.grid import home_cell
from sphcore.physics.kernels import dw_dr, w
from sphcore.physics.real import like


@njit(cache=True, inline="always")
def _mesh_distance(wd, x, y, z):
    """Trilinear signed distance of a mesh obstacle's grid (sphcore.mesh_sdf layout) and the unit
    gradient of the interpolant as the normal; far outside the grid: no wall."""
    one = like(x, 1.0)
    inv = wd[19]
    nx, ny, nz = int(wd[20]), int(wd[21]), int(wd[22])
    fx = (x - wd[16]) * inv
    fy = (y - wd[17]) * inv
    fz = (z - wd[18]) * inv
    if fx < 0.0 or fy < 0.0 or fz < 0.0 or fx > like(fx, nx - 1) or fy > like(fy, ny - 1) or fz > like(fz, nz - 1):
        return like(one, 1.0e6), like(one, 0.0), one, like(one, 0.0)
    i = min(int(fx), nx - 2)
    j = min(int(fy), ny - 2)
    k = min(int(fz), nz - 2)
    tx, ty, tz = fx - like(fx, i), fy - like(fy, j), fz - like(fz, k)
    b = 24 + (k * ny + j) * nx + i
    c000, c100 = wd[b], wd[b + 1]
    c010, c110 = wd[b + nx], wd[b + nx + 1]
    c001, c101 = wd[b + nx * ny], wd[b + nx * ny + 1]
    c011, c111 = wd[b + nx * ny + nx], wd[b + nx * ny + nx + 1]
    d00 = c000 + tx * (c100 - c000)
    d10 = c010 + tx * (c110 - c010)
    d01 = c001 + tx * (c101 - c001)
    d11 = c011 + tx * (c111 - c011)
    d0 = d00 + ty * (d10 - d00)
    d1 = d01 + ty * (d11 - d01)
    d = d0 + tz * (d1 - d0)
    gx = ((one - ty) * (one - tz) * (c100 - c000) + ty * (one - tz) * (c110 - c010)
          + (one - ty) * tz * (c101 - c001) + ty * tz * (c111 - c011))
    gy = (one - tz) * (d10 - d00) + tz * (d11 - d01)
    gz = d1 - d0
    g = math.sqrt(gx * gx + gy * gy + gz * gz)
    if g > 0.0:
        return d, gx / g, gy / g, gz / g
    return d, like(one, 0.0), one, like(one, 0.0)


@njit(cache=True, inline="always")
def signed_distance(kind, wd, x, y, z):
    """(d, nx, ny, nz) for primitive ``kind`` with data row ``wd`` at point (x, y, z)."""
    one = like(x, 1.0)
    if kind == 5:  # MESH_OUTSIDE
        return _mesh_distance(wd, x, y, z)
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
            ux, uy, uz = like(one, 0.0), one, like(one, 0.0)
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
            nlx, nly, nlz = -lx / rho, like(one, 0.0), -lz / rho
        else:
            nlx, nly, nlz = one, like(one, 0.0), like(one, 0.0)
        d = wd[15] - rho
    else:  # BOX_OUTSIDE, half extents wd[3:6]
        qx = abs(lx) - wd[3]
        qy = abs(ly) - wd[4]
        qz = abs(lz) - wd[5]
        sx = one if lx >= 0.0 else -one
        sy = one if ly >= 0.0 else -one
        sz = one if lz >= 0.0 else -one
        if qx > 0.0 or qy > 0.0 or qz > 0.0:
            ox, oy, oz = max(qx, like(qx, 0.0)), max(qy, like(qy, 0.0)), max(qz, like(qz, 0.0))
            d = math.sqrt(ox * ox + oy * oy + oz * oz)
            nlx, nly, nlz = sx * ox / d, sy * oy / d, sz * oz / d
        else:  # inside the obstacle: the nearest face decides
            if qx >= qy and qx >= qz:
                d, nlx, nly, nlz = qx, sx, like(one, 0.0), like(one, 0.0)
            elif qy >= qz:
                d, nlx, nly, nlz = qy, like(one, 0.0), sy, like(one, 0.0)
            else:
                d, nlx, nly, nlz = qz, like(one, 0.0), like(one, 0.0), sz
    nx = wd[6] * nlx + wd[7] * nly + wd[8] * nlz
    ny = wd[9] * nlx + wd[10] * nly + wd[11] * nlz
    nz = wd[12] * nlx + wd[13] * nly + wd[14] * nlz
    return d, nx, ny, nz


@njit(cache=True, inline="always")
def near_wall(cells, wall_near, x, i):
    """Whether row i's grid cell is flagged as within reach of a wall (boundaries.near_wall_cells):
    elsewhere every wall term is zero, and the passes skip them."""
    ix, iy, iz, _, _, _, _, _, _ = home_cell(x, i, cells)
    return wall_near[(iz * cells.ny + iy) * cells.nx + ix] != 0


@njit(cache=True, inline="always")
def table_lookup(table, d, end):
    """Linear interpolation of a wall table sampled on d in [0, end]; 0 beyond, table[0] below 0."""
    if d >= end:
        return like(table, 0.0)
    n = table.shape[0] - 1
    s = max(d, like(d, 0.0)) / end * like(d, n)
    k = min(int(s), n - 1)
    f = s - like(s, k)
    return table[k] * (like(f, 1.0) - f) + table[k + 1] * f


@njit(cache=True, nogil=True)
def min_wall_distance(kinds, data, x, out):
    """out[i] = min over walls of the signed distance of x[i] (used to carve initial particles; nogil:
    a large block's slabs are carved on several threads)."""
    for i in range(x.shape[0]):
        best = 1.0e300
        for q in range(kinds.shape[0]):
            d, _, _, _ = signed_distance(kinds[q], data[q], x[i, 0], x[i, 1], x[i, 2])
            best = min(best, d)
        out[i] = best


@njit(cache=True)
def _corner_sums(kernel, prm, want_force, na, nb, nc, da, db, dc, triple, coef_p, bx, by, bz):
    """Sums over the virtual points beyond walls a and b (and c if ``triple``), see module docstring.

    Returns (sum W, fx, fy, fz) with f = sum (coef_p + b . u) W' u / r; walls are given by their
    distances d and unit normals n (tuples). The lateral axis of a pair is e = n_a x n_b.
    """
    dx = prm.dx
    K = int(prm.H / dx) + 1
    ex = na[1] * nb[2] - na[2] * nb[1]
    ey = na[2] * nb[0] - na[0] * nb[2]
    ez = na[0] * nb[1] - na[1] * nb[0]
    m_lo = 0
    m_hi = 0
    if prm.dim3 and not triple:
        m_lo = -K
        m_hi = K
    sw = like(dx, 0.0)
    fx = like(dx, 0.0)
    fy = like(dx, 0.0)
    fz = like(dx, 0.0)
    for k in range(K + 1):
        za = da + (like(dx, k) + like(dx, 0.5)) * dx
        for l in range(K + 1):
            zb = db + (like(dx, l) + like(dx, 0.5)) * dx
            for m in range(m_lo, m_hi + 1) if not triple else range(K + 1):
                if triple:
                    zc = dc + (like(dx, m) + like(dx, 0.5)) * dx
                    ux = -za * na[0] - zb * nb[0] - zc * nc[0]
                    uy = -za * na[1] - zb * nb[1] - zc * nc[1]
                    uz = -za * na[2] - zb * nb[2] - zc * nc[2]
                else:
                    zm = like(dx, m) * dx
                    ux = -za * na[0] - zb * nb[0] + zm * ex
                    uy = -za * na[1] - zb * nb[1] + zm * ey
                    uz = -za * na[2] - zb * nb[2] + zm * ez
                r = math.sqrt(ux * ux + uy * uy + uz * uz)
                if r >= prm.H:
                    continue
                if want_force:
                    c = (coef_p + bx * ux + by * uy + bz * uz) * dw_dr(kernel, r, prm.H, prm.s_g) / r
                    fx += c * ux
                    fy += c * uy
                    fz += c * uz
                else:
                    sw += w(kernel, r, prm.H, prm.s_w)
    return sw, fx, fy, fz


@njit(cache=True)
def _perpendicular(n1, n2):
    c = n1[0] * n2[0] + n1[1] * n2[1] + n1[2] * n2[2]
    return abs(c) < like(c, 1.0e-6)


@njit(cache=True, inline="always")
def wall_point_velocity(motion, q, x, y, z):
    """u(r) = u_w + Omega x (r - P) of wall q at the point r = (x, y, z) (motion.py)."""
    rx, ry, rz = x - motion[q, 12], y - motion[q, 13], z - motion[q, 14]
    wx, wy, wz = motion[q, 6], motion[q, 7], motion[q, 8]
    return (motion[q, 0] + (wy * rz - wz * ry), motion[q, 1] + (wz * rx - wx * rz),
            motion[q, 2] + (wx * ry - wy * rx))


@njit(cache=True, inline="always")
def wall_point_acceleration(motion, q, x, y, z):
    """a(r) = a_w + alpha x (r - P) + Omega x (Omega x (r - P)) of wall q at r (motion.py)."""
    rx, ry, rz = x - motion[q, 12], y - motion[q, 13], z - motion[q, 14]
    wx, wy, wz = motion[q, 6], motion[q, 7], motion[q, 8]
    ex, ey, ez = motion[q, 9], motion[q, 10], motion[q, 11]
    cx, cy, cz = wy * rz - wz * ry, wz * rx - wx * rz, wx * ry - wy * rx  # Omega x r
    return (motion[q, 3] + (ey * rz - ez * ry) + (wy * cz - wz * cy),
            motion[q, 4] + (ez * rx - ex * rz) + (wz * cx - wx * cz),
            motion[q, 5] + (ex * ry - ey * rx) + (wx * cy - wy * cx))


@njit(cache=True)
def wall_terms(kernel, prm, want_force, kinds, data, tables, motion, frame, x, y, z, p_i, rho_i, bx, by, bz):
    """Wall contributions at (x, y, z): (delta rho, ax, ay, az) — density share when ``want_force``
    is false, pressure acceleration when true (module docstring). With ``frame`` the pressure behind
    a moving wall is extrapolated with the body force in the wall's frame, b - a_w (``motion[q, 3:6]``;
    Adami et al. 2012, eq. 27); where walls meet, the corner correction uses the first near wall's
    frame. (Without ``frame``, ``motion`` is not read: the purely geometric push of
    ``wall_density_gradient``.)"""
    H = prm.H
    drho = like(H, 0.0)
    ax = like(H, 0.0)
    ay = like(H, 0.0)
    az = like(H, 0.0)
    near = 0
    d1 = d2 = d3 = H
    n1 = n2 = n3 = (like(H, 0.0), like(H, 0.0), like(H, 0.0))
    cx = bx
    cy = by
    cz = bz
    for q in range(kinds.shape[0]):
        d, nx, ny, nz = signed_distance(kinds[q], data[q], x, y, z)
        if d >= H:
            continue
        if want_force:
            qx = bx
            qy = by
            qz = bz
            if frame:  # the wall's acceleration at its point nearest the particle
                awx, awy, awz = wall_point_acceleration(motion, q, x - d * nx, y - d * ny, z - d * nz)
                qx -= awx
                qy -= awy
                qz -= awz
            b_n = qx * nx + qy * ny + qz * nz
            push = prm.rho0 / (rho_i * rho_i) * (like(p_i, -2.0) * p_i * table_lookup(tables[1], d, prm.wall_table_end)
                                                  + rho_i * b_n * table_lookup(tables[2], d, prm.wall_table_end))
            if push > 0.0:
                ax += push * nx
                ay += push * ny
                az += push * nz
            g2 = prm.rho0 / rho_i * table_lookup(tables[3], d, prm.wall_table_end)
            ax += g2 * (qx - b_n * nx)
            ay += g2 * (qy - b_n * ny)
            az += g2 * (qz - b_n * nz)
            if near == 0:
                cx, cy, cz = qx, qy, qz
        else:
            drho += prm.rho0 * table_lookup(tables[0], d, prm.wall_table_end)
        if near == 0:
            d1, n1 = d, (nx, ny, nz)
        elif near == 1:
            d2, n2 = d, (nx, ny, nz)
        elif near == 2:
            d3, n3 = d, (nx, ny, nz)
        near += 1
    if near < 2:
        return drho, ax, ay, az
    # inclusion-exclusion over perpendicular pairs (and the triple) of the first three near walls
    coef = like(p_i, 2.0) * p_i / rho_i
    scale_f = prm.rho0 * prm.inv_s / rho_i
    for pair in range(3):
        if pair == 0:
            da, na, db, nb = d1, n1, d2, n2
        elif pair == 1:
            if near < 3:
                break
            da, na, db, nb = d1, n1, d3, n3
        else:
            da, na, db, nb = d2, n2, d3, n3
        if not _perpendicular(na, nb):
            continue
        sw, fx, fy, fz = _corner_sums(kernel, prm, want_force, na, nb, nb, da, db, db, False, coef, cx, cy, cz)
        drho -= prm.rho0 * prm.inv_s * sw
        ax -= scale_f * fx
        ay -= scale_f * fy
        az -= scale_f * fz
    if near >= 3 and prm.dim3 and _perpendicular(n1, n2) and _perpendicular(n1, n3) and _perpendicular(n2, n3):
        sw, fx, fy, fz = _corner_sums(kernel, prm, want_force, n1, n2, n3, d1, d2, d3, True, coef, cx, cy, cz)
        drho += prm.rho0 * prm.inv_s * sw
        ax += scale_f * fx
        ay += scale_f * fy
        az += scale_f * fz
    return drho, ax, ay, az


@njit(cache=True, inline="always")
def wall_difference_terms(prm, kinds, data, tables, motion, x, y, z, rho_i, bx, by, bz):
    """The walls' share of the corrected difference form (physics/pressure.py): their hydrostatic
    push q = (rho0 / rho_i)(b_n G1 n + G2 b_t) (the difference sum over the virtual lattice, b in each
    wall's frame, b - a_w) and their gradient moment B_v = -(rho0 / rho_i)(G1 n n + G2 (I - n n)),
    summed over the near walls without the corner correction (where virtual regions overlap both
    count it twice, consistently: B^-1 q stays exact for a linear pressure). Returns
    (qx, qy, qz, Bxx, Bxy, Bxz, Byy, Byz, Bzz)."""
    H = prm.H
    zero = like(H, 0.0)
    qx = qy = qz = zero
    bxx = bxy = bxz = byy = byz = bzz = zero
    c = prm.rho0 / rho_i
    for q in range(kinds.shape[0]):
        d, nx, ny, nz = signed_distance(kinds[q], data[q], x, y, z)
        if d >= H:
            continue
        awx, awy, awz = wall_point_acceleration(motion, q, x - d * nx, y - d * ny, z - d * nz)
        ex = bx - awx
        ey = by - awy
        ez = bz - awz
        g1 = c * table_lookup(tables[2], d, prm.wall_table_end)
        g2 = c * table_lookup(tables[3], d, prm.wall_table_end)
        b_n = ex * nx + ey * ny + ez * nz
        qx += g1 * b_n * nx + g2 * (ex - b_n * nx)
        qy += g1 * b_n * ny + g2 * (ey - b_n * ny)
        qz += g1 * b_n * nz + g2 * (ez - b_n * nz)
        dg = g2 - g1  # -(G1 n n + G2 (I - n n)) = -G2 I + (G2 - G1) n n
        bxx += dg * nx * nx - g2
        bxy += dg * nx * ny
        bxz += dg * nx * nz
        byy += dg * ny * ny - g2
        byz += dg * ny * nz
        bzz += dg * nz * nz - g2
    return qx, qy, qz, bxx, bxy, bxz, byy, byz, bzz


@njit(cache=True)
def wall_viscosity(prm, kinds, data, tables, motion, x, y, z, rho_i):
    """(k, ux, uy, uz) such that the no-slip wall drag is a_i += k v_i - u: k = 2 mu / rho_i sum over
    near walls q of Gv(d_q), u = 2 mu / rho_i sum Gv(d_q) u_w,q (module docstring: behind a wall
    moving at u_w the virtual fluid moves at u_w - beta (v_i - u_w), so v_i - v_j = beta (v_i - u_w));
    zeros away from walls."""
    k = like(prm.H, 0.0)
    ux = like(prm.H, 0.0)
    uy = like(prm.H, 0.0)
    uz = like(prm.H, 0.0)
    for q in range(kinds.shape[0]):
        d, nx, ny, nz = signed_distance(kinds[q], data[q], x, y, z)
        if d < prm.H:
            gv = table_lookup(tables[4], d, prm.wall_table_end)
            k += gv
            uwx, uwy, uwz = wall_point_velocity(motion, q, x - d * nx, y - d * ny, z - d * nz)  # at its nearest point
            ux += gv * uwx
            uy += gv * uwy
            uz += gv * uwz
    c = like(k, 2.0) * prm.mu / rho_i
    return c * k, c * ux, c * uy, c * uz


@njit(cache=True, inline="always")
def fill_fraction(rho_fluid, rho_wall, rho0):
    """theta = min(1, rho_fluid / (rho0 - rho_wall)): how full the fluid side of a wall particle is."""
    expected = rho0 - rho_wall
    if rho_wall <= 0.0 or expected <= 0.0:
        return like(rho0, 1.0)
    return min(rho_fluid / expected, like(rho0, 1.0))


@njit(cache=True, inline="always")
def wall_density_gradient(kernel, prm, wall_kind, wall_data, wall_tables, x, i, rho_i, theta):
    """g_i^wall = grad_i of the wall's density share theta rho0 Phi(d_i): the walls' pressure push at
    p_i = rho_i^2 / 2 without body force is -sum_virtual m grad W = -g_i^wall / theta.   (walls.py)"""
    # geometry only: no frame, so the motion argument (here wall_tables) is not read
    _, fx, fy, fz = wall_terms(kernel, prm, True, wall_kind, wall_data, wall_tables, wall_tables, False,
                               x[i, 0], x[i, 1], x[i, 2], like(rho_i, 0.5) * rho_i * rho_i, rho_i, like(rho_i, 0.0),
                               like(rho_i, 0.0), like(rho_i, 0.0))
    return -theta * fx, -theta * fy, -theta * fz


@njit(cache=True, inline="always")
def moving_wall_rate(kernel, prm, wall_kind, wall_data, wall_tables, wall_motion, x, i, rho_i, theta):
    """sum over the moving walls q of g_i^q . u_q: how fast the walls' density share at row i grows
    because the walls move (u_q their velocity, g_i^q the gradient of wall q's share alone, as in
    ``wall_density_gradient``); 0 for walls at rest, which cost only the test of their velocity."""
    rate = like(rho_i, 0.0)
    for q in range(wall_kind.shape[0]):
        ux, uy, uz = wall_motion[q, 0], wall_motion[q, 1], wall_motion[q, 2]
        turning = wall_motion[q, 6] != 0.0 or wall_motion[q, 7] != 0.0 or wall_motion[q, 8] != 0.0
        if ux == 0.0 and uy == 0.0 and uz == 0.0 and not turning:
            continue
        if turning:  # a turning wall's velocity at its point nearest row i
            d, nx, ny, nz = signed_distance(wall_kind[q], wall_data[q], x[i, 0], x[i, 1], x[i, 2])
            ux, uy, uz = wall_point_velocity(wall_motion, q, x[i, 0] - d * nx, x[i, 1] - d * ny, x[i, 2] - d * nz)
        gx, gy, gz = wall_density_gradient(kernel, prm, wall_kind[q:q + 1], wall_data[q:q + 1], wall_tables, x, i,
                                           rho_i, theta)
        rate += gx * ux + gy * uy + gz * uz
    return rate


@njit(cache=True)
def flag_near_cells(kinds, data, origin, cell, ncell, reach, near):
    """near[c] = 0 for every cell c off the grid's outer layer that no wall reaches within ``reach`` of
    its centre plus its half-diagonal (boundaries.near_wall_cells says why; the rest stay 1)."""
    nx, ny, nz = ncell[0], ncell[1], ncell[2]
    half = 0.5 * math.sqrt(cell[0] ** 2 + cell[1] ** 2 + cell[2] ** 2)
    for c in range(nx * ny * nz):
        ix, iy, iz = c % nx, (c // nx) % ny, c // (nx * ny)
        if ((nx > 1 and (ix == 0 or ix == nx - 1)) or (ny > 1 and (iy == 0 or iy == ny - 1))
                or (nz > 1 and (iz == 0 or iz == nz - 1))):
            continue  # the outer layer stays flagged
        cx = origin[0] + (ix + 0.5) * cell[0]
        cy = origin[1] + (iy + 0.5) * cell[1]
        cz = origin[2] + (iz + 0.5) * cell[2]
        flag = 0
        for q in range(kinds.shape[0]):
            wd = data[q]
            if kinds[q] == 5:  # MESH_OUTSIDE: its distance grid (sphcore.mesh_sdf layout), grown by H
                span = 1.0 / wd[19]
                inside = True
                for d in range(3):
                    centre = cx if d == 0 else (cy if d == 1 else cz)
                    lo = wd[16 + d] - reach
                    hi = wd[16 + d] + (wd[20 + d] - 1.0) * span + reach
                    if centre + 0.5 * cell[d] < lo or centre - 0.5 * cell[d] > hi:
                        inside = False
                if inside:
                    flag = 1
                    break
            elif signed_distance(kinds[q], wd, cx, cy, cz)[0] - half < reach:
                flag = 1
                break
        near[c] = flag
