"""``sph run``: run a scene in this process and write the contract outputs.

``run_scene`` sets the run up as peer 0 of 1 (NULL_HALO, an in-process endpoint) and runs it
through the run driver every run shares (``nodes.driver.drive``: stepping, checkpoints, VTK,
outputs); its frames go to a Viewer in this process (``LocalFrames``).
"""
from __future__ import annotations

import logging
import os
import signal
import threading
import time
from pathlib import Path

import numba

from nodes.driver import PeerRun, RunPlan, drive, listen_for_control, run_blocking
from nodes.frames import FrameMaker, domain_box
from nodes.transport import InProcessNetwork
from nodes.rerun_sinks import LIVE_FPS
from nodes.viewer import Viewer, open_recording
from sphcore import checkpoint
from sphcore.halo import NULL_HALO
from sphcore.scene import Scene
from sphcore.solver import Simulation

log = logging.getLogger("sph.run")


class LocalFrames:
    """A single process's frames: rendered every render.every steps and composited and logged to
    Rerun by a Viewer in this process (one peer needs no compositing over the network).
    ``viewer``: record / spawn / serve_web / connect (and grpc_port, web_port)."""

    def __init__(self, scene: Scene, sim: Simulation, viewer: dict):
        os.environ.setdefault("RERUN_ANALYTICS", "0")
        box = domain_box(scene)
        rec = open_recording(f"{scene.scene.name}-{os.getpid()}", viewer["record"], viewer["spawn"],
                             viewer["serve_web"], viewer["connect"], viewer.get("grpc_port"),
                             viewer.get("web_port"), viewer.get("live_fps", LIVE_FPS))
        self.record = viewer["record"]
        self.view = Viewer(scene, box, rec, 1, sim.n_particles, expected_frames=viewer.get("expected_frames"),
                           record=self.record, announce=lambda text: print(text, flush=True))
        self.maker = FrameMaker(scene, box, 0, 1, sim.n_particles)

    def show(self, sim: Simulation):
        if self.maker.due(sim):
            self.view.add(sim.step_index, 0, *self.maker.make(sim))

    def close(self):
        self.view.close()

    def summary(self) -> dict:
        return self.view.summary()

    def end(self, step: int):
        if self.view.stalled:  # the outputs are written; Rerun would wait for the live viewer for ever
            from nodes.viewer import exit_now
            exit_now(0, f"sph run: step {step}: outputs written; the live Rerun viewer stopped reading, exiting "
                        "without waiting for it")


class StopOnSignal:
    """Ctrl-C (SIGINT) or SIGTERM ends the run at the end of the current step, so that its outputs
    (summary.json, final.npz: marked interrupted, with the step) hold a consistent state; a second
    Ctrl-C aborts at once (KeyboardInterrupt). Handlers are installed only in the main thread and
    put back on exit."""

    def __init__(self):
        self.signal_name = None
        self._previous = {}

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc):
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        return False

    def _handle(self, signum, frame):
        if self.signal_name is not None and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.signal_name = signal.Signals(signum).name
        log.warning("%s: stopping at the end of this step and writing the outputs (Ctrl-C again: abort now, "
                    "nothing written)", self.signal_name)

    def requested(self) -> str | None:
        return self.signal_name


def run_scene(scene: Scene, out: Path, precision: str | None, steps: int | None, until: float | None,
              threads: int | None, progress: bool = True, viewer: dict | None = None, resume=None,
              checkpoint_every: int | None = None, backend: str = "cpu", device: int | None = None,
              control: bool = False, secure: bool = True) -> dict:
    """Run ``scene`` and write summary.json, final.npz and scene.toml into ``out``; return the summary.
    ``out`` is created and checked before the first step, summary.json is written there at once and
    rewritten every few seconds; Ctrl-C or SIGTERM ends the run after the current step with the
    outputs written and summary.json's status "interrupted".
    ``viewer`` (record / spawn / serve_web / connect) renders a frame every render.every steps and
    logs it to Rerun from this process. ``resume`` (a loaded Checkpoint) continues from it;
    checkpoints are written every ``checkpoint_every`` steps (default: the scene's
    output.checkpoint_every). ``control``: listen for ``sph control OUT COMMAND`` (nodes/driver.py
    listen_for_control; ``secure`` False: plain TCP on loopback)."""
    if threads:
        numba.set_num_threads(threads)
    t_start = time.perf_counter()
    sim = Simulation(scene, precision, backend, device)
    if resume is not None:
        checkpoint.restore(sim, resume)
        log.info("resumed from %s at step %d, t = %.6g s", resume.path, sim.step_index, sim.t)
    t_setup = time.perf_counter() - t_start
    log.info("%s: %d particles, %s, %s", scene.scene.name, sim.n_particles, sim.precision,
             sim.device_name if backend == "cuda" else f"{numba.get_num_threads()} numba threads")
    frames = LocalFrames(scene, sim, viewer) if viewer is not None else None
    endpoint = listen_for_control(out, secure) if control else InProcessNetwork().endpoint(0)
    peer = PeerRun(sim, scene, NULL_HALO, endpoint, t_start=t_start, t_setup=t_setup)
    try:
        with StopOnSignal() as stopper:
            plan = RunPlan(steps, until, out, checkpoint_every, progress=progress, stop=stopper.requested)
            return run_blocking(drive(peer, plan, frames))
    finally:
        endpoint.close()
