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
"""
from __future__ import annotations

import math
import time

import numpy as np

from sphcore.render import SceneRenderer

POINT_BUDGET = 3000  # points of the 3D cloud per frame, all peers together, when render.points_every = 0


def points_stride(points_every: int, particles_total: int) -> int:
    """Every how many particles (by id) one goes into the 3D point cloud."""
    if points_every > 0:
        return points_every
    return max(1, -(-particles_total // POINT_BUDGET))


MAX_EVENTS = 20  # event-log lines a peer sends with one frame


class FrameMaker:
    def __init__(self, scene, box, rank: int, world: int, particles_total: int):
        self.renderer = SceneRenderer(scene, *box, world)
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

    def make(self, sim, bytes_sent: int = 0):
        """(framelet, stats, points) of this peer's owned particles now; points: (positions (k, 3),
        colours (k, 3) uint8) of every points_every-th particle."""
        s = sim.state
        n = s.n_owned
        with sim.timers("render"):
            frame = self.renderer.framelet(self.rank, s.x[:n], s.v[:n], s.rho[:n], s.p[:n], s.id[:n])
            pick = np.nonzero(s.id[:n] % self.points_every == 0)[0]
            points = (s.x[pick], np.ascontiguousarray(self.renderer.base_colours(self.rank, s.v[pick], s.rho[pick],
                                                                                 s.p[pick]), dtype=np.uint8))
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
                 "bodies": body_displacements(sim)}
        samples = sim.probes.take_samples()  # every peer has the same values: rank 0's frame carries them
        if samples and self.rank == 0:
            stats["probes"] = {"names": sim.probes.names,
                               "samples": [[step, t, [float(v) if math.isfinite(v) else None for v in values]]
                                           for step, t, values in samples]}
        self.controls = []
        return frame, stats, points


def body_displacements(sim) -> dict:
    """{obstacle index: [x, y, z]}: how far each floating body has moved (the viewer draws it there)."""
    walls = sim.model.walls
    first = walls.container_walls + len(sim.scene.domain.planes)  # the obstacles' rows follow the planes'
    return {str(b.wall - first): [float(c) for c in b.x] for b in walls.bodies}


def domain_box(scene):
    """The box drawn around the fluid and framed by the default camera: the walls' bounds."""
    from sphcore.boundaries import build_walls
    from sphcore.choices import KERNELS
    walls = build_walls(scene, KERNELS[scene.sph.kernel], scene.sph.support * scene.particles.spacing, np.float64)
    return walls.lo.astype(np.float64), walls.hi.astype(np.float64)
