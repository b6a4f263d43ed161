"""``sph run``: run a scene in this process and write the contract outputs.

Single-process CPU runs live here; multi-peer runs (--peers N) and the viewer arrive with the
distributed and viewer issues (#3, #4) and reuse the same outputs.
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
              threads: int | None, progress: bool = True) -> dict:
    """Run ``scene`` and write summary.json, final.npz and scene.toml into ``out``; return the summary."""
    if threads:
        numba.set_num_threads(threads)
    t_start = time.perf_counter()
    sim = Simulation(scene, precision)
    t_setup = time.perf_counter() - t_start
    log.info("%s: %d particles, %s, %d numba threads", scene.scene.name, sim.n_particles, sim.precision,
             numba.get_num_threads())

    # The first step compiles (or loads from numba's on-disk cache) every stage; it is timed apart
    # from the stepping loop so that particle_steps_per_s measures stepping only.
    target_steps = steps if steps is not None else (None if until is not None else scene.time.steps)
    t0 = time.perf_counter()
    if target_steps != 0 and (until is None or sim.t < until):
        sim.step(dt_cap=(until - sim.t) if until is not None else None)
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
            sim.step(dt_cap=(until - sim.t) if until is not None else None)
            steps_in_loop += 1
            elapsed = time.perf_counter() - t_loop
            rate = sim.n_particles * steps_in_loop / elapsed if elapsed > 0 else 0.0
            bar.update(sim.step_index if target_steps is not None else sim.t, sim.step_index, sim, rate)
    finally:
        bar.close()
    wall_loop = time.perf_counter() - t_loop

    final = sim.final_arrays()
    summary = make_summary(sim, scene, wall_loop, steps_in_loop, t_setup, t_first,
                           time.perf_counter() - t_start)
    out.mkdir(parents=True, exist_ok=True)
    resolved = scene.to_dict()
    resolved["run"]["precision"] = sim.precision  # what ran, --precision included
    write_scene(out / "scene.toml", resolved)
    write_final(out / "final.npz", final)
    write_summary(out / "summary.json", summary)
    return summary


def make_summary(sim: Simulation, scene: Scene, wall_loop: float, steps_in_loop: int, t_setup: float,
                 t_first: float, wall_total: float) -> dict:
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
        "backend": "cpu",
        "precision": sim.precision,
        "threads": numba.get_num_threads(),
        "dim": scene.dim,
        "particle_steps_per_s": (sim.n_particles * steps_in_loop / wall_loop) if wall_loop > 0 else None,
        "loop": {"steps": steps_in_loop, "wall_s": wall_loop,
                 "note": "stepping loop only: excludes set-up and the first (compiling) step"},
        "startup": {"setup_s": t_setup, "first_step_s": t_first,
                    "note": "first_step_s includes numba compilation, or loading it from the on-disk cache"},
        "stages": stages,
        "dt": {"last": sim.dt, "binding_limit_steps": limits},
        "neighbours": {"mean": float(counts.mean()) if counts.size else 0.0,
                       "max": int(counts.max()) if counts.size else 0, "max_over_run": sim.max_neighbours},
        "leaks": sim.leaks,
        "max_compression": sim.max_compression,
        "kinetic_energy": sim.kinetic_energy(),
        "bytes_sent": 0,
        "machine": {"python": platform.python_version(), "platform": platform.platform(),
                    "numba": numba.__version__, "numpy": np.__version__},
    }
