"""``sph run``: run a scene in this process and write the contract outputs.

``run_scene`` runs a scene in this process; ``advance`` is the stepping loop (progress, timings)
that a peer process (nodes/peer.py) runs too, over its halo; ``make_summary`` and ``write_outputs``
produce the contract outputs for both.
"""
from __future__ import annotations

import logging
import math
import platform
import sys
import time
from pathlib import Path

import numba
import numpy as np

from sphcore import __version__
from sphcore.output import write_final, write_scene, write_summary
from sphcore.scene import Scene
from sphcore.halo import NULL_HALO
from sphcore.solver import Simulation

log = logging.getLogger("sph.run")


class Progress:
    """A progress bar on a terminal (tqdm), a quiet log line every so often otherwise."""

    def __init__(self, total: float, unit: str, log_every: int, enabled: bool = True):
        self.total = total
        self.unit = unit
        self.bar = None
        self.log_every = log_every  # steps between log lines; 0 = every 5 % of the run
        self.next_mark = 0.05
        self.enabled = enabled
        if enabled and sys.stderr.isatty():
            from tqdm import tqdm
            self.bar = tqdm(total=total, unit=unit, dynamic_ncols=True, leave=True,
                            bar_format="{l_bar}{bar}| {n:.4g}/{total:.4g} {unit} [{elapsed}<{remaining}{postfix}]")

    def update(self, done: float, step: int, sim: Simulation, rate: float):
        if not self.enabled:
            return
        info = f"step {step}  t={sim.t:.4g}s  dt={sim.dt:.3g} ({sim.last_limit})  {rate:.3g} particle-steps/s"
        if self.bar is not None:
            # update() redraws at most every tqdm.mininterval (0.1 s), so small scenes are not slowed
            self.bar.set_postfix_str(f"t={sim.t:.4g}s dt={sim.dt:.2g} ({sim.last_limit}) {rate:.2g} p-steps/s",
                                     refresh=False)
            self.bar.update(min(done, self.total) - self.bar.n)
        else:
            fraction = min(done / self.total, 1.0) if self.total else 1.0
            due = (step % self.log_every == 0) if self.log_every else fraction >= self.next_mark
            if due or fraction >= 1.0:
                self.next_mark = (int(fraction * 20) + 1) / 20.0
                log.info("%s  (%.0f%%)", info, 100.0 * fraction)

    def close(self):
        if self.bar is not None:
            self.bar.close()


def run_scene(scene: Scene, out: Path, precision: str | None, steps: int | None, until: float | None,
              threads: int | None, progress: bool = True, viewer: dict | None = None, resume=None,
              checkpoint_every: int | None = None, backend: str = "cpu", device: int | None = None) -> dict:
    """Run ``scene`` and write summary.json, final.npz and scene.toml into ``out``; return the summary.
    ``viewer`` (record / spawn / serve_web / connect) renders a frame every render.every steps and
    logs it to Rerun from this process (a single peer needs no compositing over the network).
    ``resume`` (a loaded Checkpoint) continues from it; checkpoints are written every
    ``checkpoint_every`` steps (default: the scene's output.checkpoint_every)."""
    from sphcore import checkpoint
    if threads:
        numba.set_num_threads(threads)
    t_start = time.perf_counter()
    sim = Simulation(scene, precision, backend, device)
    if resume is not None:
        checkpoint.restore(sim, resume)
        log.info("resumed from %s at step %d, t = %.6g s", resume.path, sim.step_index, sim.t)
    t_setup = time.perf_counter() - t_start
    every = scene.output.checkpoint_every if checkpoint_every is None else checkpoint_every
    hooks = []
    saved = checkpoint_record(every)
    if every:
        root = out / "checkpoints"

        def save():
            if sim.step_index % every == 0:
                try:
                    part = checkpoint.write_part(root, sim.step_index, 0, sim)
                    checkpoint.commit(root, sim.step_index, checkpoint.sim_info(sim), resolved_scene(scene, sim),
                                      [part], scene.output.checkpoint_keep)
                except checkpoint.CheckpointWriteError as e:
                    checkpoint_failed(saved, sim.step_index, str(e))
                else:
                    saved["written"] += 1
                    saved["last"] = sim.step_index
        hooks.append(save)
    if scene.output.vtk_every:
        from sphcore.vtk import VtkWriter
        vtk = VtkWriter(out, scene)
        hooks.append(lambda: vtk.write(sim) if vtk.due(sim) else None)
    log.info("%s: %d particles, %s, %s", scene.scene.name, sim.n_particles, sim.precision,
             sim.device_name if backend == "cuda" else f"{numba.get_num_threads()} numba threads")
    on_step, view = None, None
    if viewer is not None:
        import os

        from nodes.frames import FrameMaker, domain_box
        from nodes.viewer import Viewer, open_recording
        os.environ.setdefault("RERUN_ANALYTICS", "0")
        box = domain_box(scene)
        rec = open_recording(f"{scene.scene.name}-{os.getpid()}", viewer["record"], viewer["spawn"],
                             viewer["serve_web"], viewer["connect"], viewer.get("grpc_port"),
                             viewer.get("web_port"))
        view = Viewer(scene, box, rec, 1, sim.n_particles)
        maker = FrameMaker(scene, box, 0, 1, sim.n_particles)

        def frame():
            if maker.due(sim):
                view.add(sim.step_index, 0, *maker.make(sim))
        hooks.append(frame)
    if hooks:
        def on_step(seconds):
            for hook in hooks:
                hook()

    try:
        loop = advance(sim, NULL_HALO, scene, steps, until, progress, on_step=on_step)
    finally:
        if view is not None:
            view.flush()
            view.rec.flush()
    final = sim.final_arrays()
    summary = make_summary(sim, scene, loop, t_setup, time.perf_counter() - t_start)
    if every:
        summary["checkpoints"] = saved
    if view is not None:
        summary["viewer"] = {"frames": view.frames, "record": str(viewer["record"]) if viewer["record"] else None,
                             "composite_latency_ms_median": float(np.median(view.latency_ms)) if view.latency_ms
                             else None}
    write_outputs(out, resolved_scene(scene, sim), final, summary)
    return summary


def checkpoint_record(every: int) -> dict:
    """summary.json's "checkpoints": how many were written and failed, the newest good step."""
    return {"every": every, "written": 0, "failed": 0, "last": None, "failures": []}


def checkpoint_failed(record: dict, step: int, error: str):
    """A checkpoint that could not be written: one warning, counted; the run goes on."""
    record["failed"] += 1
    record["failures"].append({"step": step, "error": error})
    last = f"step {record['last']}" if record["last"] is not None else "none yet"
    log.warning("%s; not kept, the run goes on (last good checkpoint: %s)", error, last)


def resolved_scene(scene: Scene, sim) -> dict:
    """The scene as it ran: every key resolved, --precision included, run-time changes included."""
    resolved = sim.scene.to_dict()
    resolved["run"]["precision"] = sim.precision
    return resolved


def write_outputs(out: Path, resolved: dict, final: dict, summary: dict):
    """summary.json, final.npz and scene.toml (``resolved``: resolved_scene(scene, sim))."""
    out.mkdir(parents=True, exist_ok=True)
    write_scene(out / "scene.toml", resolved)
    write_final(out / "final.npz", final)
    write_summary(out / "summary.json", summary)


def advance(sim: Simulation, halo, scene: Scene, steps: int | None, until: float | None, progress: bool,
            on_step=None) -> dict:
    """Step ``sim`` (over ``halo``) for ``steps`` steps or until simulated time ``until`` (else the
    scene's time.steps; a resumed run counts from its checkpoint's step); ``on_step(seconds)`` is
    called after each step (seconds None for the first, untimed one). Returns the loop
    timings: the first step (numba compilation or cache load) is timed apart from the loop, so
    that particle-steps/s measures stepping only."""
    target_steps = steps if steps is not None else (None if until is not None else scene.time.steps)

    def cap():
        return (until - sim.t) if until is not None else None

    t0 = time.perf_counter()
    if target_steps != 0 and (until is None or sim.t < until) and (target_steps is None
                                                                    or sim.step_index < target_steps):
        sim.step(cap(), halo)
        if on_step is not None:
            on_step(None)  # not timed: this step compiled the kernels
    t_first = time.perf_counter() - t0
    sim.timers.reset()
    steps_in_loop = 0
    total = target_steps if target_steps is not None else until
    bar = Progress(total, "steps" if target_steps is not None else "s", scene.run.log_every, enabled=progress)
    t_loop = time.perf_counter()
    try:
        while True:
            if target_steps is not None and sim.step_index >= target_steps:
                break
            if until is not None and sim.t >= until * (1 - 1e-12):
                break
            t_step = time.perf_counter()
            sim.step(cap(), halo)
            now = time.perf_counter()
            if on_step is not None:
                on_step(now - t_step)
            steps_in_loop += 1
            rate = sim.n_particles * steps_in_loop / (now - t_loop)
            bar.update(sim.step_index if target_steps is not None else sim.t, sim.step_index, sim, rate)
    finally:
        bar.close()
    return {"steps": steps_in_loop, "wall_s": time.perf_counter() - t_loop, "first_step_s": t_first}


def make_summary(sim: Simulation, scene: Scene, loop: dict, t_setup: float, wall_total: float) -> dict:
    stages = sim.timers.summary()
    counts = sim.grid.counts[: sim.state.n_owned]
    limits = {k: v for k, v in sim.limit_counts.items() if v}
    return {
        "scene": scene.scene.name,
        "source": scene.source,
        "version": __version__,
        "particles": sim.n_particles,
        "steps": sim.step_index,
        "sim_time": sim.t,
        "wall_s": wall_total,
        "peers": 1,
        "backend": sim.backend,
        "device": sim.device_name,
        "precision": sim.precision,
        "threads": numba.get_num_threads() if sim.backend == "cpu" else None,
        "dim": scene.dim,
        "particle_steps_per_s": (sim.n_particles * loop["steps"] / loop["wall_s"]) if loop["wall_s"] > 0 else None,
        "loop": {"steps": loop["steps"], "wall_s": loop["wall_s"],
                 "note": "stepping loop only: excludes set-up and the first (compiling) step"},
        "startup": {"setup_s": t_setup, "first_step_s": loop["first_step_s"],
                    "note": "first_step_s includes numba compilation, or loading it from the on-disk cache"},
        "stages": stages,
        "dt": {"last": sim.dt, "binding_limit_steps": limits},
        "solver": {"name": scene.sph.solver, **({
            name: {"mean_iterations": st["iterations"] / max(st["steps"], 1), "max_iterations": st["max"],
                   "unconverged_steps": st["unconverged"], "last_mean_error": st["last_error"]}
            for name, st in sim.solver_stats.items()} if sim.dfsph else {})},
        "neighbours": {"mean": float(counts.mean()) if counts.size else 0.0,
                       "max": int(counts.max()) if counts.size else 0, "max_over_run": sim.max_neighbours},
        "leaks": sim.leaks,
        "max_compression": sim.max_compression,
        "kinetic_energy": sim.kinetic_energy(),
        "bytes_sent": 0,
        "machine": {"python": platform.python_version(), "platform": platform.platform(),
                    "numba": numba.__version__, "numpy": np.__version__},
    }
