"""The viewer: composites the peers' framelets by depth (sort-last) and streams to Rerun.

``Viewer`` does the compositing and logging; it is fed either directly (a single-process run
renders its own frames) or by ``run_viewer``, a process that subscribes to every peer's framelets
over Zenoh (``sph/<run>/frame/<rank>``). Peers never wait for the viewer: framelets are published
with ``CongestionControl.DROP`` and only while a viewer is subscribed; a frame whose framelets do
not all arrive within ``frame_timeout`` seconds (or before a later frame completes) is composited
from what arrived and marked (``composite/status``).

Rerun entities (timelines ``step`` and ``sim_time``):

    composite/rgb, composite/depth          the composited image and its depth (m along the view axis)
    composite/peers                         each peer's framelet rectangle, labelled by rank
    composite/status                        a text log line for every incomplete frame
    peers/<rank>/rgb                        each peer's framelet
    fluid/points                            every k-th particle, coloured by peer (render.points_every)
    stats/...                               per-peer particles, stage milliseconds, bytes sent; kinetic
                                            energy, max density deviation, frames/s, composite latency
    domain (static)                         the domain box
    info (static)                           the scene's physical parameters and the number of peers
"""
from __future__ import annotations

import json
import logging
import threading
import time
from pathlib import Path

import numpy as np

from nodes import wire
from nodes.rerun_sinks import sinks_for
from nodes.zenoh_transport import zenoh_config
from sphcore.output import write_summary
from sphcore.render import RANK_COLOURS, Framelet, SceneRenderer

log = logging.getLogger("sph.viewer")


def open_recording(run_id: str, record: Path | None = None, spawn: bool = False, serve_web: bool = False,
                   connect: str | None = None, grpc_port: int | None = None, web_port: int | None = None):
    """A Rerun recording stream that goes to every destination asked for at once (nodes/rerun_sinks.py:
    the file, the native viewer, the web viewer on loopback, a URL); analytics stay off
    (RERUN_ANALYTICS=0 is set by the launcher; ``rerun analytics disable`` makes it permanent)."""
    import rerun as rr

    rec = rr.RecordingStream("sphfluid", recording_id=run_id)
    sinks = sinks_for(record, spawn, serve_web, connect, grpc_port, web_port,
                      announce=lambda text: print(text, flush=True))
    if sinks:
        rec.set_sinks(*sinks)
    return rec


def info_text(scene, particles: int, world: int) -> str:
    s, t, f = scene.sph, scene.time, scene.forces
    visc = {"artificial": f"artificial, alpha = {s.alpha:g}", "none": "none"}.get(s.viscosity,
                                                                                 f"{s.viscosity}, nu = {s.nu:g} m²/s")
    return "\n".join([
        f"# {scene.scene.name}", "", scene.scene.description, "",
        f"- particles: {particles:,}  ·  peers: {world}  ·  spacing: {scene.particles.spacing:g} m",
        f"- kernel: {s.kernel}, support {s.support:g} spacings  ·  EOS: {s.eos}, c0 = {s.sound_speed:g} m/s",
        f"- rest density: {scene.fluid.rest_density:g} kg/m³  ·  viscosity: {visc}",
        f"- gravity: {list(f.gravity)} m/s²  ·  external: {list(f.external)} m/s²",
        f"- time: {t.integrator}, {t.mode} dt (max {t.dt:g} s, CFL {t.cfl:g})",
        f"- colour: {scene.render.color_by}",
    ])


class Viewer:
    """Composites frames of ``world`` peers and logs them to ``rec`` (a Rerun RecordingStream)."""

    def __init__(self, scene, box, rec, world: int = 1, particles: int = 0, frame_timeout: float = 2.0):
        import rerun as rr
        self.rr, self.rec, self.scene = rr, rec, scene
        self.world = world
        self.renderer = SceneRenderer(scene, *box, world)
        self.frame_timeout = frame_timeout
        self.pending = {}        # step -> {"parts": {rank: (framelet, stats, points)}, "since": time}
        self.frames = 0
        self.incomplete = 0
        self.latency_ms = []
        self._last_emit = None
        self._lock = threading.Lock()
        lo, hi = self.renderer.box
        rec.log("domain", rr.Boxes3D(mins=[lo], sizes=[hi - lo], colors=[[200, 200, 200]]), static=True)
        rec.log("info", rr.TextDocument(info_text(scene, particles, world), media_type=rr.MediaType.MARKDOWN),
                static=True)

    def add(self, step: int, rank: int, frame: Framelet, stats: dict, points=None):
        """One peer's framelet of ``step``; composites when all peers' framelets are in."""
        with self._lock:
            entry = self.pending.setdefault(step, {"parts": {}, "since": time.perf_counter()})
            entry["parts"][rank] = (frame, stats, points)
            if len(entry["parts"]) == self.world:
                for older in sorted(s for s in self.pending if s < step):  # a later frame is complete
                    self._emit(older)
                self._emit(step)

    def expire(self, now: float | None = None):
        """Composite frames that waited longer than frame_timeout (marked incomplete)."""
        now = time.perf_counter() if now is None else now
        with self._lock:
            for step in sorted(self.pending):
                if now - self.pending[step]["since"] > self.frame_timeout:
                    self._emit(step)

    def flush(self):
        with self._lock:
            for step in sorted(self.pending):
                self._emit(step)

    def _emit(self, step: int):
        rr, rec = self.rr, self.rec
        parts = self.pending.pop(step)["parts"]
        ranks = sorted(parts)
        stats = {r: parts[r][1] for r in ranks}
        sim_time = max(s["sim_time"] for s in stats.values())
        rec.set_time("step", sequence=step)
        rec.set_time("sim_time", duration=sim_time)
        frames = [parts[r][0] for r in ranks]
        rgb, depth, _ = self.renderer.image(frames)
        rec.log("composite/rgb", rr.Image(rgb))
        rec.log("composite/depth", rr.DepthImage(np.where(np.isfinite(depth), depth, 0.0).astype(np.float32),
                                                 meter=1.0))
        boxes = [f for f in frames if f.w and f.h]
        if boxes:
            rec.log("composite/peers", rr.Boxes2D(mins=[[f.x0, f.y0] for f in boxes], sizes=[[f.w, f.h] for f in boxes],
                                                  labels=[f"peer {f.rank}" for f in boxes],
                                                  colors=[RANK_COLOURS[f.rank % len(RANK_COLOURS)] for f in boxes]))
        for f in frames:
            if f.w and f.h:
                rec.log(f"peers/{f.rank}/rgb", rr.Image(f.rgb))
        for text in stats[ranks[0]].get("controls", []):  # every peer applied it; log it once
            rec.log("control", rr.TextLog(text, level="INFO"))
        missing = sorted(set(range(self.world)) - set(ranks))
        if missing:
            self.incomplete += 1
            rec.log("composite/status", rr.TextLog(f"step {step}: incomplete frame, no framelet from peer(s) "
                                                   f"{missing}", level="WARN"))
        pts = [(r, parts[r][2]) for r in ranks if parts[r][2] is not None and len(parts[r][2])]
        if pts:
            rec.log("fluid/points", rr.Points3D(np.concatenate([p for _, p in pts]),
                                                colors=np.concatenate([np.broadcast_to(
                                                    RANK_COLOURS[r % len(RANK_COLOURS)], (len(p), 3)) for r, p in pts]),
                                                radii=0.5 * self.renderer.radius))
        for r, s in stats.items():
            rec.log(f"stats/particles/peer{r}", rr.Scalars(s["particles"]))
            rec.log(f"stats/bytes_sent_mb/peer{r}", rr.Scalars(s["bytes_sent"] / 1e6))
            for stage, ms in s["stage_ms"].items():
                rec.log(f"stats/stage_ms/{stage}/peer{r}", rr.Scalars(ms))
        rec.log("stats/kinetic_energy", rr.Scalars(sum(s["kinetic_energy"] for s in stats.values())))
        rec.log("stats/max_density_deviation", rr.Scalars(max(s["max_density_deviation"] for s in stats.values())))
        now = time.time()
        latency = 1e3 * (now - max(s["wall_time"] for s in stats.values()))
        self.latency_ms.append(latency)
        rec.log("stats/composite_latency_ms", rr.Scalars(latency))
        if self._last_emit is not None and now > self._last_emit:
            rec.log("stats/fps", rr.Scalars(1.0 / (now - self._last_emit)))
        self._last_emit = now
        self.frames += 1


# -- the wire side --------------------------------------------------------------------------------
def frame_arrays(frame: Framelet, stats: dict, points=None) -> dict:
    arrays = {"rect": np.array([frame.x0, frame.y0, frame.w, frame.h], dtype=np.int64), "rgb": frame.rgb,
              "depth": frame.depth, "id": frame.id,
              "stats": np.frombuffer(json.dumps(stats).encode(), dtype=np.uint8)}
    if points is not None:
        arrays["points"] = np.ascontiguousarray(points, dtype=np.float32)
    return arrays


def frame_from_arrays(rank: int, a: dict):
    """(framelet, stats, points) from a decoded message; ValueError if the parts do not fit."""
    x0, y0, w, h = (int(v) for v in a["rect"])
    if a["rgb"].shape != (h, w, 3) or a["depth"].shape != (h, w) or a["id"].shape != (h, w):
        raise ValueError(f"framelet planes do not match its rectangle {w} x {h}")
    stats = json.loads(bytes(a["stats"]).decode())
    points = a.get("points")
    if points is not None and (points.ndim != 2 or points.shape[1] != 3):
        raise ValueError("points must be (n, 3)")
    return Framelet(rank, x0, y0, a["rgb"], a["depth"], a["id"]), stats, points


def run_viewer(scene, run_id: str, listen: list[str], connect: list[str], rec, box, world: int | None,
               particles: int, ready=None, idle_timeout: float | None = None, grace: float = 1.0,
               stats_path: Path | None = None, trust=None) -> int:
    """Subscribe to the run's framelets until rank 0 announces the end (or Ctrl-C); returns frames.
    ``trust``: the viewer's credentials (nodes/security.py), None for an --insecure run."""
    import zenoh

    done = threading.Event()
    state = {"viewer": None, "last": time.perf_counter()}

    def on_frame(sample):
        try:
            source, (step, phase), arrays = wire.decode(sample.payload.to_bytes(), run_id, wire.VIEWER, 1 << 20)
            if phase == "end":
                done.set()
                return
            frame, stats, points = frame_from_arrays(source, arrays)
        except (wire.WireError, ValueError, KeyError) as e:
            log.warning("viewer: dropped a message on %s: %s", sample.key_expr, e)
            return
        state["last"] = time.perf_counter()
        if state["viewer"] is None:
            n = world or int(stats["world"])
            state["viewer"] = Viewer(scene, box, rec, n, stats.get("particles_total", particles))
        state["viewer"].add(step, source, frame, stats, points)

    session = zenoh.open(zenoh_config(listen, connect, trust=trust))
    try:
        session.declare_subscriber(wire.frame_all(run_id), on_frame)
        if ready is not None:
            ready()
        while not done.wait(0.2):
            if state["viewer"] is not None:
                state["viewer"].expire()
            if idle_timeout and time.perf_counter() - state["last"] > idle_timeout:
                log.warning("viewer: no frames for %g s; stopping", idle_timeout)
                break
        if done.is_set():
            time.sleep(grace)  # framelets still on their way from the other peers
    finally:
        if state["viewer"] is not None:
            state["viewer"].flush()
        session.close()
        rec.flush()
    v = state["viewer"]
    if stats_path is not None and v is not None:
        write_summary(stats_path, {"frames": v.frames, "incomplete_frames": v.incomplete,
                                   "composite_latency_ms": {"median": float(np.median(v.latency_ms)),
                                                            "max": float(np.max(v.latency_ms))},
                                   "note": "latency: from the newest framelet's publication to the composite "
                                           "being logged (same-machine clocks)"})
    return 0 if v is None else v.frames
