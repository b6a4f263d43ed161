"""The viewer: composites the peers' framelets by depth (sort-last) and streams to Rerun.

``Viewer`` does the compositing and logging; it is fed either directly (a single-process run
renders its own frames) or by ``run_viewer``, a process that subscribes to every peer's framelets
over Zenoh (``sph/<run>/frame/<rank>``). Peers never wait for the viewer: framelets are published
with ``CongestionControl.DROP`` and only while a viewer is subscribed; a frame whose framelets do
not all arrive within ``frame_timeout`` seconds (or before a later frame completes) is composited
from what arrived and marked (``composite/status``).

The viewer never waits for Rerun either. Complete frames go into a short queue that one writer
thread composites, encodes and logs; when the queue is full (compositing and encoding cannot keep
up) the oldest waiting frame is dropped and counted (``stats/dropped_frames``, summary.json's viewer
section), so what is shown stays close to the simulation instead of falling ever further behind.
The recording file and live viewers are separate streams (nodes/rerun_sinks.Streams): a live viewer
that is slow or stopped reading loses frames (the newest is sent, at most ``--live-fps`` per second)
but never holds up the file or the writer. The control commands a dropped frame carried are logged
with the next frame. Images are compressed: the composite's RGB as JPEG (quality ``RGB_QUALITY``),
each peer's framelet as JPEG (``PEER_QUALITY``), the depth as a 16-bit PNG
(lossless, depth quantised to 1/60000 of the frame's farthest sample).

A blueprint (``blueprint()``) is sent first: the composite large with its RGB visible and its depth
hidden (one click shows it), a navigable 3D view (domain, container, obstacles and meshes, the point
cloud coloured like the composite), a legend of the colour map and its range, the scene's info, an
event log, and the statistics in a few plots.

Rerun entities (timelines ``step`` and ``sim_time``):

    composite/rgb, composite/depth          the composited image (JPEG) and its depth (16-bit PNG, meter)
    composite/peers                         each peer's framelet rectangle, labelled by rank
    composite/legend, composite/legend_label    the colour bar under the image, labelled with the range
    composite/status                        a text log line for every incomplete frame
    peers/<rank>/rgb                        each peer's framelet (JPEG)
    fluid/points                            the 3D point cloud (render.points_every; 0 = a point budget)
    fluid/surface                           the live fluid surface (render.surface): a mesh (3D) or lines
                                            (2D), every render.surface_every frames
    camera                                  the camera the frames are rendered with (pinhole + pose)
    control                                 the control commands applied (sph control)
    events                                  camera and colour switches, dropped frames; each peer's
                                            rebalances, restarts and warnings ("peer r: ...")
    probes/<name>                           the scene's [[probes]] (Pa or m), each sample at its own step
    stats/...                               per-peer particles (and imbalance), stage milliseconds, bytes
                                            sent (all, and per exchange: stats/exchange_mb/<exchange>);
                                            kinetic energy, max density deviation, frames/s,
                                            composite latency, dropped frames (recording; live)
    domain, container, obstacles/<i> (static)   the domain box and the walls as meshes
    inlets/<i>, outlets/<i> (static)        the open boundaries' zones as boxes (green in, orange out)
    damping_zones/<i> (static)              the damping zones as boxes (blue)
    info, legend                            the scene's physical parameters (updated after control set),
                                            the colouring and its range
"""
from __future__ import annotations

import ast
import dataclasses
import io
import json
import logging
import math
import queue
import re
import threading
import time
from pathlib import Path

import numpy as np

from nodes import wire
from nodes.frames import SURFACE_SCALE, surface_lattice
from nodes.rerun_sinks import LIVE_FPS, Streams, sinks_for
from nodes.walls_view import (body_shifts, body_transform, floating_obstacles, merge_layer, moving_obstacles,
                               obstacle_distance, obstacle_layer, obstacle_transform, wall_meshes)
from nodes.zenoh_transport import zenoh_config
from sphcore.output import write_summary
from sphcore.render import LUT, RANK_COLOURS, Framelet, SceneRenderer, composite, draw_box
from sphcore.scene import artificial_alpha

log = logging.getLogger("sph.viewer")

RGB_QUALITY = 90      # JPEG quality of the composite's RGB
PEER_QUALITY = 75     # JPEG quality of each peer's framelet (a diagnostic view)
DEPTH_STEPS = 60000   # the frame's farthest sample maps to this 16-bit value (0 = no sample)
QUEUE_FRAMES = 3      # complete frames waiting for the writer; more and the oldest is dropped
UNITS = {"speed": "m/s", "density": "kg/m³", "pressure": "Pa", "rank": ""}


def open_recording(run_id: str, record: Path | None = None, spawn: bool = False, serve_web: bool = False,
                   connect: str | None = None, grpc_port: int | None = None, web_port: int | None = None,
                   live_fps: float = LIVE_FPS) -> Streams:
    """The viewer's Rerun output to every destination asked for at once (nodes/rerun_sinks.py: the
    file, the native viewer, the web viewer on loopback, a URL): one stream for the file and one for
    the live sinks, so a live viewer never holds up the recording; analytics stay off
    (RERUN_ANALYTICS=0 is set by the launcher; ``rerun analytics disable`` makes it permanent)."""
    import rerun as rr

    file_sink, live_sinks = sinks_for(record, spawn, serve_web, connect, grpc_port, web_port,
                                      announce=lambda text: print(text, flush=True))
    file = live = None
    if file_sink is not None:
        file = rr.RecordingStream("sphfluid", recording_id=run_id)
        file.set_sinks(file_sink)
    if live_sinks:
        live = rr.RecordingStream("sphfluid", recording_id=run_id)
        live.set_sinks(*live_sinks)
    return Streams(file, live, live_fps)


def info_text(scene, particles: int, world: int, changes=()) -> str:
    s, t, f = scene.sph, scene.time, scene.forces
    alpha = (f"alpha = {artificial_alpha(scene):.4g} (nu = {s.alpha_nu:g} m²/s)" if s.alpha_nu > 0
             else f"alpha = {s.alpha:g}") + (", Balsara's switch" if s.viscosity_switch == "balsara" else "")
    visc = {"artificial": f"artificial, {alpha}", "none": "none"}.get(s.viscosity,
                                                                      f"{s.viscosity}, nu = {s.nu:g} m²/s")
    lines = [
        f"# {scene.scene.name}", "", scene.scene.description, "",
        f"- particles: {particles:,}  ·  peers: {world}  ·  spacing: {scene.particles.spacing:g} m",
        f"- kernel: {s.kernel}, support {s.support:g} spacings  ·  EOS: {s.eos}, c0 = {s.sound_speed:g} m/s",
        f"- rest density: {scene.fluid.rest_density:g} kg/m³  ·  viscosity: {visc}",
        f"- gravity: {list(f.gravity)} m/s²  ·  external: {list(f.external)} m/s²",
        f"- boundary: friction {scene.boundary.friction:g}, restitution {scene.boundary.restitution:g}",
        f"- time: {t.integrator}, {t.mode} dt (max {t.dt:g} s, CFL {t.cfl:g})",
        f"- colour: {scene.render.color_by}",
    ]
    if any(scene.origin):  # sphcore.scene.scene_origin: positions in this recording are relative to it
        lines.append(f"- coordinates: relative to the scene's origin {list(scene.origin)} m (world = origin + shown)")
    if changes:
        lines += ["", "## Changed during the run", ""] + [f"- step {step}: {text}" for step, text in changes]
    return "\n".join(lines)


def legend_text(quantity: str, lo: float, hi: float) -> str:
    if quantity == "rank":
        return "# Colour: peer rank\n\nEach peer's particles in its own colour (Tableau 10; peer 0 blue)."
    unit = UNITS[quantity]
    return (f"# Colour: {quantity}\n\nviridis from dark purple = {lo:.4g} {unit} to yellow = {hi:.4g} {unit} "
            "(clamped outside; `render.range`, or `sph control color_by`)")


def apply_setting(scene, text: str):
    """The scene after a control line ``set KEY = VALUE`` (as nodes/control.py describes it), or
    ``scene`` unchanged for any other line or a value that does not read back."""
    m = re.fullmatch(r"set (\w+)\.(\w+) = (.+)", text)
    if not m:
        return scene
    section, name, raw = m.groups()
    try:
        value = ast.literal_eval(raw)
        part = dataclasses.replace(getattr(scene, section), **{name: tuple(value) if isinstance(value, list)
                                                              else value})
        return dataclasses.replace(scene, **{section: part})
    except (ValueError, SyntaxError, TypeError, AttributeError):
        return scene


def encode_jpeg(rgb: np.ndarray, quality: int) -> bytes:
    from PIL import Image
    out = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb)).save(out, "JPEG", quality=quality)
    return out.getvalue()


def encode_depth(depth: np.ndarray) -> tuple[bytes, float]:
    """(16-bit PNG, meter: PNG units per metre) of a depth image (inf = no sample -> 0)."""
    from PIL import Image
    finite = np.isfinite(depth) & (depth > 0)
    far = float(depth[finite].max()) if finite.any() else 1.0
    meter = DEPTH_STEPS / far
    values = np.where(finite, np.clip(np.rint(np.where(finite, depth, 0.0) * meter), 1, 65535), 0).astype(np.uint16)
    out = io.BytesIO()
    Image.fromarray(values).save(out, "PNG", compress_level=1)
    return out.getvalue(), meter


def camera_pose(camera):
    """(translation, 3 x 3 rotation: camera axes right, down, forward in world) of a render Camera
    (sphcore.render), in Rerun's RDF pinhole convention."""
    eye, right, up, forward = camera.basis()
    return eye, np.stack([right, -up, forward], axis=1)


def blueprint(scene, world: int, camera=None):
    """The layout sent at the start of a recording: composite large (RGB visible, depth hidden),
    3D view, legend and info, event log, statistics grouped in a few plots."""
    import rerun.blueprint as rrb
    eye = None
    if camera is not None and hasattr(rrb, "EyeControls3D"):
        eye = rrb.EyeControls3D(position=list(camera.eye), look_target=list(camera.target),
                                eye_up=list(camera.up))
    view3d = rrb.Spatial3DView(name="3D (drag to orbit)", origin="/",
                               contents=["/domain", "/container/**", "/obstacles/**", "/inlets/**", "/outlets/**",
                                         "/damping_zones/**", "/fluid/**", "/camera/**"],
                               **({"eye_controls": eye} if eye is not None else {}))
    plots = rrb.Tabs(
        rrb.TimeSeriesView(name="Stage ms per peer", origin="/stats/stage_ms"),
        rrb.TimeSeriesView(name="Particles per peer, imbalance", origin="/stats",
                           contents=["/stats/particles/**", "/stats/imbalance"]),
        rrb.TimeSeriesView(name="MB sent per peer", origin="/stats/bytes_sent_mb"),
        rrb.TimeSeriesView(name="MB per exchange (arrays)", origin="/stats/exchange_mb"),
        rrb.TimeSeriesView(name="Kinetic energy", origin="/stats", contents=["/stats/kinetic_energy"]),
        rrb.TimeSeriesView(name="Max density error", origin="/stats", contents=["/stats/max_density_deviation"]),
        *[rrb.TimeSeriesView(name=f"Probes: {title}", origin="/probes",
                             contents=[f"/probes/{p.name}" for p in scene.probes if p.kind == kind])
          for kind, title in (("pressure", "pressure (Pa)"), ("height", "surface height (m)"))
          if any(p.kind == kind for p in scene.probes)],
        rrb.TimeSeriesView(name="Viewer: latency ms, frames/s, dropped", origin="/stats",
                           contents=["/stats/composite_latency_ms", "/stats/fps", "/stats/dropped_frames",
                                     "/stats/live_dropped_frames"]),
        name="Statistics")
    composite = rrb.Spatial2DView(name="Composite", origin="/composite",
                                  overrides={"/composite/depth": rrb.EntityBehavior(visible=False)})
    events = rrb.TextLogView(name="Events", origin="/", contents=["/control", "/events", "/composite/status"])
    notes = rrb.Tabs(rrb.TextDocumentView(name="Legend", origin="/legend"),
                     rrb.TextDocumentView(name="Scene", origin="/info"), name="Legend and scene")
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(composite, rrb.Horizontal(events, notes), row_shares=[4, 1]),
            rrb.Vertical(view3d, plots, row_shares=[1, 1]),
            column_shares=[3, 2]),
        collapse_panels=True)


_HELD = []  # recording streams stuck on a live viewer that stopped reading: never dropped (dropping flushes)


def let_rerun_go(rec=None):
    """Do not wait for a stalled live viewer: Rerun flushes a stream without a time limit when it
    is dropped and at exit, so a viewer that stopped reading would hold this process for ever.
    The stream is kept (not dropped) and Rerun's exit hook removed; ``exit_now`` ends the process."""
    import atexit

    import rerun
    atexit.unregister(rerun.rerun_shutdown)
    if rec is not None:
        _HELD.append(rec)


def exit_now(code: int, message: str):
    """End a process whose Rerun stream is stuck (``_HELD``), its outputs written: say why, flush the
    standard streams, exit without running the finalizers that would wait for the stream."""
    import os
    import sys
    print(message, file=sys.stderr, flush=True)
    sys.stdout.flush()
    logging.shutdown()
    os._exit(code)


class Viewer:
    """Composites frames of ``world`` peers and logs them to ``rec`` (``Streams``, or one Rerun
    RecordingStream logged in the writer thread). ``announce``: where the recording size estimate
    goes (a line after the first frame)."""

    def __init__(self, scene, box, rec, world: int = 1, particles: int = 0, frame_timeout: float = 2.0,
                 queue_frames: int = QUEUE_FRAMES, expected_frames: int | None = None, announce=None,
                 record: Path | None = None):
        import rerun as rr
        self.rr, self.rec, self.scene = rr, rec if isinstance(rec, Streams) else Streams(rec), scene
        rec = self.rec
        self.world, self.particles = world, particles
        self.renderer = SceneRenderer(scene, *box, world)
        self.frame_timeout = frame_timeout
        self.expected_frames, self.announce, self.record = expected_frames, announce, record
        self.pending = {}        # step -> {"parts": {rank: (framelet, stats, points)}, "since": time}
        self.frames = 0          # frames logged
        self.incomplete = 0
        self.dropped = 0         # complete frames dropped because the writer was behind
        self.stalled = False     # the live viewer did not take the last frames at the end (it stopped reading)
        self.latency_ms = []     # per logged frame: newest framelet's publication -> logged
        self.frame_bytes = []    # per logged frame: bytes of its encoded images and points
        self.changes = []        # (step, control text) of the settings changed
        self._last_emit = None
        self._carried = []       # control lines of dropped frames, logged with the next frame
        self._layers = {}        # camera name -> the obstacles' (rgb, depth) seen from it (walls_view.py)
        self._obstacle_sdf = None  # the obstacles' distance function (walls_view.py); False: none to draw
        self.lattice = surface_lattice(scene, box, particles)  # what a peer's surface piece must fit (frames.py)
        self.surface_ms = []     # per live surface: assembling the pieces and extracting the mesh
        self.surface_bytes = []  # per live surface: the mesh's bytes as logged
        self.bad_surfaces = 0    # pieces off the lattice (a peer's frame is data from the network): dropped
        self._lock = threading.Lock()
        self._queue = queue.Queue(maxsize=max(1, queue_frames))
        lo, hi = self.renderer.box
        rec.send_blueprint(blueprint(scene, world, self.renderer.camera))
        rec.log("domain", rr.Boxes3D(mins=[lo], sizes=[hi - lo], colors=[[200, 200, 200]]), static=True)
        for name, zones, colour, label in (("inlets", scene.inlets, [80, 200, 120], "inlet"),
                                           ("outlets", scene.outlets, [230, 120, 60], "outlet"),
                                           ("damping_zones", scene.damping_zones, [90, 140, 230], "damping")):
            for i, z in enumerate(zones):  # the open boundaries' zones (sphcore/open_boundary.py), the damping zones
                zmin, zmax = np.array(z.min, dtype=float), np.array(z.max, dtype=float)
                rec.log(f"{name}/{i}", rr.Boxes3D(mins=[zmin], sizes=[zmax - zmin], colors=[colour],
                                                  labels=[f"{label} {i}"]), static=True)
        try:
            for name, mesh in wall_meshes(scene).items():
                rec.log(name, mesh, static=True)
        except (ImportError, OSError, ValueError) as e:  # a mesh that cannot be read: the run says so itself
            log.warning("viewer: walls not drawn in 3D: %s", e)
        self._log_info()
        self._log_legend()
        self._log_camera()
        self._writer = threading.Thread(target=self._write_loop, name="sph-viewer-writer", daemon=True)
        self._writer.start()

    # -- the producer side (a Zenoh callback, the simulation's thread): never waits for Rerun --------
    def add(self, step: int, rank: int, frame: Framelet, stats: dict, points=None, surface=None):
        """One peer's framelet of ``step`` (its point cloud and live surface piece, if any); queues
        the frame for logging when all peers' are in."""
        with self._lock:
            entry = self.pending.setdefault(step, {"parts": {}, "since": time.perf_counter()})
            entry["parts"][rank] = (frame, stats, points, surface)
            if len(entry["parts"]) == self.world:
                for older in sorted(s for s in self.pending if s < step):  # a later frame is complete
                    self._submit(older)
                self._submit(step)

    def expire(self, now: float | None = None):
        """Queue frames that waited longer than frame_timeout (marked incomplete)."""
        now = time.perf_counter() if now is None else now
        with self._lock:
            for step in sorted(self.pending):
                if now - self.pending[step]["since"] > self.frame_timeout:
                    self._submit(step)

    def _submit(self, step: int, wait: float = 0.0):
        """(Under the lock.) Hand frame ``step`` to the writer; if it is behind, drop the oldest
        waiting frame (``wait`` > 0: wait up to that long for room instead: the end of a run)."""
        item = (step, self.pending.pop(step)["parts"])
        try:
            self._queue.put(item, timeout=wait) if wait > 0 else self._queue.put_nowait(item)
            return
        except queue.Full:
            pass
        try:
            old_step, old_parts = self._queue.get_nowait()
            self._queue.task_done()
            self.dropped += 1
            first = min(old_parts)
            self._carried += old_parts[first][1].get("controls", [])
            if self.dropped == 1 or self.dropped % 50 == 0:
                log.warning("viewer: Rerun is behind, dropped the frame of step %d (%d dropped so far)", old_step,
                            self.dropped)
        except queue.Empty:
            pass
        self._queue.put_nowait(item)

    def flush(self, timeout: float = 60.0):
        """Queue every pending frame and wait (up to ``timeout`` s) until the writer logged them."""
        deadline = time.monotonic() + timeout
        with self._lock:
            for step in sorted(self.pending):
                self._submit(step, wait=max(0.01, deadline - time.monotonic()))
        q = self._queue
        with q.all_tasks_done:
            while q.unfinished_tasks and time.monotonic() < deadline:
                q.all_tasks_done.wait(max(0.01, deadline - time.monotonic()))

    def close(self, timeout: float = 30.0):
        """Flush, stop the writer, then flush the recording (up to ``timeout`` s for a live viewer)
        and close its sinks: the file gets its footer, and its size is final (summary())."""
        self.flush()
        self._queue.put(None)
        self._writer.join(timeout=timeout)
        if not self.rec.close(timeout):  # the file is complete; a live viewer that stopped reading holds its stream
            log.warning("viewer: the live Rerun viewer did not take the last frames within %g s: it stopped "
                        "reading; not waiting for it (the recording file is complete)", timeout)
            self.stalled = True
            let_rerun_go(self.rec)

    def summary(self) -> dict:
        """summary.json's "viewer": frames, drops, latency, recorded size."""
        out = {"frames": self.frames, "incomplete_frames": self.incomplete, "dropped_frames": self.dropped,
               "record": str(self.record) if self.record else None, "stalled": self.stalled}
        live = self.rec.summary()
        if live is not None:
            out["live"] = live
        if self.latency_ms:
            out["composite_latency_ms"] = {"median": float(np.median(self.latency_ms)),
                                           "max": float(np.max(self.latency_ms))}
        if self.frame_bytes:
            out["encoded_mb_per_frame"] = float(np.mean(self.frame_bytes)) / 1e6
        if self.surface_ms:
            out["surface"] = {"meshes": len(self.surface_ms), "median_ms": float(np.median(self.surface_ms)),
                              "mean_mb": float(np.mean(self.surface_bytes)) / 1e6, "bad_pieces": self.bad_surfaces}
        if self.record is not None and Path(self.record).exists():
            size = Path(self.record).stat().st_size
            out["record_mb"] = size / 1e6
            if self.frames:
                out["record_mb_per_frame"] = size / 1e6 / self.frames
        return out

    # -- the writer thread ---------------------------------------------------------------------
    def _write_loop(self):
        while True:
            item = self._queue.get()
            try:
                if item is None:
                    return
                self._log_frame(*item)
            except Exception:  # a frame that cannot be logged must not stop the ones after it
                log.exception("viewer: frame not logged")
            finally:
                self._queue.task_done()

    def _log_info(self):
        rr = self.rr
        self.rec.log("info", rr.TextDocument(info_text(self.scene, self.particles, self.world, self.changes),
                                             media_type=rr.MediaType.MARKDOWN), static=True)

    def _log_legend(self):
        rr, r = self.rr, self.renderer
        lo, hi = r.range
        self.rec.log("legend", rr.TextDocument(legend_text(r.quantity, lo, hi), media_type=rr.MediaType.MARKDOWN),
                     static=True)
        cam = r.camera
        width = min(256, cam.width)
        bar = np.repeat(LUT[np.linspace(0, len(LUT) - 1, width).astype(np.int64)][None], 12, axis=0)
        if r.quantity == "rank":
            bar = np.repeat(RANK_COLOURS[np.arange(width) * self.world // width % len(RANK_COLOURS)][None], 12, axis=0)
        label = "peer 0 ... %d" % (self.world - 1) if r.quantity == "rank" else \
            f"{r.quantity}: {lo:.3g} ... {hi:.3g} {UNITS[r.quantity]}"
        y = cam.height + 6
        self.rec.log("composite/legend", rr.Transform3D(translation=[8, y, 0]), static=True)
        self.rec.log("composite/legend", rr.Image(bar, opacity=1.0), static=True)
        self.rec.log("composite/legend_label", rr.Boxes2D(mins=[[8, y]], sizes=[[width, 12]], labels=[label],
                                                          colors=[[200, 200, 200]]), static=True)

    def _log_camera(self):
        rr, cam = self.rr, self.renderer.camera
        eye, rot = camera_pose(cam)
        self.rec.log("camera", rr.Transform3D(translation=eye, mat3x3=rot), static=True)
        self.rec.log("camera", rr.Pinhole(focal_length=cam.focal, width=cam.width, height=cam.height,
                                          image_plane_distance=0.1 * float(np.linalg.norm(np.subtract(cam.eye,
                                                                                                      cam.target)))),
                     static=True)

    def _follow(self, step: int, stats: dict):
        """Follow the peers' camera and colouring (sph control camera / color_by)."""
        r, rec, rr = self.renderer, self.rec, self.rr
        name = stats.get("camera")
        if name is not None and name != r.camera_name and name in r.cameras:
            r.camera_name = name
            rec.log("events", rr.TextLog(f"step {step}: camera {name}", level="INFO"))
            self._log_camera()
            self._log_legend()
            rec.send_blueprint(blueprint(self.scene, self.world, r.camera))
        quantity = stats.get("color_by")
        if quantity is not None and quantity in UNITS and (quantity != r.quantity or
                                                           list(stats.get("range", r.range)) != list(r.range)):
            r.quantity = quantity
            r.range = tuple(stats.get("range", r.range))
            rec.log("events", rr.TextLog(f"step {step}: colour by {quantity}", level="INFO"))
            self._log_legend()

    def image(self, frames, sim_time: float = 0.0, shifts=None):
        """The composite of ``frames`` (sort-last), the obstacles (where they are at ``sim_time``; the
        floating ones displaced by ``shifts``) merged by depth, the domain outline drawn over what is
        in front of it: (rgb, depth)."""
        r = self.renderer
        cam = r.camera
        rgb, depth, _ = composite(frames, cam.width, cam.height)
        moving = bool(moving_obstacles(self.scene) or floating_obstacles(self.scene))
        if r.camera_name not in self._layers or moving:  # moving obstacles: traced again every frame
            try:
                if self._obstacle_sdf is None:
                    self._obstacle_sdf = obstacle_distance(self.scene) or False
                self._layers[r.camera_name] = (obstacle_layer(self.scene, cam, r.box, t=sim_time, sdf=self._obstacle_sdf,
                                                              shifts=shifts) if self._obstacle_sdf else None)
            except (OSError, ValueError) as e:  # a mesh that cannot be read: the run says so itself
                log.warning("viewer: obstacles not drawn: %s", e)
                self._layers[r.camera_name] = None
                self._obstacle_sdf = False
        merge_layer(rgb, depth, self._layers[r.camera_name])
        draw_box(cam, *r.box, rgb, depth, self.scene.dim)
        return rgb, depth

    def _log_frame(self, step: int, parts: dict):
        published = [p[1].get("wall_time") for p in parts.values()]
        published = max((t for t in published if isinstance(t, (int, float))), default=None)
        with self.rec.frame(published):  # one frame for the live stream: sent whole or dropped whole
            self._log_parts(step, parts)

    def _log_parts(self, step: int, parts: dict):
        rr, rec = self.rr, self.rec
        ranks = sorted(parts)
        stats = {r: parts[r][1] for r in ranks}
        sim_time = max(s["sim_time"] for s in stats.values())
        rec.set_time("step", sequence=step)
        rec.set_time("sim_time", duration=sim_time)
        self._follow(step, stats[ranks[0]])
        with self._lock:
            controls, self._carried = self._carried + list(stats[ranks[0]].get("controls", [])), []
        for r in ranks:  # each peer's own: rebalances, restarts, warnings (nodes/driver._EventFeed)
            for level, text in peer_events(stats[r].get("events")):
                rec.log("events", rr.TextLog(f"peer {r}: {text}", level=level))
        for text in controls:  # every peer applied it; log it once
            rec.log("control", rr.TextLog(text, level="INFO"))
            changed = apply_setting(self.scene, text)
            if changed is not self.scene:
                self.scene = changed
                self.changes.append((step, text))
                self._log_info()
        frames = [parts[r][0] for r in ranks]
        shifts = body_shifts(self.scene, stats[ranks[0]].get("bodies"))  # floating bodies, as rank 0 has them
        rgb, depth = self.image(frames, sim_time, shifts)
        for i, motion in moving_obstacles(self.scene).items():  # the 3D view's meshes follow them too
            rec.log(f"obstacles/{i}", rr.Transform3D(**obstacle_transform(self.scene, i, motion, sim_time)))
        for i, (shift, R) in shifts.items():
            rec.log(f"obstacles/{i}", rr.Transform3D(**body_transform(self.scene, i, shift, R)))
        jpeg = encode_jpeg(rgb, RGB_QUALITY)
        png, meter = encode_depth(depth)
        size = len(jpeg) + len(png)
        # opaque: Rerun draws an image that shares its view with other images (the depth, the legend)
        # half transparent unless told otherwise
        rec.log("composite/rgb", rr.EncodedImage(contents=jpeg, media_type="image/jpeg", opacity=1.0))
        rec.log("composite/depth", rr.EncodedDepthImage(png, media_type="image/png", meter=meter))
        boxes = [f for f in frames if f.w and f.h]
        if boxes:
            rec.log("composite/peers", rr.Boxes2D(mins=[[f.x0, f.y0] for f in boxes], sizes=[[f.w, f.h] for f in boxes],
                                                  labels=[f"peer {f.rank}" for f in boxes],
                                                  colors=[RANK_COLOURS[f.rank % len(RANK_COLOURS)] for f in boxes]))
        for f in boxes:
            data = encode_jpeg(f.rgb, PEER_QUALITY)
            size += len(data)
            rec.log(f"peers/{f.rank}/rgb", rr.EncodedImage(contents=data, media_type="image/jpeg"))
        missing = sorted(set(range(self.world)) - set(ranks))
        if missing:
            self.incomplete += 1
            rec.log("composite/status", rr.TextLog(f"step {step}: incomplete frame, no framelet from peer(s) "
                                                   f"{missing}", level="WARN"))
        if any(stats[r].get("surface") is True for r in ranks):
            size += self._log_surface([parts[r][3] for r in ranks if parts[r][3] is not None])
        pts = [parts[r][2] for r in ranks if parts[r][2] is not None and len(parts[r][2][0])]
        if pts:
            xyz = np.concatenate([p[0] for p in pts]).astype(np.float32)
            rgb_pts = np.concatenate([p[1] for p in pts])
            size += xyz.nbytes + rgb_pts.nbytes
            rec.log("fluid/points", rr.Points3D(xyz, colors=rgb_pts, radii=self.renderer.radius))
        counts = [s["particles"] for s in stats.values()]
        for r, s in stats.items():
            rec.log(f"stats/particles/peer{r}", rr.Scalars(s["particles"]))
            rec.log(f"stats/bytes_sent_mb/peer{r}", rr.Scalars(s["bytes_sent"] / 1e6))
            for stage, ms in s["stage_ms"].items():
                rec.log(f"stats/stage_ms/{stage}/peer{r}", rr.Scalars(ms))
            for kind, sent in exchange_bytes(s.get("bytes_by_exchange")):
                rec.log(f"stats/exchange_mb/{kind}/peer{r}", rr.Scalars(sent / 1e6))
        if self.world > 1 and counts and np.mean(counts) > 0:
            rec.log("stats/imbalance", rr.Scalars(max(counts) / np.mean(counts) - 1.0))
        rec.log("stats/kinetic_energy", rr.Scalars(sum(s["kinetic_energy"] for s in stats.values())))
        rec.log("stats/max_density_deviation", rr.Scalars(max(s["max_density_deviation"] for s in stats.values())))
        rec.log("stats/dropped_frames", rr.Scalars(self.dropped))
        if self.rec.live is not None:  # frames the live viewer did not get (behind, or --live-fps)
            rec.log("stats/live_dropped_frames", rr.Scalars(self.rec.live_dropped))
        probes = stats[ranks[0]].get("probes") if ranks[0] == 0 else None
        if probes:  # each sample at its own step ([[probes]], sphcore/probes.py); a dry height line is a gap
            for sample_step, t, values in probe_samples(probes):
                rec.set_time("step", sequence=sample_step)
                rec.set_time("sim_time", duration=t)
                for name, value in zip(probes["names"], values):
                    if value is not None:
                        rec.log(f"probes/{name}", rr.Scalars(value))
            rec.set_time("step", sequence=step)
            rec.set_time("sim_time", duration=sim_time)
        now = time.time()
        latency = 1e3 * (now - max(s["wall_time"] for s in stats.values()))
        self.latency_ms.append(latency)
        self.frame_bytes.append(size)
        rec.log("stats/composite_latency_ms", rr.Scalars(latency))
        if self._last_emit is not None and now > self._last_emit:
            rec.log("stats/fps", rr.Scalars(1.0 / (now - self._last_emit)))
        self._last_emit = now
        self.frames += 1
        if self.frames == 1 and self.announce is not None:
            total = "" if not self.expected_frames else \
                f", about {size * self.expected_frames / 1e6:.2g} MB for the run's {self.expected_frames} " \
                f"frame{'s' if self.expected_frames != 1 else ''}"
            self.announce(f"sph viewer: about {size / 1e6:.2f} MB per frame recorded{total}")


    def _log_surface(self, pieces: list) -> int:
        """Assemble the peers' pieces of the colour field on the lattice, extract its 0.5 level and
        log it as fluid/surface (a Mesh3D in 3D, line strips in 2D; cleared when there is none);
        returns the bytes logged."""
        rr, rec = self.rr, self.rec
        start = time.perf_counter()
        origin, step, shape = self.lattice
        good = []
        for at, field in pieces:  # off the wire: a piece must lie on the lattice
            if (field.ndim == 3 and np.all(at >= 0) and np.all(at <= shape)  # (no overflow in the sum below)
                    and np.all(at + np.array(field.shape) <= shape)):
                good.append((at, field))
            else:
                self.bad_surfaces += 1
                if self.bad_surfaces == 1:
                    log.warning("viewer: dropped a surface piece of shape %s at %s: off the %s lattice",
                                field.shape, at, shape.tolist())
        if not good:
            rec.log("fluid/surface", rr.Clear(recursive=False))
            return 0
        lo = np.min([at for at, _ in good], axis=0)
        hi = np.max([at + np.array(f.shape) for at, f in good], axis=0)
        pad = np.array([1, 1, 1 if self.scene.dim == 3 else 0])  # zeros around: the surface closes on the walls
        field = np.zeros(tuple(hi - lo + 2 * pad), dtype=np.float32)
        for at, f in good:
            a = at - lo + pad
            field[a[0]:a[0] + f.shape[0], a[1]:a[1] + f.shape[1], a[2]:a[2] + f.shape[2]] = f
        from sphcore.surface import iso_surface
        mesh = iso_surface(field / SURFACE_SCALE, origin + (lo - pad) * step, step)
        size = 0
        if mesh.n_points == 0:
            rec.log("fluid/surface", rr.Clear(recursive=False))
        elif self.scene.dim == 3:
            mesh = mesh.triangulate()
            xyz = np.asarray(mesh.points, dtype=np.float32)
            tri = np.asarray(mesh.faces, dtype=np.uint32).reshape(-1, 4)[:, 1:]
            normals = surface_normals(mesh)
            rec.log("fluid/surface", rr.Mesh3D(vertex_positions=xyz, triangle_indices=tri, vertex_normals=normals,
                                               albedo_factor=SURFACE_COLOUR))
            size = xyz.nbytes + tri.nbytes + normals.nbytes
        else:
            segments = np.asarray(mesh.points, dtype=np.float32)[np.asarray(mesh.lines).reshape(-1, 3)[:, 1:]]
            rec.log("fluid/surface", rr.LineStrips3D(segments, colors=[SURFACE_COLOUR[:3]],
                                                     radii=rr.Radius.ui_points(1.5)))
            size = segments.nbytes
        self.surface_ms.append(1e3 * (time.perf_counter() - start))
        self.surface_bytes.append(size)
        return size


SURFACE_COLOUR = [90, 160, 230, 255]  # the live surface: water blue (the points carry the quantity's colours)


def surface_normals(mesh) -> np.ndarray:
    """Unit normals at the mesh's vertices, so that Rerun shades the surface (unlit without them).
    They follow the triangles' winding, which flying edges keeps consistent and outward on a closed
    surface (tests/test_live_surface.py checks that they point out of the fluid)."""
    mesh = mesh.compute_normals(auto_orient_normals=False, split_vertices=False)
    return np.asarray(mesh.point_data["Normals"], dtype=np.float32)


# -- the wire side --------------------------------------------------------------------------------
EVENT_LEVELS = ("INFO", "WARN", "ERROR")
_NAME = re.compile(r"[a-z][a-z0-9_]{0,31}")


def peer_events(events) -> list[tuple[str, str]]:
    """The well-formed (level, text) pairs of a peer's ``events`` (a frame's statistics come off the
    wire: anything else is skipped), texts cut at 500 characters, at most 32."""
    if not isinstance(events, list):
        return []
    out = []
    for e in events[:32]:
        if isinstance(e, list) and len(e) == 2 and e[0] in EVENT_LEVELS and isinstance(e[1], str):
            out.append((e[0], e[1][:500]))
    return out


def exchange_bytes(sent) -> list[tuple[str, float]]:
    """The (exchange, bytes) pairs of a peer's ``bytes_by_exchange`` that are plain names with finite
    counts >= 0 (they become entity paths: nothing else is logged), at most 16."""
    if not isinstance(sent, dict):
        return []
    return [(k, float(v)) for k, v in list(sent.items())[:16]
            if isinstance(k, str) and _NAME.fullmatch(k) and isinstance(v, (int, float))
            and not isinstance(v, bool) and math.isfinite(v) and v >= 0]


def probe_samples(probes) -> list:
    """[(step, t, values)] of a frame's "probes" statistics that are well formed (a peer's frame is
    data from the network: names that are not probe names, and malformed samples, are skipped)."""
    from sphcore.scene import PROBE_NAME
    names = probes.get("names") if isinstance(probes, dict) else None
    samples = probes.get("samples") if isinstance(probes, dict) else None
    if (not isinstance(names, list) or not isinstance(samples, list)
            or not all(isinstance(n, str) and PROBE_NAME.fullmatch(n) for n in names)):
        return []
    out = []
    for sample in samples:
        if (isinstance(sample, list) and len(sample) == 3 and isinstance(sample[0], int)
                and isinstance(sample[1], (int, float)) and isinstance(sample[2], list)
                and len(sample[2]) == len(names)
                and all(v is None or (isinstance(v, (int, float)) and math.isfinite(v)) for v in sample[2])):
            out.append((sample[0], float(sample[1]), sample[2]))
    return out


def frame_arrays(frame: Framelet, stats: dict, points=None, surface=None) -> dict:
    arrays = {"rect": np.array([frame.x0, frame.y0, frame.w, frame.h], dtype=np.int64), "rgb": frame.rgb,
              "depth": frame.depth, "id": frame.id,
              "stats": np.frombuffer(json.dumps(stats).encode(), dtype=np.uint8)}
    if points is not None:
        arrays["points"] = np.ascontiguousarray(points[0], dtype=np.float32)
        arrays["point_colours"] = np.ascontiguousarray(points[1], dtype=np.uint8)
    if surface is not None:
        arrays["surface_at"] = np.asarray(surface[0], dtype=np.int64)
        arrays["surface"] = np.ascontiguousarray(surface[1], dtype=np.uint8)
    return arrays


def frame_from_arrays(rank: int, a: dict):
    """(framelet, stats, points: (positions, colours) or None, surface: (node offset, uint8 field) or
    None) from a decoded message; ValueError if the parts do not fit."""
    x0, y0, w, h = (int(v) for v in a["rect"])
    if a["rgb"].shape != (h, w, 3) or a["depth"].shape != (h, w) or a["id"].shape != (h, w):
        raise ValueError(f"framelet planes do not match its rectangle {w} x {h}")
    stats = json.loads(bytes(a["stats"]).decode())
    points = a.get("points")
    if points is not None:
        colours = a.get("point_colours")
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError("points must be (n, 3)")
        if colours is None or colours.shape != points.shape or colours.dtype != np.uint8:
            raise ValueError("point_colours must be (n, 3) uint8, one per point")
        points = (points, colours)
    surface = a.get("surface")
    if surface is not None:
        at = a.get("surface_at")
        if surface.ndim != 3 or surface.dtype != np.uint8 or at is None or at.shape != (3,) or at.dtype != np.int64:
            raise ValueError("surface must be (a, b, c) uint8 with surface_at (3,) int64")
        surface = (at.copy(), surface)
    if not isinstance(stats, dict):
        raise ValueError("the statistics are not a JSON object")
    return Framelet(rank, x0, y0, a["rgb"], a["depth"], a["id"]), stats, points, surface


def run_viewer(scene, run_id: str, listen: list[str], connect: list[str], rec, box, world: int | None,
               particles: int, ready=None, idle_timeout: float | None = None, grace: float = 1.0,
               stats_path: Path | None = None, trust=None, record: Path | None = None,
               expected_frames: int | None = None) -> int:
    """Subscribe to the run's framelets until rank 0 announces the end (or Ctrl-C); returns frames.
    ``trust``: the viewer's credentials (nodes/security.py), None for an --insecure run; ``record``:
    the recording file (its size goes into ``stats_path``)."""
    import zenoh

    done = threading.Event()
    state = {"viewer": None, "last": time.perf_counter()}

    def on_frame(sample):
        try:
            source, (step, phase), arrays = wire.decode(sample.payload.to_bytes(), run_id, wire.VIEWER, 1 << 20)
            if phase == "end":
                done.set()
                return
            frame, stats, points, surface = frame_from_arrays(source, arrays)
        except (wire.WireError, ValueError, KeyError) as e:
            log.warning("viewer: dropped a message on %s: %s", sample.key_expr, e)
            return
        state["last"] = time.perf_counter()
        if state["viewer"] is None:
            n = world or int(stats["world"])
            state["viewer"] = Viewer(scene, box, rec, n, stats.get("particles_total", particles),
                                     expected_frames=expected_frames, record=record,
                                     announce=lambda text: print(text, flush=True))
        state["viewer"].add(step, source, frame, stats, points, surface)

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
        session.close()
        if state["viewer"] is not None:
            state["viewer"].close()
        elif not rec.close(10.0):
            let_rerun_go(rec)
    v = state["viewer"]
    if stats_path is not None and v is not None:
        write_summary(stats_path, dict(v.summary(), note="latency: from the newest framelet's publication to the "
                                                         "composite being logged (same-machine clocks)"))
    if _HELD:
        exit_now(0, f"sph viewer: {0 if v is None else v.frames} frames; the live Rerun viewer stopped reading, "
                    "not waiting for it (the recording file has what it received)")
    return 0 if v is None else v.frames
