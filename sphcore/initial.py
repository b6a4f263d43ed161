"""Initial particles from a scene: lattice-filled blocks, masses, initial velocities.

Every process generating particles from the same scene gets the same particles with the same global
ids (blocks in file order, lattice points in z, y, x order within a block, or ring by ring from the
centre for a polar block), which is what lets each peer of a distributed run generate only its own
share.

Lattice points lie at ``min + (k + 1/2) dx`` so that a block touching a wall starts half a spacing
from it. Points closer than half a spacing to any wall (outside the container, inside an obstacle)
are carved away. Masses make the density of a full lattice equal rho0 for the chosen kernel:
m = rho0 / sum_j W(|x_j|) over an infinite lattice (boundaries.lattice_sum, applied by the
solver), so a scene starts at rest density.
"""
from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from types import SimpleNamespace

import numpy as np

from sphcore.boundaries import Walls, container_frame
from sphcore.physics.walls import min_wall_distance
from sphcore.scene import Scene, SceneError, block_estimate


def _polar_points(centre, radius: float, dim: int, dx: float) -> np.ndarray:
    """A sphere block's polar lattice: rings (2D) or shells (3D) at r_k = (k + 1/2) dx about the centre,
    k = 0 .. round(R / dx) - 1, each holding n_k = max(round(2 pi r_k / dx), 1) points (2D: evenly in
    angle, every other ring turned by half a step) or max(round(4 pi r_k^2 / dx^2), 1) points (3D: the
    Fibonacci spiral, equal areas). Ring k stands for the annulus k dx .. (k + 1) dx, so a wall
    circle about the same centre at a whole number of spacings sits half a spacing from the nearest
    ring, as a flat wall sits from a cartesian lattice; each point holds about dx^dim of volume."""
    rings = max(int(round(radius / dx)), 1)
    out = []
    for k in range(rings):
        r = (k + 0.5) * dx
        if dim == 2:
            n = max(int(round(2.0 * math.pi * r / dx)), 1)
            theta = 2.0 * math.pi * (np.arange(n) + 0.5 * (k % 2)) / n
            out.append(np.stack([r * np.cos(theta), r * np.sin(theta), np.zeros(n)], axis=1))
        else:
            n = max(int(round(4.0 * math.pi * r * r / (dx * dx))), 1)
            j = np.arange(n) + 0.5
            cos_polar = 1.0 - 2.0 * j / n
            sin_polar = np.sqrt(np.maximum(1.0 - cos_polar**2, 0.0))
            azimuth = math.pi * (3.0 - math.sqrt(5.0)) * j  # the golden angle
            out.append(r * np.stack([sin_polar * np.cos(azimuth), sin_polar * np.sin(azimuth), cos_polar], axis=1))
    return np.asarray(centre, dtype=float) + np.concatenate(out)


def _cartesian_points(block, dim: int, dx: float, slab=None) -> np.ndarray:
    """A block's cartesian lattice: points at min + (k + 1/2) dx over its bounding box, a sphere
    block's cut to its radius. ``slab`` = (k0, k1): only the layers k0 <= k < k1 of the outermost
    axis (z in 3D, y in 2D), whose points are a contiguous run of the whole lattice's (z, y, x) order."""
    if block.shape == "box":
        lo = np.array(block.min, dtype=float)
        hi = np.array(block.max, dtype=float)
    else:
        c = np.array(block.center, dtype=float)
        lo = c - block.radius
        hi = c + block.radius
    counts = [max(int(round((hi[d] - lo[d]) / dx)), 1) if d < dim else 1 for d in range(3)]
    axes = [lo[d] + (np.arange(counts[d]) + 0.5) * dx if d < dim else np.zeros(1) for d in range(3)]
    if slab is not None:
        axes[dim - 1] = axes[dim - 1][slab[0]:slab[1]]
    gz, gy, gx = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    pts = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1)
    if block.shape == "sphere":
        rel = pts - np.array(block.center)
        rel[:, dim:] = 0.0
        pts = pts[np.einsum("ij,ij->i", rel, rel) <= block.radius**2]
    return pts


def _slabs(block, dim: int, dx: float, slab_points: int) -> list:
    """The block's lattice in slabs of whole outer layers of about ``slab_points`` points each, filled
    in parallel; [None] (the block whole) for a polar lattice or a block of one slab."""
    if block.lattice == "polar":
        return [None]
    if block.shape == "box":
        sides = [block.max[d] - block.min[d] for d in range(dim)]
    else:
        sides = [2.0 * block.radius] * dim
    counts = [max(int(round(side / dx)), 1) for side in sides]
    layers = counts[-1]
    per_layer = max(math.prod(counts[:-1]), 1)
    n_slabs = min(layers, max(1, (layers * per_layer) // max(slab_points, 1)))
    if n_slabs <= 1:
        return [None]
    cuts = [layers * k // n_slabs for k in range(n_slabs + 1)]
    return [(a, b) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]


def _block_points(block, scene: Scene, dx: float, slab=None) -> np.ndarray:
    """The block's lattice points (a polar lattice only for a sphere block: scene validation), in
    world coordinates; ``slab``: only those layers of a cartesian lattice (_cartesian_points)."""
    if block.lattice == "polar":
        pts = _polar_points(block.center, block.radius, scene.dim, dx)
    else:
        pts = _cartesian_points(block, scene.dim, dx, slab)
    if block.frame == "container":
        c, R = container_frame(scene)
        pts = c + (pts * scene.domain.scale) @ R.T
    return pts


def _outside_domain(walls: Walls, scene: Scene, pts: np.ndarray, dx: float) -> np.ndarray:
    """Which points lie outside the domain: beyond a container wall or a plane (obstacles are carved
    from a block on purpose, so they do not count), or outside the bounds along a periodic axis or of
    container = 'none'."""
    n_domain = walls.container_walls + len(scene.domain.planes)
    outside = np.zeros(len(pts), dtype=bool)
    if n_domain:
        dist = np.full(len(pts), np.inf)
        min_wall_distance(walls.kind[:n_domain], walls.data[:n_domain].astype(np.float64), pts, dist)
        outside |= dist < -1e-9 * dx
    dom = scene.domain
    for d in range(scene.dim):
        if dom.container == "none" or dom.periodic[d]:
            outside |= (pts[:, d] < walls.lo[d] - 1e-9 * dx) | (pts[:, d] > walls.hi[d] + 1e-9 * dx)
    return outside


outside_domain = _outside_domain  # the probes' name for it (sphcore/probes.py)


def check_probes_inside(scene: Scene, walls: Walls):
    """SceneError naming the [[probes]] whose point lies outside the domain (a point on a wall is
    inside)."""
    if not scene.probes:
        return
    pts = np.array([p.at for p in scene.probes], dtype=np.float64)
    for i in np.nonzero(_outside_domain(walls, scene, pts, scene.particles.spacing))[0]:
        p = scene.probes[i]
        o = scene.origin  # the scene file's (world) coordinates, not the run's
        lo = [round(float(v + c), 6) for v, c in zip(walls.lo[: scene.dim], o)]
        hi = [round(float(v + c), 6) for v, c in zip(walls.hi[: scene.dim], o)]
        at = [v + c for v, c in zip(p.at[: scene.dim], o)]
        raise SceneError(f"probes[{i}].at = {at!r}: outside the domain (probe {p.name!r}); "
                         f"its walls bound it within {lo} .. {hi}")


SLAB_POINTS = 1 << 20  # lattice points a thread fills at once (a large block is filled in parallel)


def _kept_by_walls(walls: Walls, pts: np.ndarray, dx: float) -> np.ndarray:
    """The points at least half a spacing from every wall (not inside an obstacle or beyond the container)."""
    dist = np.full(len(pts), np.inf)
    if walls.kind.shape[0]:
        min_wall_distance(walls.kind, walls.data.astype(np.float64), pts, dist)
    return dist >= 0.5 * dx * (1 - 1e-6)


def _fill_slab(block, scene: Scene, walls: Walls, dx: float, slab, earlier):
    """(kept points, lattice points, points outside the domain) of one slab of a block: the points not
    outside the domain, not within half a spacing of a wall or inside an obstacle, not inside an
    earlier block's box (``earlier``: their (lo, hi) grown by half a spacing)."""
    pts = _block_points(block, scene, dx, slab)
    outside = _outside_domain(walls, scene, pts, dx)
    keep = _kept_by_walls(walls, pts, dx) & ~outside
    if len(pts) and earlier:
        # blocks must not overlap: skip points already filled by an earlier block; only the boxes that
        # meet this slab's are tested (3,000 small blocks took 34 s testing every box against every slab)
        lo_all, hi_all = np.array([b[0] for b in earlier]), np.array([b[1] for b in earlier])
        near = np.all((lo_all <= pts.max(axis=0)) & (hi_all >= pts.min(axis=0)), axis=1)
        for lo, hi in zip(lo_all[near], hi_all[near]):
            keep &= ~np.all((pts >= lo) & (pts <= hi), axis=1)
    return pts[keep], len(pts), int(outside.sum())


def _joined(pool, parts: list, width: int) -> np.ndarray:
    """The parts' rows, in order, in one (n, width) array, copied in parallel (first touch of a
    large array is most of its cost)."""
    if len(parts) == 1:
        return parts[0]
    ends = np.cumsum([len(p) for p in parts])
    out = np.empty((int(ends[-1]) if len(ends) else 0, width))

    def copy(k):
        out[ends[k] - len(parts[k]):ends[k]] = parts[k]
    list(pool.map(copy, range(len(parts))))
    return out


def _workers() -> int:
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def fill_blocks(scene: Scene, walls: Walls, slab_points: int = SLAB_POINTS) -> list[tuple[np.ndarray, np.ndarray]]:
    """(x (n, 3), its velocity (3,)) of each fluid block, in file order: its lattice points inside the domain, not
    within half a spacing of a wall or inside an obstacle, not filled already by an earlier block.
    SceneError for a block of which some points fall outside the domain (unless the block says
    clip = true) or none is left. A large block is filled in slabs on every core (the same points in
    the same order as one pass: a slab is a contiguous run of the lattice's order)."""
    dx = scene.particles.spacing
    estimate = sum(block_estimate(b, scene.dim, dx) for b in scene.fluid.blocks)
    if estimate > scene.particles.max_particles:  # validated at load; scenes made by dataclasses.replace too
        raise SceneError(f"particles.spacing = {dx!r}: would create about {estimate:.3g} particles, more than "
                         f"particles.max_particles = {scene.particles.max_particles} (raise the spacing or the limit)")
    filled, earlier = [], []  # earlier: each filled block's points' box, grown by half a spacing
    with ThreadPoolExecutor(_workers()) as pool:
        for i, block in enumerate(scene.fluid.blocks):
            key = f"fluid.blocks[{i}]"
            parts = list(pool.map(lambda slab: _fill_slab(block, scene, walls, dx, slab, earlier),
                                  _slabs(block, scene.dim, dx, slab_points)))
            n_pts = sum(p[1] for p in parts)
            n_out = sum(p[2] for p in parts)
            if n_out == n_pts:
                raise SceneError(f"{key}: no particle of this block lies inside the domain (check its min/max or "
                                 "center/radius against domain and obstacles)")
            if n_out and not block.clip:
                raise SceneError(f"{key}: {n_out} of its {n_pts} particles fall outside the domain (container "
                                 "walls, domain.planes or bounds); move or shrink the block, or set "
                                 f"{key}.clip = true to keep only the part inside")
            pts = _joined(pool, [p[0] for p in parts], 3)
            if len(pts) == 0:
                raise SceneError(f"{key}: no particle of this block is left inside the domain (within half a spacing "
                                 "of a wall, inside an obstacle or filled by an earlier block)")
            filled.append((pts, np.array(block.velocity, dtype=float)))
            earlier.append((pts.min(axis=0) - 0.5 * dx, pts.max(axis=0) + 0.5 * dx))
    return filled


def generate_particles(scene: Scene, walls: Walls, slab_points: int = SLAB_POINTS):
    """Return (ids (n,), x (n,3), v (n,3)) in float64; raise SceneError for impossible blocks."""
    filled = fill_blocks(scene, walls, slab_points)
    x = filled[0][0] if len(filled) == 1 else np.concatenate([x for x, _ in filled])
    v = np.empty_like(x)
    start = 0
    for pts, velocity in filled:
        v[start:start + len(pts)] = velocity
        start += len(pts)
    if scene.fluid.initial_flow == "taylor_green":
        lo = np.array(scene.domain.bounds_min if scene.domain.container == "none" else walls.lo)
        hi = np.array(scene.domain.bounds_max if scene.domain.container == "none" else walls.hi)
        L = hi - lo
        k = 2.0 * math.pi * (x - lo) / np.where(L > 0, L, 1.0)
        U = scene.fluid.flow_speed
        v[:, 0] += -U * np.cos(k[:, 0]) * np.sin(k[:, 1])
        v[:, 1] += U * np.sin(k[:, 0]) * np.cos(k[:, 1])
    elif scene.fluid.initial_flow == "straining":
        c = np.array(scene.fluid.flow_center, dtype=float)
        A = scene.fluid.flow_rate
        v[:, 0] += A * (x[:, 0] - c[0])
        v[:, 1] += -A * (x[:, 1] - c[1])
    ids = np.arange(len(x), dtype=np.int64)
    return ids, x, v


FULL = 0.97  # forces.hydrostatic = "removed": the share of the container's lattice the particles must fill


def check_full(scene: Scene, walls: Walls, n_particles: int):
    """forces.hydrostatic = "removed" assumes no free surface anywhere, so the fluid must fill its
    closed container. The container holds the lattice of a block as large as the domain's box, carved
    as blocks are (``_cartesian_points``, ``_kept_by_walls``); SceneError if the particles are fewer
    than FULL of its points, naming both counts."""
    dx = scene.particles.spacing
    box = SimpleNamespace(shape="box", min=walls.lo, max=walls.hi)
    layers = max(int(round((walls.hi[scene.dim - 1] - walls.lo[scene.dim - 1]) / dx)), 1)
    holds = sum(int(np.count_nonzero(_kept_by_walls(walls, _cartesian_points(box, scene.dim, dx, (k, k + 1)), dx)))
                for k in range(layers))  # one layer of the lattice at a time
    if n_particles < FULL * holds:
        raise SceneError(f"forces.hydrostatic = 'removed': the fluid must fill its closed container (no free "
                         f"surface), but its {n_particles} particles fill {n_particles / max(holds, 1):.0%} of the "
                         f"{holds} lattice sites the container holds at this spacing; fill it with [[fluid.blocks]], "
                         f"or use forces.hydrostatic = 'resolved'")


def lattice_neighbours(support: float, dim: int) -> int:
    """Neighbours of a particle inside a full lattice: the other lattice points closer than the
    support radius H = support x spacing."""
    k = int(math.ceil(support))
    r = np.arange(-k, k + 1)
    grids = np.meshgrid(*([r] * dim), indexing="ij")
    inside = sum(g.astype(float) ** 2 for g in grids) < support**2
    return int(inside.sum()) - 1


def scene_report(scene: Scene) -> dict:
    """What ``sph run`` checks and makes before its first step, without building a simulation: the
    particles of each block (the same ``fill_blocks`` the run uses; SceneError for a bad block), the
    memory estimate, the neighbours of a particle in the bulk and the first time step estimated from
    the CFL limits at the initial speeds and the body forces."""
    from sphcore.boundaries import build_walls
    from sphcore.choices import KERNELS
    from sphcore.scene import BYTES_PER_CELL, bytes_per_particle, resource_estimate
    from sphcore.timestep import choose_dt
    dx = scene.particles.spacing
    H = scene.sph.support * dx
    walls = build_walls(scene, KERNELS[scene.sph.kernel], H, np.float64)
    filled = fill_blocks(scene, walls)
    check_probes_inside(scene, walls)
    counts = [len(x) for x, _ in filled]
    n = sum(counts)
    inlets = []
    if scene.inlets or scene.outlets:  # the inlets fill themselves, replacing the blocks' particles there
        from sphcore.open_boundary import OpenBoundaries
        ob = OpenBoundaries(scene, walls)
        x = np.concatenate([x for x, _ in filled])
        n = len(ob.initial(np.arange(len(x)), x, np.zeros_like(x))[0])
        inlets = [{"per_layer": len(lat.nodes), "layers": lat.K0, "layer_every_s": lat.dx / lat.U}
                  for lat in ob.inlets]
    est = resource_estimate(scene)
    vmax = max(float(np.sqrt((v**2).sum())) for _, v in filled)
    if scene.fluid.initial_flow == "taylor_green":
        vmax += scene.fluid.flow_speed
    amax = math.hypot(*scene.forces.gravity) + math.hypot(*scene.forces.external)
    nu = scene.sph.nu if scene.sph.viscosity in ("muller", "morris") else 0.0
    c0 = 0.0 if scene.sph.solver == "dfsph" else scene.sph.sound_speed
    dt, limit = choose_dt(scene.time.mode, scene.time.dt, scene.time.cfl, 0.5 * H, c0, vmax, amax, nu,
                          scene.terms.shifting)
    return {"blocks": counts, "inlets": inlets, "particles": n, "cells": est["cells"],
            "memory": n * bytes_per_particle(scene) + est["cells"] * BYTES_PER_CELL,
            "neighbours": lattice_neighbours(scene.sph.support, scene.dim), "dt": dt, "dt_limit": limit}
