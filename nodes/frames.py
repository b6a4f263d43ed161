"""Frames of a running simulation: every ``render.every`` steps a peer renders its own particles into
a framelet (sphcore.render) with a few statistics, for the viewer (nodes/viewer.py).

``FrameMaker`` is the part shared by a peer process (which publishes over Zenoh, only while a
viewer listens) and a single-process run (which hands frames straight to an in-process Viewer).
Rendering is timed as the stage ``render``, so its cost shows in summary.json beside the physics.

The 3D point cloud is on by default: ``render.points_every = k > 0`` sends every k-th particle (by id);
0 picks k so that all peers together send about ``POINT_BUDGET`` points (the cloud stays cheap to
send, record and draw whatever the particle count). The points carry the colours of the composite.
A frame's statistics also name the camera and the colouring in use, so that the viewer follows
``sph control camera NAME`` and ``color_by`` (outline, point of view, legend).

The live surface (``render.surface``): every ``render.surface_every`` frames each peer samples the
colour field (sphcore/surface.py) on the nodes of one global lattice (``surface_lattice``: the
domain box's corner + i * step, the same on every process) that lie in its own block, from its owned
particles and ghosts, so every node belongs to exactly one peer and its value needs no neighbour's
help (a node's particles lie within H of it: in the block or its ghost zone). The ghosts hold the
positions of the step's start, the owned rows its end: near a cut the field lags by one step's
motion (under a CFL fraction of a spacing). It travels as uint8 (c x ``SURFACE_SCALE``) cropped to
the nodes where c > 0; the viewer assembles the pieces and extracts one mesh (nodes/viewer.py).
"""
from __future__ import annotations

import math
import time

import numpy as np

from sphcore.render import SceneRenderer

POINT_BUDGET = 3000  # points of the 3D cloud per frame, all peers together, when render.points_every = 0
SURFACE_SCALE = 128  # the colour field on the wire: uint8 round(c x 128), so the 0.5 level is 64


def points_stride(points_every: int, particles_total: int) -> int:
    """Every how many particles (by id) one goes into the 3D point cloud."""
    if points_every > 0:
        return points_every
    return max(1, -(-particles_total // POINT_BUDGET))


MAX_EVENTS = 20  # event-log lines a peer sends with one frame


def surface_wanted(scene, particles_total: int) -> bool:
    """render.surface: on, off, or auto (on up to SURFACE_AUTO_MAX particles)."""
    from sphcore.scene import SURFACE_AUTO_MAX
    mode = scene.render.surface
    return mode == "on" or (mode == "auto" and particles_total <= SURFACE_AUTO_MAX)


def surface_lattice(scene, box, particles_total: int) -> tuple[np.ndarray, float, np.ndarray]:
    """(origin (3,) m, step m, shape (3,) nodes) of the live surface's lattice over the domain box
    ``box`` (domain_box); one node layer in z in 2D, at z = 0 where the particles are. The step is
    render.surface_step spacings, or with 0 one spacing up to SURFACE_NODES particles and above
    that as many nodes in the fluid as SURFACE_NODES: the mesh's size and cost stay bounded however
    many particles (a coarser step smooths the surface more)."""
    from sphcore.scene import SURFACE_NODES
    lo, hi = (np.asarray(b, dtype=np.float64) for b in box)
    n = particles_total if isinstance(particles_total, int) and particles_total > 0 else 1  # (off the wire too)
    spacings = scene.render.surface_step or max(1.0, (n / SURFACE_NODES) ** (1.0 / scene.dim))
    step = spacings * scene.particles.spacing
    origin = lo.copy()
    shape = np.floor((hi - lo) / step + 1e-9).astype(np.int64) + 1
    if scene.dim == 2:
        origin[2], shape[2] = 0.0, 1
    return origin, float(step), shape


def surface_piece(sim, lattice, block) -> tuple[np.ndarray, np.ndarray] | None:
    """(offset (3,) int64 node index, field (a, b, c) uint8) of the colour field on this peer's
    nodes of ``lattice`` (those in ``block`` = (lo, hi) m, or all of them), cropped to where it is
    > 0; None if it is 0 on all of them."""
    from sphcore.surface import colour_field
    origin, step, shape = lattice
    if block is None:
        i0, i1 = np.zeros(3, dtype=np.int64), shape.copy()
    else:  # nodes in [lo, hi): the neighbour's lo is this block's hi, computed alike, so no node is taken twice
        lo, hi = (np.asarray(b, dtype=np.float64) for b in block)
        i0 = np.clip(np.ceil((lo - origin) / step), 0, shape).astype(np.int64)
        i1 = np.clip(np.ceil((hi - origin) / step), 0, shape).astype(np.int64)
        if sim.scene.dim == 2:
            i0[2], i1[2] = 0, 1
    if np.any(i1 <= i0):
        return None
    s = sim.state
    vol = s.m / np.where(s.rho > 0, s.rho, sim.prm.rho0)
    field, _ = colour_field(s.x, vol, origin + i0 * step, origin + (i1 - 1) * step, step, int(sim.kernel), sim.H,
                            sim.scene.dim)
    want = tuple(int(v) for v in i1 - i0)
    field = np.pad(field, [(0, max(0, w - f)) for w, f in zip(want, field.shape)])[:want[0], :want[1], :want[2]]
    q = np.clip(np.rint(field * SURFACE_SCALE), 0, 255).astype(np.uint8)
    nonzero = [np.flatnonzero(q.any(axis=tuple(b for b in range(3) if b != a))) for a in range(3)]
    if any(len(n) == 0 for n in nonzero):
        return None
    cut = tuple(slice(int(n[0]), int(n[-1]) + 1) for n in nonzero)
    return (i0 + np.array([c.start for c in cut], dtype=np.int64)), np.ascontiguousarray(q[cut])


class FrameMaker:
    def __init__(self, scene, box, rank: int, world: int, particles_total: int):
        self.renderer = SceneRenderer(scene, *box, world)
        # the live surface's lattice (None: off), and this peer's block (lo, hi) m, None for the whole
        # domain; nodes/driver.py sets ``block_box`` for a peer, whose block moves when it rebalances
        self.lattice = (surface_lattice(scene, box, particles_total) if surface_wanted(scene, particles_total)
                        else None)
        self.surface_every = scene.render.surface_every
        self.block_box = lambda: None
        self.every = scene.render.every
        self.points_every = points_stride(scene.render.points_every, particles_total)
        self.rank, self.world, self.particles_total = rank, world, particles_total
        self._seen = {}  # stage -> samples already summarised
        self.controls = []  # control commands applied since the last frame (logged by the viewer)
        # (level, text) since the last frame for the viewer's event log: rebalances, restarts and this
        # peer's warnings (nodes/driver.py adds them); at most MAX_EVENTS per frame, then a count
        self.events = []
        self.events_dropped = 0
        self.exchange_bytes = None  # the halo's array bytes sent per exchange (sphcore/halo.py), if any

    def event(self, level: str, text: str):
        """Queue a line for the viewer's event log (level INFO, WARN or ERROR)."""
        if len(self.events) < MAX_EVENTS:
            self.events.append([level, text])
        else:
            self.events_dropped += 1

    def _take_events(self) -> list:
        events, self.events = self.events, []
        if self.events_dropped:
            events.append(["WARN", f"{self.events_dropped} more events since the last frame not shown"])
            self.events_dropped = 0
        return events

    def due(self, sim) -> bool:
        return self.every > 0 and sim.step_index % self.every == 0

    def surface_due(self, sim) -> bool:
        """Whether this frame carries the live surface (the same frames on every peer): the first frame
        after step 0 and every surface_every-th after it, so the surface shows from the start."""
        return self.lattice is not None and (sim.step_index // self.every - 1) % self.surface_every == 0

    def make(self, sim, bytes_sent: int = 0):
        """(framelet, stats, points, surface) of this peer's owned particles now; points: (positions
        (k, 3), colours (k, 3) uint8) of every points_every-th particle; surface: ``surface_piece``
        on the frames that carry the live surface (stats "surface" is then true), else None."""
        s = sim.state
        n = s.n_owned
        with sim.timers("render"):
            frame = self.renderer.framelet(self.rank, s.x[:n], s.v[:n], s.rho[:n], s.p[:n], s.id[:n])
            pick = np.nonzero(s.id[:n] % self.points_every == 0)[0]
            points = (s.x[pick], np.ascontiguousarray(self.renderer.base_colours(self.rank, s.v[pick], s.rho[pick],
                                                                                 s.p[pick]), dtype=np.uint8))
        surface, with_surface = None, self.surface_due(sim)
        if with_surface:
            with sim.timers("surface"):
                surface = surface_piece(sim, self.lattice, self.block_box())
        stage_ms = {}
        for name, samples in sim.timers.samples.items():
            first = self._seen.get(name, 0)
            if first > len(samples):  # timers were reset
                first = 0
            if len(samples) > first:
                stage_ms[name] = 1e3 * float(np.mean(samples[first:]))
            self._seen[name] = len(samples)
        dev = float(np.max(s.rho[:n]) / sim.prm.rho0 - 1.0) if n else 0.0
        stats = {"step": sim.step_index, "sim_time": sim.t, "world": self.world, "particles": n,
                 "particles_total": self.particles_total, "stage_ms": stage_ms, "bytes_sent": int(bytes_sent),
                 "kinetic_energy": sim.kinetic_energy(), "max_density_deviation": dev, "wall_time": time.time(),
                 "controls": self.controls, "camera": self.renderer.camera_name,
                 "events": self._take_events(),
                 "bytes_by_exchange": {k: int(v) for k, v in (self.exchange_bytes or {}).items()},
                 "color_by": self.renderer.quantity, "range": [float(v) for v in self.renderer.range],
                 "bodies": body_displacements(sim), "surface": with_surface}
        samples = sim.probes.take_samples()  # every peer has the same values: rank 0's frame carries them
        if samples and self.rank == 0:
            stats["probes"] = {"names": sim.probes.names,
                               "samples": [[step, t, [float(v) if math.isfinite(v) else None for v in values]]
                                           for step, t, values in samples]}
        self.controls = []
        return frame, stats, points, surface


def body_displacements(sim) -> dict:
    """{obstacle index: [x, y, z]}: how far each floating body has moved, then, for one that turns, its
    orientation R row by row (9 more numbers): the viewer draws it there."""
    walls = sim.model.walls
    first = walls.container_walls + len(sim.scene.domain.planes)  # the obstacles' rows follow the planes'
    return {str(b.wall - first): [float(c) for c in (*b.x, *(b.R.ravel() if b.rotates else ()))] for b in walls.bodies}


def domain_box(scene):
    """The box drawn around the fluid and framed by the default camera: the walls' bounds."""
    from sphcore.boundaries import build_walls
    from sphcore.choices import KERNELS
    walls = build_walls(scene, KERNELS[scene.sph.kernel], scene.sph.support * scene.particles.spacing, np.float64)
    return walls.lo.astype(np.float64), walls.hi.astype(np.float64)
