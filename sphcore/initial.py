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


def _cartesian_points(block, dim: int, dx: float) -> np.ndarray:
    """A block's cartesian lattice: points at min + (k + 1/2) dx over its bounding box, a sphere
    block's cut to its radius."""
    if block.shape == "box":
        lo = np.array(block.min, dtype=float)
        hi = np.array(block.max, dtype=float)
    else:
        c = np.array(block.center, dtype=float)
        lo = c - block.radius
        hi = c + block.radius
    counts = [max(int(round((hi[d] - lo[d]) / dx)), 1) if d < dim else 1 for d in range(3)]
    axes = [lo[d] + (np.arange(counts[d]) + 0.5) * dx if d < dim else np.zeros(1) for d in range(3)]
    gz, gy, gx = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    pts = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1)
    if block.shape == "sphere":
        rel = pts - np.array(block.center)
        rel[:, dim:] = 0.0
        pts = pts[np.einsum("ij,ij->i", rel, rel) <= block.radius**2]
    return pts


def _block_points(block, scene: Scene, dx: float) -> np.ndarray:
    """The block's lattice points (a polar lattice only for a sphere block: scene validation), in
    world coordinates."""
    if block.lattice == "polar":
        pts = _polar_points(block.center, block.radius, scene.dim, dx)
    else:
        pts = _cartesian_points(block, scene.dim, dx)
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


def fill_blocks(scene: Scene, walls: Walls) -> list[tuple[np.ndarray, np.ndarray]]:
    """The (x, v) of each fluid block, in file order: its lattice points inside the domain, not
    within half a spacing of a wall or inside an obstacle, not filled already by an earlier block.
    SceneError for a block of which some points fall outside the domain (unless the block says
    clip = true) or none is left."""
    dx = scene.particles.spacing
    estimate = sum(block_estimate(b, scene.dim, dx) for b in scene.fluid.blocks)
    if estimate > scene.particles.max_particles:  # validated at load; scenes made by dataclasses.replace too
        raise SceneError(f"particles.spacing = {dx!r}: would create about {estimate:.3g} particles, more than "
                         f"particles.max_particles = {scene.particles.max_particles} (raise the spacing or the limit)")
    filled = []
    for i, block in enumerate(scene.fluid.blocks):
        key = f"fluid.blocks[{i}]"
        pts = _block_points(block, scene, dx)
        outside = _outside_domain(walls, scene, pts, dx)
        n_out = int(outside.sum())
        if n_out == len(pts):
            raise SceneError(f"{key}: no particle of this block lies inside the domain (check its min/max or "
                             "center/radius against domain and obstacles)")
        if n_out and not block.clip:
            raise SceneError(f"{key}: {n_out} of its {len(pts)} particles fall outside the domain (container "
                             "walls, domain.planes or bounds); move or shrink the block, or set "
                             f"{key}.clip = true to keep only the part inside")
        dist = np.full(len(pts), np.inf)
        if walls.kind.shape[0]:
            min_wall_distance(walls.kind, walls.data.astype(np.float64), pts, dist)
        keep = (dist >= 0.5 * dx * (1 - 1e-6)) & ~outside
        for prev, _ in filled:  # blocks must not overlap: skip points already filled by an earlier block
            if len(prev) and len(pts):
                lo, hi = prev.min(axis=0) - 0.5 * dx, prev.max(axis=0) + 0.5 * dx
                inside = np.all((pts >= lo) & (pts <= hi), axis=1)
                keep &= ~inside
        pts = pts[keep]
        if len(pts) == 0:
            raise SceneError(f"{key}: no particle of this block is left inside the domain (within half a spacing "
                             "of a wall, inside an obstacle or filled by an earlier block)")
        filled.append((pts, np.tile(np.array(block.velocity, dtype=float), (len(pts), 1))))
    return filled


def generate_particles(scene: Scene, walls: Walls):
    """Return (ids (n,), x (n,3), v (n,3)) in float64; raise SceneError for impossible blocks."""
    filled = fill_blocks(scene, walls)
    xs = [x for x, _ in filled]
    vs = [v for _, v in filled]
    x = np.concatenate(xs)
    v = np.concatenate(vs)
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
    from sphcore.scene import BYTES_PER_CELL, BYTES_PER_PARTICLE, resource_estimate
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
    vmax = max(float(np.sqrt((v**2).sum(axis=1)).max()) for _, v in filled)
    if scene.fluid.initial_flow == "taylor_green":
        vmax += scene.fluid.flow_speed
    amax = math.hypot(*scene.forces.gravity) + math.hypot(*scene.forces.external)
    nu = scene.sph.nu if scene.sph.viscosity in ("muller", "morris") else 0.0
    c0 = 0.0 if scene.sph.solver == "dfsph" else scene.sph.sound_speed
    dt, limit = choose_dt(scene.time.mode, scene.time.dt, scene.time.cfl, 0.5 * H, c0, vmax, amax, nu,
                          scene.terms.shifting)
    return {"blocks": counts, "inlets": inlets, "particles": n, "cells": est["cells"],
            "memory": n * BYTES_PER_PARTICLE + est["cells"] * BYTES_PER_CELL,
            "neighbours": lattice_neighbours(scene.sph.support, scene.dim), "dt": dt, "dt_limit": limit}
