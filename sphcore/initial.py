"""Initial particles from a scene: lattice-filled blocks, masses, initial velocities.

Every process generating particles from the same scene gets the same particles with the same global
ids (blocks in file order, lattice points in z, y, x order within a block), which is what lets each
peer of a distributed run generate only its own share.

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
from sphcore.scene import Scene, SceneError


def _block_points(block, scene: Scene, dx: float) -> np.ndarray:
    dim = scene.dim
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
    if block.frame == "container":
        c, R = container_frame(scene)
        pts = c + (pts * scene.domain.scale) @ R.T
    return pts


def _estimate_count(block, scene: Scene, dx: float) -> float:
    if block.shape == "box":
        return float(np.prod([(block.max[d] - block.min[d]) / dx for d in range(scene.dim)]))
    return (math.pi * block.radius**2 if scene.dim == 2 else 4.0 / 3.0 * math.pi * block.radius**3) / dx**scene.dim


def generate_particles(scene: Scene, walls: Walls):
    """Return (ids (n,), x (n,3), v (n,3)) in float64; raise SceneError for impossible blocks."""
    dx = scene.particles.spacing
    limit = scene.particles.max_particles
    estimate = sum(_estimate_count(b, scene, dx) for b in scene.fluid.blocks)
    if estimate > limit:
        raise SceneError(f"particles.spacing = {dx!r}: would create about {estimate:.3g} particles, more than "
                         f"particles.max_particles = {limit} (raise the spacing or the limit)")
    xs, vs = [], []
    for i, block in enumerate(scene.fluid.blocks):
        pts = _block_points(block, scene, dx)
        dist = np.full(len(pts), np.inf)
        if walls.kind.shape[0]:
            min_wall_distance(walls.kind, walls.data.astype(np.float64), pts, dist)
        keep = dist >= 0.5 * dx * (1 - 1e-6)
        for prev in xs:  # blocks must not overlap: skip points already filled by an earlier block
            if len(prev) and len(pts):
                lo, hi = prev.min(axis=0) - 0.5 * dx, prev.max(axis=0) + 0.5 * dx
                inside = np.all((pts >= lo) & (pts <= hi), axis=1)
                keep &= ~inside
        pts = pts[keep]
        if len(pts) == 0:
            raise SceneError(f"fluid.blocks[{i}]: no particle of this block lies inside the domain (check its "
                             "min/max or center/radius against domain and obstacles)")
        xs.append(pts)
        vs.append(np.tile(np.array(block.velocity, dtype=float), (len(pts), 1)))
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
