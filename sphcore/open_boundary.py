"""Inlets and outlets on the host: the particles an inlet adds and an outlet removes at the end of
each step (what the zones do to the particles inside them: physics/open_boundary.py).

**Inlet layers.** Inlet q is a box along one axis (its velocity's, U > 0 along it, sign s = +-1).
Its particles form layers of one lattice moving with U: layer k's nodes are the cross-section's
``nodes`` (spacing dx, half a spacing from the box's sides, none within half a spacing of a wall),
at the distance xi_k(t) = (K0 - k - 1/2) dx + U t from the back face, where K0 = floor(L / dx)
layers fill the box (its length L along the axis) at t = 0. Layer k exists once xi_k >= 0, so at
time t there are ``layers(t)`` = K0 + max(0, floor(U t / dx + 1/2)) of them: a function of t alone.
That makes everything about a new layer follow from the time: its positions and its global ids,
(q + 1) ID_STRIDE + k n_q + j for node j, so every peer computes the same layers at the same step,
keeps the rows its block owns, and a resumed run makes the rows the continuous one makes (bitwise;
a checkpoint at time t holds exactly layers(t) of every inlet).

**Outlets.** Rows past an outlet box's far face (within the box's cross-section) are removed. The
global count of particles (``Simulation.n_particles``) follows: the inlets' additions are known
everywhere, the removals are summed over the peers (one integer reduction per step).

Scenes without inlets or outlets skip all of this (``OpenBoundaries.active`` is False).
"""
from __future__ import annotations

import math

import numpy as np

from sphcore.physics.walls import min_wall_distance
from sphcore.scene import SceneError
from sphcore.state import with_new_owned

ID_STRIDE = 2 ** 40  # inlet q's ids start at (q + 1) * ID_STRIDE; the blocks' are 0 .. n_initial - 1


def _axis(vec, dim: int) -> tuple[int, float]:
    axis = next(d for d in range(dim) if vec[d] != 0.0)
    return axis, math.copysign(1.0, vec[axis])


class InletLattice:
    """One inlet's moving lattice (see the module's docstring)."""

    def __init__(self, zone, q: int, dim: int, dx: float, walls):
        self.axis, self.sign = _axis(zone.velocity, dim)
        a = self.axis
        self.U = abs(float(zone.velocity[a]))
        self.velocity = np.array(zone.velocity, dtype=np.float64)
        self.dx = dx
        self.back = float(zone.min[a] if self.sign > 0 else zone.max[a])
        self.K0 = max(1, int(math.floor((zone.max[a] - zone.min[a]) / dx + 1e-9)))
        axes = []
        for d in range(3):
            if d == a or d >= dim:
                axes.append(np.zeros(1))
            else:
                count = max(int(round((zone.max[d] - zone.min[d]) / dx)), 1)
                axes.append(zone.min[d] + (np.arange(count) + 0.5) * dx)
        gz, gy, gx = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
        nodes = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1)
        nodes[:, a] = self.back + self.sign * 0.5 * dx  # a layer's place, to test it against the walls
        dist = np.full(len(nodes), np.inf)
        if walls.kind.shape[0]:
            min_wall_distance(walls.kind, walls.rest.astype(np.float64), nodes, dist)
        self.nodes = nodes[dist >= 0.5 * dx * (1 - 1e-6)]
        self.nodes[:, a] = 0.0
        self.base = (q + 1) * ID_STRIDE

    def layers(self, t: float) -> int:
        """How many layers exist at time t (s)."""
        return self.K0 + max(0, int(math.floor(self.U * t / self.dx + 0.5)))

    def rows(self, k0: int, k1: int, t: float):
        """(ids, x, v) of layers k0 .. k1 - 1 at time t, float64, layer by layer, node by node."""
        n = len(self.nodes)
        k = np.repeat(np.arange(k0, k1, dtype=np.int64), n)
        x = np.tile(self.nodes, (k1 - k0, 1))
        xi = (self.K0 - k - 0.5) * self.dx + self.U * t
        x[:, self.axis] = self.back + self.sign * xi
        ids = self.base + k * n + np.tile(np.arange(n, dtype=np.int64), k1 - k0)
        return ids, x, np.tile(self.velocity, (len(ids), 1))

    def inside(self, x: np.ndarray, zone, dim: int) -> np.ndarray:
        return np.all((x[:, :dim] >= np.array(zone.min[:dim])) & (x[:, :dim] < np.array(zone.max[:dim])), axis=1)


class OpenBoundaries:
    """A simulation's inlets and outlets: the initial rows, the rows added and removed each step, and
    which particle ids can exist."""

    def __init__(self, scene, walls):
        self.scene = scene
        self.dim = scene.dim
        dx = scene.particles.spacing
        self.inlets = [InletLattice(z, q, scene.dim, dx, walls) for q, z in enumerate(scene.inlets)]
        for q, lattice in enumerate(self.inlets):
            if not len(lattice.nodes):
                raise SceneError(f"inlets[{q}]: no node of its cross-section lies inside the domain (each is within "
                                 "half a spacing of a wall or outside it); widen the zone or move it off the walls")
        self.outlets = []
        for z in scene.outlets:
            axis, sign = _axis(z.direction, scene.dim)
            face = float(z.max[axis] if sign > 0 else z.min[axis])
            self.outlets.append((axis, sign, face, np.array(z.min[: scene.dim]), np.array(z.max[: scene.dim])))
        self.active = bool(self.inlets or self.outlets)
        self.n_initial = 0     # the blocks' particles: ids 0 .. n_initial - 1
        self.inflow = 0        # rows the inlets added after t = 0 (all peers)
        self.outflow = 0       # rows the outlets removed (all peers)

    def initial(self, ids, x, v):
        """The blocks' particles without those inside an inlet (it fills itself), renumbered, then
        every inlet's layers at t = 0."""
        keep = np.ones(len(ids), dtype=bool)
        for lattice, zone in zip(self.inlets, self.scene.inlets):
            keep &= ~lattice.inside(x, zone, self.dim)
        x, v = x[keep], v[keep]
        self.n_initial = len(x)
        parts = [(np.arange(len(x), dtype=np.int64), x, v)]
        parts += [lattice.rows(0, lattice.layers(0.0), 0.0) for lattice in self.inlets]
        return tuple(np.concatenate([p[c] for p in parts]) for c in range(3))

    def created(self, t: float) -> int:
        """Rows the inlets have made by time t, the initial ones included."""
        return sum(len(lat.nodes) * lat.layers(t) for lat in self.inlets)

    def ids_valid(self, ids: np.ndarray, t: float) -> bool:
        """Every id is one a particle of this run can have at time t (a block's, or an inlet's made by t)."""
        ok = (ids >= 0) & (ids < self.n_initial)
        for lat in self.inlets:
            ok |= (ids >= lat.base) & (ids < lat.base + len(lat.nodes) * lat.layers(t))
        return bool(ok.all())

    def past_outlets(self, x: np.ndarray) -> np.ndarray:
        """Rows beyond an outlet's far face, within its cross-section."""
        gone = np.zeros(len(x), dtype=bool)
        for axis, sign, face, lo, hi in self.outlets:
            across = [d for d in range(self.dim) if d != axis]
            within = np.all((x[:, across] >= lo[across]) & (x[:, across] < hi[across]), axis=1)
            gone |= within & (sign * (x[:, axis] - face) >= 0.0)
        return gone

    def after_step(self, sim, halo, t0: float, t1: float):
        """Generator, at the end of the step from t0 to t1: remove this peer's rows past an outlet, add
        the inlets' layers made between t0 and t1 that its block owns, and update the global count."""
        s = sim.state
        n = s.n_owned
        gone = self.past_outlets(s.x[:n]) if self.outlets else np.zeros(n, dtype=bool)
        made = [(lat, lat.layers(t0), lat.layers(t1)) for lat in self.inlets]
        new = [lat.rows(k0, k1, t1) for lat, k0, k1 in made if k1 > k0]
        added = sum(len(r[0]) for r in new)
        ids, x, v = (np.concatenate([r[c] for r in new]) for c in range(3)) if new else (np.zeros(0, np.int64),) * 3
        if len(ids):
            mine = halo.owns(sim, x)
            ids, x, v = ids[mine], x[mine], v[mine]
        if gone.any() or len(ids):
            sim.state = with_new_owned(s, ~gone, ids, x.reshape(-1, 3), v.reshape(-1, 3), sim.model.mass,
                                       sim.prm.rho0)
        removed = yield from halo.reduce_sum(sim, "outflow", int(gone.sum()))
        self.inflow += added
        self.outflow += removed
        sim.n_particles += added - removed

    def summary(self) -> dict:
        return {"inlets": len(self.inlets), "outlets": len(self.outlets), "added": self.inflow,
                "removed": self.outflow}
