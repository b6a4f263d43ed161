"""The fluid's force and torque on a floating body as the surface integral of its traction
(``sph.body_force = "traction"``; the default, ``"reaction"``, is physics/bodies.py):

    F = sum_q t_q dS_q,   T = sum_q (s_q - c) x t_q dS_q,   t = -p n + mu (grad u + grad u^T) n

over quadrature points s_q of the body's surface (n the outward normal, into the fluid; dS_q the
patch each point stands for: ``surface_points``), with the pressure and the velocity gradient at s_q
from a weighted least-squares fit of the particles j within H of it (a linear moving-least-squares
interpolation: Dilts 1999; Marrone et al. 2011 take the values of their fixed ghost particles this
way), weights w_j = V_j W(|x_j - s_q|), V_j = m_j / rho_j, u_j = (x_j - s_q) / H:

    p_j ~ a_0 + a . u_j                  ->  p(s_q) = a_0
    v_j - u_w(s_q) ~ G u_j               ->  grad u = G / H   (no constant: the no-slip wall moves at u_w)

u_w(s) = U + Omega x (s - c), the body's velocity at s. The viscous part is there with a laminar
viscosity (Morris or Muller: mu = rho0 nu); with artificial viscosity the traction is the pressure's.

Why not the reaction. The reaction to the walls' push is the sum over the particles near the body
of sum_i 2 V_i G0(d_i) p_i n_i, a kernel-weighted estimate of the pressure on the surface that is exact
for a uniform pressure only while the particles sit in the wall lattice's arrangement. A settling
cylinder at Re 0.04 (docs/VALIDATION.md) showed the difference: under a uniform pressure that rose
from 19 to 138 Pa in a closed box, the reaction's pressure force on the body grew from 0.10 to 0.19
N/m, the traction's stayed at 0.105-0.107. A least-squares fit is exact for any linear field
whatever the arrangement, so a uniform pressure gives sum_q n_q dS_q p = 0 to the quadrature's
round-off, and the hydrostatic gradient exactly the buoyancy. With the difference form of the
pressure gradient (physics/pressure.py) the walls no longer push with the particles' pressure at
all, and the traction is the only estimate of the body's force there is. The price: the force is
not the reaction to what the body does to the fluid, so momentum is not conserved pair by pair.

**Dry and partly wet points.** phi = sum_j w_j is the fluid fraction (probes.py): about 0.5 on a
wetted face, 0.25 in a 2D corner. A point with phi < DRY_FRACTION reads the air's traction, 0; one
with phi < FIT_FRACTION (a few particles at the edge of its support: the waterline, spray) the
Shepard pressure sum_j w_j p_j / phi and no viscous part, since a fit on a sliver of support
extrapolates wildly; the others the fit (with a ridge of RIDGE phi on its gradient rows, far below
their own size, ~0.1 phi, against round-off in a degenerate arrangement).

**Across peers, bitwise.** Each peer sums its owned rows only, each pair's every moment rounded to
an integer number of quanta (MOMENT_QUANTUM of the dimensionless weight, of p / p_scale and of
(v - u_w) / v_scale), so the sums are int64 and their sum over peers (``PeerHalo.reduce_sums``) is
exact and independent of the order. Every peer then solves the same small systems from the same
integers in float64 (``traction_from_moments``: Gaussian elimination written out, compiled without
fastmath, no LAPACK whose kernels differ between machines) and moves the body by the same bits.

Moments per point (K = 23 int64): the 10 entries of A = sum w phi phi^T (phi = (1, u), upper
triangle, row by row), the 4 of b = sum w phi p / p_scale, the 9 of C[k][c] = sum w u_k (v_c - u_w,c)
/ v_scale (k, c = x, y, z). In 2D the z entries are 0 and the systems are solved on x, y.
"""
import math

import numpy as np
from numba import njit, prange

from sphcore.physics.kernels import w

MOMENTS = 23
MOMENT_QUANTUM = 2.0 ** -40  # one unit of every moment (they are dimensionless)
PAIR_CAP = 2.0 ** 50         # a pair's moment in units is clamped to this: a blown-up run saturates, never overflows
DRY_FRACTION = 0.05          # phi below this: the air's traction, 0 (as the pressure probes' dry rule)
FIT_FRACTION = 0.2           # phi below this: the Shepard pressure, no viscous part (no fit on a sliver)
RIDGE = 1.0e-9               # the fit's gradient rows + RIDGE phi: against round-off only
_UPPER = ((0, 0), (0, 1), (0, 2), (0, 3), (1, 1), (1, 2), (1, 3), (2, 2), (2, 3), (3, 3))


@njit(cache=True, inline="always")
def _units(value):
    r = max(min(value / MOMENT_QUANTUM, PAIR_CAP), -PAIR_CAP)
    if r >= 0.0:
        return np.int64(r + 0.5)
    return -np.int64(-r + 0.5)


@njit(cache=True, parallel=True)
def traction_moments(points, wall_velocity, rows, x, v, m, rho, p, kernel, H, s_w, p_scale, v_scale, out):
    """out[q, :] = the integer moments (module docstring) of surface point q over the rows ``rows``
    (a peer's owned rows near the body). Every pair's arithmetic is float64 and depends on that
    pair only: a row contributes the same bits whichever peer owns it."""
    for q in prange(points.shape[0]):
        sx, sy, sz = points[q, 0], points[q, 1], points[q, 2]
        for k in range(MOMENTS):
            out[q, k] = 0
        for t in range(rows.shape[0]):
            j = rows[t]
            ux = (np.float64(x[j, 0]) - sx) / H
            uy = (np.float64(x[j, 1]) - sy) / H
            uz = (np.float64(x[j, 2]) - sz) / H
            r = math.sqrt(ux * ux + uy * uy + uz * uz) * H
            if r >= H:
                continue
            wj = np.float64(m[j]) / np.float64(rho[j]) * w(kernel, r, H, s_w)
            phi = (1.0, ux, uy, uz)
            for e in range(10):
                a, b = _UPPER[e]
                out[q, e] += _units(wj * phi[a] * phi[b])
            pj = np.float64(p[j]) / p_scale
            for a in range(4):
                out[q, 10 + a] += _units(wj * phi[a] * pj)
            dv = ((np.float64(v[j, 0]) - wall_velocity[q, 0]) / v_scale,
                  (np.float64(v[j, 1]) - wall_velocity[q, 1]) / v_scale,
                  (np.float64(v[j, 2]) - wall_velocity[q, 2]) / v_scale)
            for a in range(3):
                for c in range(3):
                    out[q, 14 + 3 * a + c] += _units(wj * phi[a + 1] * dv[c])


@njit(cache=True)
def _solve(A, b, n):
    """x with A[:n, :n] x = b[:n, :] (b has columns), by Gaussian elimination with partial pivoting;
    A and b are overwritten. Plain float64 operations in a fixed order."""
    for col in range(n):
        best = col
        for r in range(col + 1, n):
            if abs(A[r, col]) > abs(A[best, col]):
                best = r
        if best != col:
            for c in range(n):
                A[col, c], A[best, c] = A[best, c], A[col, c]
            for c in range(b.shape[1]):
                b[col, c], b[best, c] = b[best, c], b[col, c]
        piv = A[col, col]
        for r in range(col + 1, n):
            f = A[r, col] / piv
            for c in range(col, n):
                A[r, c] -= f * A[col, c]
            for c in range(b.shape[1]):
                b[r, c] -= f * b[col, c]
    for col in range(n - 1, -1, -1):
        for c in range(b.shape[1]):
            s = b[col, c]
            for k in range(col + 1, n):
                s -= A[col, k] * b[k, c]
            b[col, c] = s / A[col, col]


@njit(cache=True)
def traction_from_moments(sums, points, normals, areas, centre, dim, H, p_scale, v_scale, mu):
    """(F, T, wet): the force (N; N/m in 2D) and torque about ``centre`` (N m; N) of the traction
    fitted from the global moments ``sums`` (Q, 23), and the number of wet points."""
    F = np.zeros(3)
    T = np.zeros(3)
    wet = 0
    A = np.zeros((4, 4))
    rhs = np.zeros((4, 3))
    for q in range(points.shape[0]):
        phi0 = sums[q, 0] * MOMENT_QUANTUM
        if phi0 < DRY_FRACTION:
            continue
        wet += 1
        for e in range(10):
            a, b = _UPPER[e]
            A[a, b] = sums[q, e] * MOMENT_QUANTUM
            A[b, a] = A[a, b]
        for a in range(1, dim + 1):
            A[a, a] += RIDGE * phi0
        fit = phi0 >= FIT_FRACTION
        if fit:  # the pressure: the full (dim + 1) system, its constant term
            B = A[: dim + 1, : dim + 1].copy()
            for a in range(dim + 1):
                rhs[a, 0] = sums[q, 10 + a] * MOMENT_QUANTUM
            bp = rhs[: dim + 1, :1].copy()
            _solve(B, bp, dim + 1)
            pressure = bp[0, 0] * p_scale
        else:  # Shepard
            pressure = sums[q, 10] * MOMENT_QUANTUM / phi0 * p_scale
        tx = -pressure * normals[q, 0]
        ty = -pressure * normals[q, 1]
        tz = -pressure * normals[q, 2]
        if mu > 0.0 and fit:  # the gradient block alone: v - u_w has no constant term at the wall
            G = A[1: dim + 1, 1: dim + 1].copy()
            bv = np.zeros((dim, dim))
            for a in range(dim):
                for c in range(dim):
                    bv[a, c] = sums[q, 14 + 3 * a + c] * MOMENT_QUANTUM
            _solve(G, bv, dim)
            grad = np.zeros((3, 3))  # grad[c, k] = d u_c / d x_k
            for a in range(dim):
                for c in range(dim):
                    grad[c, a] = bv[a, c] * v_scale / H
            for c in range(3):
                s = 0.0
                for k in range(3):
                    s += (grad[c, k] + grad[k, c]) * normals[q, k]
                if c == 0:
                    tx += mu * s
                elif c == 1:
                    ty += mu * s
                else:
                    tz += mu * s
        dS = areas[q]
        fx, fy, fz = tx * dS, ty * dS, tz * dS
        F[0] += fx
        F[1] += fy
        F[2] += fz
        rx = points[q, 0] - centre[0]
        ry = points[q, 1] - centre[1]
        rz = points[q, 2] - centre[2]
        T[0] += ry * fz - rz * fy
        T[1] += rz * fx - rx * fz
        T[2] += rx * fy - ry * fx
    return F, T, wet


# The most points a body's surface may take: every peer sends every other its moments of all of
# them each step (MOMENTS int64 a point: 46 MB at this limit), and fits each point on the host. A
# sphere of 140 spacings' radius in 3D reaches it; the scene refuses a larger body (scene.py).
MAX_SURFACE_POINTS = 250_000


def surface_point_count(shape: str, dim: int, radius: float, size, spacing: float) -> int:
    """About how many points ``surface_points`` puts on the body, without placing them (a scene with
    a huge body is refused before its points are made): exactly for a circle and a box; for a
    sphere within a few points (its rings' radii from the Gauss-Legendre nodes' asymptotic form,
    cos(pi (k + 3/4) / (rings + 1/2)), where the points use the nodes themselves)."""
    h = 0.5 * spacing
    if shape == "sphere":
        if dim == 2:
            return max(8, math.ceil(2.0 * math.pi * radius / h))
        rings = max(4, math.ceil(math.pi * radius / h))
        z = np.cos(math.pi * (np.arange(rings) + 0.75) / (rings + 0.5))
        per_ring = np.ceil(2.0 * math.pi * radius * np.sqrt(np.maximum(1.0 - z * z, 0.0)) / h)
        return int(np.maximum(per_ring, 4).sum())
    half = 0.5 * np.asarray(size[:3], dtype=np.float64)
    return sum(2 * math.prod(max(1, math.ceil(2.0 * half[a] / h)) for a in range(dim) if a != axis)
               for axis in range(dim))


def surface_points(shape: str, dim: int, radius: float, size, R: np.ndarray, spacing: float):
    """(points, normals, areas): quadrature points of a floating body's surface relative to its
    centre, as the scene places it (turned by R), about two per particle spacing along the surface;
    normals outward (into the fluid), areas the patch of each (m^2; m per metre of depth in 2D).
    A sphere: equal angles on the circle in 2D; in 3D rings at the Gauss-Legendre nodes in cos(theta),
    each with equal angles (a product rule: exact for the linear pressures and quadratic moments a
    buoyancy needs, which a Fibonacci lattice misses by ~1e-4); a box: the centres of equal patches of
    each face (edge in 2D)."""
    h = 0.5 * spacing
    if shape == "sphere":
        if dim == 2:
            n = max(8, math.ceil(2.0 * math.pi * radius / h))
            theta = (np.arange(n) + 0.5) * (2.0 * math.pi / n)
            normals = np.stack([np.cos(theta), np.sin(theta), np.zeros(n)], axis=1)
            areas = np.full(n, 2.0 * math.pi * radius / n)
        else:
            rings = max(4, math.ceil(math.pi * radius / h))
            z, weight = np.polynomial.legendre.leggauss(rings)  # in cos(theta): exact for degree <= 2 rings - 1
            parts, ars = [], []
            for k in range(rings):
                ring = math.sqrt(max(1.0 - z[k] * z[k], 0.0))
                count = max(4, math.ceil(2.0 * math.pi * radius * ring / h))
                angle = (np.arange(count) + 0.5 * (k % 2)) * (2.0 * math.pi / count)
                parts.append(np.stack([ring * np.cos(angle), ring * np.sin(angle), np.full(count, z[k])], axis=1))
                ars.append(np.full(count, radius * radius * weight[k] * 2.0 * math.pi / count))
            normals, areas = np.concatenate(parts), np.concatenate(ars)
        points = radius * normals
    else:
        half = 0.5 * np.asarray(size[:3], dtype=np.float64)
        pts, nrm, ars = [], [], []
        for axis in range(dim):
            others = [a for a in range(dim) if a != axis]
            counts = [max(1, math.ceil(2.0 * half[a] / h)) for a in others]
            grids = np.meshgrid(*[(np.arange(c) + 0.5) / c * 2.0 * half[a] - half[a] for c, a in zip(counts, others)],
                                indexing="ij")
            patch = float(np.prod([2.0 * half[a] / c for c, a in zip(counts, others)]))
            for sign in (-1.0, 1.0):
                p = np.zeros((grids[0].size, 3))
                for g, a in zip(grids, others):
                    p[:, a] = g.ravel()
                p[:, axis] = sign * half[axis]
                nv = np.zeros((p.shape[0], 3))
                nv[:, axis] = sign
                pts.append(p)
                nrm.append(nv)
                ars.append(np.full(p.shape[0], patch))
        points, normals, areas = np.concatenate(pts), np.concatenate(nrm), np.concatenate(ars)
    R = np.asarray(R, dtype=np.float64)
    return points @ R.T, normals @ R.T, areas
