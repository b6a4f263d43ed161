"""Turn a scene's container, planes and obstacles into wall primitives for the drivers.

Produces ``Walls``: ``kind`` (nw,) int32 codes (``WallKind``), ``data`` (nw, 16) float rows in the
layout documented in ``sphcore.physics.walls``, the tables Phi(d) and G(d) of the run's kernel, and
the axis-aligned bounds of the domain (which the global grid covers).

A box container becomes six planes (the faces along periodic axes are dropped), a cylinder its
lateral surface plus two cap planes, a sphere one spherical wall. Treating faces as separate planes
makes corners see both walls' share of the kernel.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sphcore.choices import Kernel, WallKind
from sphcore.motion import FloatingBody, Motion, inertia_tensor, matmul3, matvec3, rotation_matrix
from sphcore.physics.kernels import dw_dr, kernel_constants, w
from sphcore.physics.damping import DAMPING_COLUMNS
from sphcore.physics.open_boundary import ZONE_COLUMNS, ZONE_FAR, ZONE_INLET, ZONE_NONE, ZONE_OUTLET
from sphcore.physics.traction import surface_points
from sphcore.physics.walls import flag_near_cells
from sphcore.scene import Scene, SceneError


MOTION_COLUMNS = 15  # Walls.motion: u_w, a_w, Omega, alpha, P(t)


@dataclass
class Walls:
    kind: np.ndarray        # (nw,) int32
    data: np.ndarray        # (nw, 16+) float: the rows at the current time (moving walls displaced)
    tables: np.ndarray      # (5, nt): Phi(d), G0(d), G1(d), G2(d), Gv(d) on d in [0, H] (wall_tables)
    lo: np.ndarray          # (3,) lower corner of the domain's bounding box
    hi: np.ndarray          # (3,) upper corner
    container_walls: int    # the first walls belong to the container
    motion: np.ndarray      # (nw, 15) float, now: each wall's velocity u_w [0:3] (m/s) and acceleration a_w [3:6]
                            # (m/s^2) at its pivot, angular velocity Omega [6:9] (rad/s) and acceleration alpha
                            # [9:12] (rad/s^2), the pivot P(t) [12:15] (m) (motion.py; physics/walls.py reads them)
    moves: tuple = ()       # (wall row, motion.Motion or motion.FloatingBody) of the walls that move
    rest: np.ndarray | None = None  # (nw, 16+) float64: the rows at t = 0
    zones: np.ndarray | None = None  # (nz, 10) float: inlet and outlet zones (physics/open_boundary.py)
    damping: np.ndarray | None = None  # (nd, 10) float: damping zones (physics/damping.py)
    near: np.ndarray | None = None   # (grid cells,) uint8: 1 where a wall may be within H (near_wall_cells)
    t: float = math.nan     # the time the rows and motion are at (s); none yet: moved before the first step

    # what changes as the walls move: not the walls' definition (Simulation's _same compares the rest)
    STATE = ("data", "motion", "t")

    @property
    def bodies(self) -> list:
        """The floating bodies (motion.FloatingBody), in wall order."""
        return [m for _, m in self.moves if isinstance(m, FloatingBody)]

    def at(self, t: float) -> bool:
        """Move the walls to time ``t`` (sphcore/motion.py; floating bodies: to their current state):
        their rows and velocities; False if no wall moves or they are there already."""
        if not self.moves or self.t == t:
            return False
        self.t = t
        for q, motion in self.moves:
            shift = motion.displacement(t)
            row = self.rest[q].copy()
            pivot = row[0:3] + motion.pivot
            if motion.rotates:  # turn the geometry about the pivot (motion.py): its point, then its axes
                R = motion.rotation(t)
                row[0:3] = pivot + matvec3(R, row[0:3] - pivot)
                if self.kind[q] == WallKind.PLANE:
                    row[3:6] = matvec3(R, row[3:6])
                elif self.kind[q] in (WallKind.BOX_OUTSIDE, WallKind.CYLINDER_INSIDE):
                    row[6:15] = matmul3(R, row[6:15].reshape(3, 3)).ravel()
            row[0:3] += shift
            if self.kind[q] == WallKind.MESH_OUTSIDE:
                row[16:19] += shift  # the distance grid's origin (sphcore.mesh_sdf layout)
            self.data[q] = row
            self.motion[q, 0:3] = motion.wall_velocity(t)
            self.motion[q, 3:6] = motion.wall_acceleration(t)
            self.motion[q, 6:9] = motion.angular_velocity(t)
            self.motion[q, 9:12] = motion.angular_acceleration(t)
            self.motion[q, 12:15] = pivot + shift
        return True


def _row(point=(0, 0, 0), normal=(0, 0, 0), R=np.eye(3), radius=0.0, half=None):
    row = np.zeros(16)
    row[0:3] = point
    row[3:6] = normal if half is None else half
    row[6:15] = np.asarray(R).reshape(9)
    row[15] = radius
    return row


def container_frame(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """(centre, R) of the container: local coordinates map to centre + R @ local."""
    dom = scene.domain
    return np.array(dom.center, dtype=float), rotation_matrix(dom.rotation)


def _zone_bounds(scene: Scene, z) -> tuple[list, list]:
    """A zone's box as 3 lower and 3 upper bounds (m): an axis beyond the scene's dimension spans
    (-ZONE_FAR, ZONE_FAR)."""
    lo = [z.min[d] if d < scene.dim else -ZONE_FAR for d in range(3)]
    hi = [z.max[d] if d < scene.dim else ZONE_FAR for d in range(3)]
    return lo, hi


def zone_rows(scene: Scene, dtype) -> np.ndarray:
    """The [[inlets]] and [[outlets]] as wall_zones rows (physics/open_boundary.py); one padding row
    (kind 0) when there are none, so that every backend has an array to pass."""
    rows = []
    for kind, zones in ((ZONE_INLET, scene.inlets), (ZONE_OUTLET, scene.outlets)):
        for z in zones:
            lo, hi = _zone_bounds(scene, z)
            rows.append([kind, *lo, *hi, *(z.velocity if kind == ZONE_INLET else (z.pressure, 0.0, 0.0))])
    return np.array(rows or [[ZONE_NONE] + [0.0] * (ZONE_COLUMNS - 1)], dtype=dtype).reshape(-1, ZONE_COLUMNS)


def damping_rows(scene: Scene, dtype) -> np.ndarray:
    """The [[damping_zones]] as wall_damping rows (physics/damping.py); one padding row (rate 0, an
    empty box) when there are none, so that every backend has an array to pass."""
    rows = []
    for z in scene.damping_zones:
        axis = next(d for d in range(scene.dim) if z.direction[d] != 0.0)
        start, end = (z.min[axis], z.max[axis]) if z.direction[axis] > 0.0 else (z.max[axis], z.min[axis])
        lo, hi = _zone_bounds(scene, z)
        rows.append([*lo, *hi, start, 1.0 / (end - start), axis, z.rate])
    return np.array(rows or [[0.0] * DAMPING_COLUMNS], dtype=dtype).reshape(-1, DAMPING_COLUMNS)


def build_walls(scene: Scene, kernel: Kernel, H: float, dtype) -> Walls:
    dx = scene.particles.spacing
    dom = scene.domain
    c, R = container_frame(scene)
    s = dom.scale
    kinds, rows, moving = [], [], []
    corners = []
    if dom.container == "box":
        half = 0.5 * np.array(dom.size) * s
        if scene.dim == 2:
            half[2] = 0.0
        for axis in range(scene.dim):
            if dom.periodic[axis]:
                continue
            for sign in (-1.0, 1.0):
                n_local = np.zeros(3)
                n_local[axis] = -sign  # normal points inwards
                p_local = np.zeros(3)
                p_local[axis] = sign * half[axis]
                kinds.append(WallKind.PLANE)
                rows.append(_row(point=c + R @ p_local, normal=R @ n_local))
        for corner in np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T:
            corners.append(c + R @ (corner * half))
    elif dom.container == "sphere":
        r = dom.radius * s
        kinds.append(WallKind.SPHERE_INSIDE)
        rows.append(_row(point=c, radius=r))
        ext = np.array([r, r, r if scene.dim == 3 else 0.0])
        corners += [c - ext, c + ext]
    elif dom.container == "cylinder":
        r = 0.5 * dom.size[0] * s
        half_h = 0.5 * dom.size[1] * s
        kinds.append(WallKind.CYLINDER_INSIDE)
        rows.append(_row(point=c, R=R, radius=r))
        axis = R @ np.array([0.0, 1.0, 0.0])
        for sign in (-1.0, 1.0):
            kinds.append(WallKind.PLANE)
            rows.append(_row(point=c + sign * half_h * axis, normal=-sign * axis))
        for corner in np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T:
            corners.append(c + R @ (corner * np.array([r, half_h, r])))
    else:  # none: bounds given explicitly
        corners += [np.array(dom.bounds_min, dtype=float), np.array(dom.bounds_max, dtype=float)]
    n_container = len(kinds)
    flat = [(r[0:3], r[3:6]) for k, r in zip(kinds, rows) if k == WallKind.PLANE]  # (point, normal) of each plane
    for i, pl in enumerate(dom.planes):
        nrm = np.array(pl.normal, dtype=float)
        nrm = nrm / math.hypot(*nrm)  # hypot: a normal of 1e-300 has a direction, np.linalg.norm's square lost it
        point = np.array(pl.point, dtype=float)
        for q, (p_other, n_other) in enumerate(flat):
            # the same plane twice pushes the fluid twice (a plane on the box's floor: 70 x the compression)
            if float(nrm @ n_other) > 1.0 - 1e-9 and abs(float(nrm @ (point - p_other))) <= 1e-6 * dx:
                what = "a wall of the container" if q < len(flat) - i else f"domain.planes[{q - (len(flat) - i)}]"
                raise SceneError(f"domain.planes[{i}]: point = {list(pl.point[: scene.dim])!r}, normal = "
                                 f"{list(pl.normal[: scene.dim])!r} is {what} again (a wall counted twice pushes twice)")
        flat.append((point, nrm))
        moving.append((len(kinds), Motion.of(pl)))
        kinds.append(WallKind.PLANE)
        rows.append(_row(point=pl.point, normal=nrm))
    for ob in scene.obstacles:
        moving.append((len(kinds), floating_body(scene, ob, len(kinds)) if ob.density > 0.0 else Motion.of(ob)))
        centre = np.array(ob.center, dtype=float)
        Rob = rotation_matrix(ob.rotation)
        if ob.frame == "container":
            centre = c + R @ (centre * s)
            Rob = R @ Rob
        if ob.shape == "sphere":
            kinds.append(WallKind.SPHERE_OUTSIDE)
            rows.append(_row(point=centre, radius=ob.radius))
        elif ob.shape == "mesh":
            from sphcore.mesh_sdf import MeshCheckError, pack, signed_distance_grid
            from sphcore.scene import mesh_path
            try:
                origin, step, values = signed_distance_grid(mesh_path(scene, ob), centre, ob.scale * s, Rob,
                                                            0.5 * dx, 2.0 * H + 2.0 * dx)
            except MeshCheckError as e:  # (the scene's loader says it first, naming the keys)
                raise SceneError(f"obstacles[{scene.obstacles.index(ob)}]: {e}") from None
            kinds.append(WallKind.MESH_OUTSIDE)
            rows.append(np.concatenate([_row(point=centre), pack(origin, step, values)]))
        else:
            kinds.append(WallKind.BOX_OUTSIDE)
            rows.append(_row(point=centre, R=Rob, half=0.5 * np.array(ob.size)))
    corners = np.array(corners)
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    if scene.dim == 2:
        lo[2], hi[2] = 0.0, 0.0
    tables = wall_tables(kernel, scene.dim, H, dx)
    return Walls(
        kind=np.array(kinds, dtype=np.int32),
        data=_pad_rows(rows, dtype),
        tables=tables.astype(dtype), lo=lo, hi=hi, container_walls=n_container,
        motion=np.zeros((len(kinds), MOTION_COLUMNS), dtype=dtype),
        moves=tuple((q, m) for q, m in moving if m is not None),
        rest=_pad_rows(rows, np.float64),
        zones=zone_rows(scene, dtype),
        damping=damping_rows(scene, dtype),
    )


def floating_body(scene: Scene, ob, wall: int) -> FloatingBody:
    """The floating body of obstacle ``ob`` (sphere or box), at rest where the scene puts it; its mass
    is density x volume (x area per metre of depth in 2D), its inertia that of a uniform body turned
    as the scene places it (I_0 = R_ob I R_ob^T; the container's frame too)."""
    if ob.shape == "sphere":
        volume = math.pi * ob.radius ** 2 if scene.dim == 2 else 4.0 / 3.0 * math.pi * ob.radius ** 3
        reach = ob.radius
    else:
        volume = float(np.prod(ob.size[: scene.dim]))
        reach = 0.5 * math.hypot(*ob.size[: scene.dim])
    mass = ob.density * volume
    free = np.zeros(3)
    free[: scene.dim] = [1.0 if f else 0.0 for f in ob.free[: scene.dim]]
    Rob = rotation_matrix(ob.rotation)
    if ob.frame == "container":
        Rob = matmul3(container_frame(scene)[1], Rob)
    inertia = matmul3(matmul3(Rob, inertia_tensor(ob.shape, scene.dim, mass, ob.size, ob.radius)), Rob.T)
    free_rotation = np.array([1.0 if f else 0.0 for f in ob.free_rotation])
    surface = ()
    if scene.sph.body_force == "traction":  # its quadrature points, as placed (physics/traction.py)
        surface = surface_points(ob.shape, scene.dim, ob.radius, ob.size, Rob, scene.particles.spacing)
    return FloatingBody(wall=wall, mass=mass, free=free, free_rotation=free_rotation, inertia=inertia, reach=reach,
                        density=ob.density, surface=surface)


def _pad_rows(rows, dtype) -> np.ndarray:
    """Rows of 16 floats, or longer where a mesh wall carries its distance grid (zero padded)."""
    width = max([16] + [len(r) for r in rows])
    out = np.zeros((len(rows), width), dtype=dtype)
    for q, r in enumerate(rows):
        out[q, :len(r)] = r
    return out


BETA_MAX = 3.0  # caps the no-slip extrapolation z / d (Morris et al. 1997 use 1.5: a 45 % slip at the first row here)


def wall_tables(kernel: Kernel, dim: int, H: float, dx: float, per_half_spacing: int = 64) -> np.ndarray:
    """Wall tables on d in [0, table_end(H, dx)]: rows Phi(d), G0(d), G1(d), G2(d), Gv(d), omega(d) (see
    sphcore.physics.walls). Samples are dx / (2 per_half_spacing) apart, so d = dx/2 — a lattice
    particle next to a wall — is a sample and is looked up exactly.

    The fluid beyond a wall is taken as the continuation of the initial lattice: rows of virtual
    particles at normal distances z_k = d + (k + 1/2) dx from the particle, on lattice columns
    aligned with it. Sums are normalised by the full-lattice sum S = sum_j W(|x_j|) that also sets the
    particle mass (m = rho0 / S), so a particle of the initial lattice next to a wall has exactly
    rho0, and a resting hydrostatic column starts in balance.

        Phi(d) = sum_virtual W(r) / S
        G0(d)  = sum_virtual W'(r) z / r / S          (mirrored pressure, p_j = p_i)
        G1(d)  = sum_virtual W'(r) z^2 / r / S        (hydrostatic extrapolation along the normal)
        G2(d)  = sum_virtual W'(r) t^2 / r / S        (... along one tangential axis t)
        Gv(d)  = sum_virtual W'(r) r / (r^2 + eta^2) beta / S,  eta^2 = 0.01 h^2, h = H/2,
                 beta = min(BETA_MAX, z / d)             (no-slip viscous wall, Morris et al. 1997)
        omega(d) = S dx^(dim-1) L(d) / sum_k L((k + 1/2) dx),  L(d) = sum_lateral W(sqrt(l^2 + d^2))
                 (the wall stress's share at distance d, 1/m: a lattice column's particles, of mass
                 rho0 / S each, take exactly the stress of their wall area dx^(dim-1);
                 physics/wall_friction.py)
    """
    s_w, s_g, _ = kernel_constants(kernel, dim, H)
    s_g /= lattice_gradient_moment(kernel, dim, H, dx)  # the calibrated gradient (see that function)
    K = int(math.ceil(H / dx)) + 1
    lateral = np.arange(-K, K + 1) * dx
    if dim == 3:
        la, lb = np.meshgrid(lateral, lateral, indexing="ij")
        t2 = (la**2).ravel()
        l2 = (la**2 + lb**2).ravel()
    else:
        t2 = l2 = lateral**2
    full = [np.sqrt(l2 + z * z) for z in np.arange(-K, K + 1) * dx]
    wv = np.vectorize(lambda r: w(int(kernel), r, H, s_w), otypes=[float])
    gv = np.vectorize(lambda r: dw_dr(int(kernel), r, H, s_g), otypes=[float])
    S = float(sum(wv(r).sum() for r in full))
    end = table_end(H, dx)
    size = int(round(end / (0.5 * dx))) * per_half_spacing + 1
    out = np.zeros((6, size))
    eta2 = 0.01 * (0.5 * H) ** 2
    for i, d in enumerate(np.linspace(0.0, end, size)):
        for k in range(K + 1):
            z = d + (k + 0.5) * dx
            if z >= H:
                break
            r = np.sqrt(l2 + z * z)
            out[0, i] += wv(r).sum()
            dwz = gv(r) * z / r
            out[1, i] += dwz.sum()
            out[2, i] += (dwz * z).sum()
            out[3, i] += (gv(r) / r * t2).sum()
            # Morris: the virtual particle moves with -(z - d)/d v_i, so v_i - v_j = (z / d) v_i
            beta = min(BETA_MAX, z / d) if d > 0.0 else BETA_MAX
            out[4, i] += (gv(r) * r / (r * r + eta2)).sum() * beta
        if d < H:
            out[5, i] = wv(np.sqrt(l2 + d * d)).sum()
    column = sum(wv(np.sqrt(l2 + z * z)).sum() for z in (np.arange(K + 1) + 0.5) * dx if z < H)
    out[5] *= S * S * dx ** (dim - 1) / column  # omega, after the division by S below
    return out / S


def table_end(H: float, dx: float) -> float:
    """The wall tables span [0, end], end = the first multiple of dx/2 at or beyond H."""
    return math.ceil(H / (0.5 * dx) - 1e-9) * 0.5 * dx


def lattice_gradient_moment(kernel: Kernel, dim: int, H: float, dx: float) -> float:
    """M = -sum_j V x_j dW/dx (x_j) over an infinite cubic lattice, with the particle volume
    V = m / rho0 = 1 / S of the lattice-normalised mass (lattice_sum).

    For the continuous kernel M = 1 (integration by parts); on a lattice with a support of only 2-3
    spacings it is not: 0.947 for Wendland C2 at H = 2.3 dx in 2D, so the SPH pressure gradient would
    be 5 % weak and a resting column would need a 5.6 % too steep pressure profile. Dividing the
    gradient constant by M makes sum_j V_j x_ij (x) grad W_ij = I hold exactly on the initial
    lattice (a constant kernel-gradient correction, the simplest form of Bonet & Lok 1999); being a
    constant factor it keeps every pair force antisymmetric.
    """
    _, s_g, _ = kernel_constants(kernel, dim, H)
    K = int(math.ceil(H / dx)) + 1
    r = np.arange(-K, K + 1) * dx
    grids = np.meshgrid(*([r] * dim), indexing="ij")
    x0 = grids[0].ravel()
    dist = np.sqrt(sum(g**2 for g in grids)).ravel()
    total = 0.0
    for xj, rj in zip(x0, dist):
        if rj > 0.0:
            total += dw_dr(int(kernel), float(rj), H, s_g) * xj * xj / rj
    return -total / lattice_sum(kernel, dim, H, dx)


def lattice_pressure_diagonal(kernel: Kernel, dim: int, H: float, dx: float, rho0: float) -> float:
    """D0 = sum_j |m grad W(x_j)|^2 over an infinite cubic lattice (m = rho0 / S, calibrated gradient):
    DFSPH's diagonal D_i of a particle with a full neighbourhood at rest (physics/dfsph.py)."""
    _, s_g, _ = kernel_constants(kernel, dim, H)
    s_g /= lattice_gradient_moment(kernel, dim, H, dx)
    m = rho0 / lattice_sum(kernel, dim, H, dx)
    K = int(math.ceil(H / dx)) + 1
    r = np.arange(-K, K + 1) * dx
    grids = np.meshgrid(*([r] * dim), indexing="ij")
    dist = np.sqrt(sum(g**2 for g in grids)).ravel()
    return float(sum((m * dw_dr(int(kernel), float(d), H, s_g)) ** 2 for d in dist if d > 0.0))


def lattice_jacobi_ratio(kernel: Kernel, dim: int, H: float, dx: float, samples: int | None = None) -> float:
    """lambda_max / D0 of DFSPH's pressure operator on an infinite cubic lattice (physics/dfsph.py).

    On a lattice the operator is a convolution: a pressure wave lambda e^{i k.x} changes the density
    by |g(k)|^2 lambda, g(k) = sum_j grad W(x_j) sin(k.x_j), while its Jacobi diagonal is
    D0 = sum_j |grad W(x_j)|^2, the mean of |g(k)|^2 over k (Parseval). The ratio of the largest
    |g(k)|^2 to that mean grows with the number of neighbours (2D Wendland C2: 2.3 at 2.3 spacings,
    5.7 at 4), and relaxed Jacobi converges only if omega * ratio < 2. Sampled on a grid of k over
    [0, pi/dx]^dim (|g(k)|^2 is even in every component of k)."""
    _, s_g, _ = kernel_constants(kernel, dim, H)
    K = int(math.ceil(H / dx)) + 1
    r = np.arange(-K, K + 1, dtype=float)
    offsets = np.stack([g.ravel() for g in np.meshgrid(*([r] * dim), indexing="ij")], axis=1)  # in spacings
    dist = np.linalg.norm(offsets, axis=1) * dx
    keep = (dist > 0.0) & (dist < H)
    offsets, dist = offsets[keep], dist[keep]
    dw = np.array([dw_dr(int(kernel), float(d), H, s_g) for d in dist])
    grad = offsets / np.linalg.norm(offsets, axis=1)[:, None] * dw[:, None]  # grad W(x_j), shape (n, dim)
    d0 = float(np.sum(grad**2))
    n = samples or (65 if dim == 2 else 25)
    ks = np.linspace(0.0, math.pi, n)
    best = 0.0
    for kx in ks:  # one slab of k at a time keeps the memory small in 3D
        rest = np.stack([g.ravel() for g in np.meshgrid(*([ks] * (dim - 1)), indexing="ij")], axis=1)
        k = np.hstack([np.full((len(rest), 1), kx), rest])
        g_k = np.sin(k @ offsets.T) @ grad  # (len(k), dim)
        best = max(best, float(np.max(np.sum(g_k**2, axis=1))))
    return best / d0


def lattice_sum(kernel: Kernel, dim: int, H: float, dx: float) -> float:
    """S = sum_j W(|x_j|) over an infinite cubic lattice of spacing dx (self included)."""
    s_w, _, _ = kernel_constants(kernel, dim, H)
    K = int(math.ceil(H / dx)) + 1
    r = np.arange(-K, K + 1) * dx
    grids = np.meshgrid(*([r] * dim), indexing="ij")
    dist = np.sqrt(sum(g**2 for g in grids)).ravel()
    return float(sum(w(int(kernel), float(d), H, s_w) for d in dist))


# -- which grid cells the walls can reach ---------------------------------------------------------
# Most particles are farther than H from every wall, and for them the walls' terms are zero: the
# density and force passes evaluate them only for particles in a cell flagged here (physics/walls.py
# near_wall), which skipped 3.5 ms of a 36 ms step on the 3D dam break (docs/BENCHMARKS.md). A flag
# must never be missing: a cell is flagged when a wall's signed distance at its centre, less the
# half-diagonal, is under H (the primitives' distances are Euclidean, so they change no faster than
# the point moves), when it lies in a mesh's distance grid grown by H (a trilinear interpolant is not
# 1-Lipschitz), on the grid's outer layer (a particle outside the grid is binned there), or when any
# wall moves (the flags would have to follow it).
NEAR_MARGIN = 1e-3   # of H, plus 1e-5 of the domain's extent: room for the run's rounding of d


def near_wall_cells(walls: Walls, grid) -> np.ndarray:
    """(grid cells,) uint8 flags of the cells within reach of a wall (the rule above)."""
    near = np.ones(grid.ncells, dtype=np.uint8)
    if walls.moves:
        return near
    H = math.sqrt(float(grid.H2))
    origin, cell = grid.origin.astype(np.float64), grid.cell.astype(np.float64)
    extent = float(np.max(np.abs(np.concatenate([origin, origin + grid.ncell * cell]))))
    reach = H * (1.0 + NEAR_MARGIN) + 1e-5 * extent
    flag_near_cells(walls.kind, walls.data.astype(np.float64), origin, cell, grid.ncell, reach, near)
    return near
