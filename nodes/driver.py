"""The one run driver: a peer stepped to the end of the run, with its outputs, checkpoints and
control commands, over any ``nodes.endpoint.Endpoint``.

    drive(peer, plan, frames)    generator; yields only while its endpoint waits (in-process)

The same loop runs everywhere, with different endpoints:

    one process (launch/run.py)        peer 0 of 1, NULL_HALO, an in-process endpoint; its frames go
                                       to its own Viewer
    in-process cluster (cluster.py)    N peers on an InProcessNetwork, resumed in turn
    a peer process (``run_peer``)      one peer on a ZenohEndpoint, which blocks instead of yielding
                                       (``run_blocking``); frames are published to any viewer

After the last step every peer sends rank 0 its owned particles and statistics ("final"), rank 0
writes the contract outputs (``write_outputs``: summary.json, final.npz, scene.toml) and says "bye".
``advance`` is the stepping loop itself (first step timed apart, progress); ``make_summary``,
``checkpoint_record`` and ``resolved_scene`` are the parts of the outputs every run shares.
"""
from __future__ import annotations

import json
import logging
import os
import platform
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Protocol

import numba
import numpy as np

from nodes.endpoint import Endpoint, TransportError
from nodes.frames import FrameMaker, domain_box
from nodes.peer import (Controls, PeerRecorder, _empty_check, _entry_check, _final_check, decomposition_for,
                        message_limit, peer_summary, take_block)
from nodes.viewer import frame_arrays
from sphcore import __version__, checkpoint
from sphcore.halo import PeerHalo
from sphcore.output import write_final, write_scene, write_summary
from sphcore.probes import ProbeWriter
from sphcore.scene import Scene
from sphcore.solver import Simulation, SimulationError
from sphcore.state import merge_by_id

log = logging.getLogger("sph.run")
peer_log = logging.getLogger("sph.peer")


@dataclass(frozen=True)
class RunPlan:
    """What a run does besides stepping: how far it goes and what it writes and reports."""

    steps: int | None = None              # run to this step (a resumed run counts from its checkpoint)
    until: float | None = None            # ... or to this simulated time; neither: the scene's time.steps
    out: Path | None = None               # where rank 0 writes the contract outputs (None: nowhere)
    checkpoint_every: int | None = None   # steps between checkpoints (None: output.checkpoint_every)
    checkpoint_root: Path | None = None   # checkpoints (and VTK pieces: its parent); None: out/checkpoints
    progress: bool = True                 # rank 0 shows a progress bar or log lines
    report: Callable[[int], None] | None = None  # called with the step number after every step
    restarts: list | None = None          # the launcher's restart history, for summary.json
    summary_every_s: float = 10.0         # rank 0 rewrites OUT/summary.json (atomically) this often
    stop: Callable[[], str | None] | None = None  # after each step: the signal asking to stop, or None


class OutputError(ValueError):
    """The output folder cannot be created or written; checked before the first step."""


def prepare_output(out: Path):
    """Create ``out`` and make sure a file can be written there (created and removed), before any
    step runs; OutputError (one line) says why not."""
    out = Path(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / f".write-test-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as e:
        raise OutputError(f"--out {str(out)!r}: cannot write there ({e.strerror or e}"
                          f"{': ' + e.filename if e.filename and str(e.filename) != str(out) else ''})") from None


@dataclass
class PeerRun:
    """One peer of a run, set up and ready to step. ``dec`` None: a single process (NULL_HALO,
    control commands from its endpoint applied after each step, nothing to gather, the
    single-process summary)."""

    sim: Simulation
    scene: Scene
    halo: object                          # NULL_HALO or a PeerHalo over ``endpoint``
    endpoint: Endpoint
    rank: int = 0
    world: int = 1
    dec: object = None                    # the starting Decomposition (None: one process)
    t_start: float = 0.0                  # perf_counter() when set-up began
    t_setup: float = 0.0                  # seconds of set-up


class FrameSink(Protocol):
    """Where a run's frames go: its own Viewer (one process) or the endpoint (peers)."""

    maker: FrameMaker                     # renders this peer's framelet (control commands change it)

    def show(self, sim: Simulation) -> None:
        """After each step: render and hand on a frame if one is due."""

    def close(self) -> None:
        """After the stepping loop, also when it failed: flush what is pending."""

    def summary(self) -> dict | None:
        """summary.json's "viewer", or None for none."""

    def end(self, step: int) -> None:
        """After the outputs are written: tell any viewer the run is over."""


class PublishFrames:
    """A peer's frames: published to any viewer on the endpoint, rendered only while one listens."""

    def __init__(self, maker: FrameMaker, endpoint: Endpoint):
        self.maker, self.endpoint = maker, endpoint

    def show(self, sim: Simulation):
        if self.maker.due(sim) and self.endpoint.viewer_listening():
            frame, stats, points, surface = self.maker.make(sim, sum(self.endpoint.bytes_sent.values()))
            with sim.timers("publish"):
                self.endpoint.publish_frame(sim.step_index, "frame", frame_arrays(frame, stats, points, surface))

    def close(self):
        pass

    def summary(self):
        return None

    def end(self, step: int):
        self.endpoint.publish_frame(step, "end", {}, reliable=True)  # the viewer flushes and stops


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


def run_blocking(gen):
    """The value of a driver generator whose endpoint blocks instead of yielding (a single process,
    a Zenoh peer)."""
    try:
        next(gen)
    except StopIteration as done:
        return done.value
    gen.close()
    raise RuntimeError("the run yielded: its endpoint does not block (drive in-process peers with nodes.cluster)")


def advance(sim: Simulation, halo, scene: Scene, steps: int | None, until: float | None, progress: bool,
            on_step=None, stop=None):
    """Generator: step ``sim`` (over ``halo``) for ``steps`` steps or until simulated time ``until``
    (else the scene's time.steps; a resumed run counts from its checkpoint's step); ``on_step(seconds)``
    (a generator function) runs after each step (seconds None for the first, untimed one); ``stop()``
    after each step returns the name of a signal that asks the run to end there (or None). Returns
    the loop timings (and "interrupted": the signal, if one stopped it): the first step (numba
    compilation or cache load) is timed apart from the loop, so that particle-steps/s measures
    stepping only."""
    target_steps = steps if steps is not None else (None if until is not None else scene.time.steps)

    def cap():
        return (until - sim.t) if until is not None else None

    t0 = time.perf_counter()
    if target_steps != 0 and (until is None or sim.t < until) and (target_steps is None
                                                                    or sim.step_index < target_steps):
        yield from sim.stages(halo, cap())
        if on_step is not None:
            yield from on_step(None)  # not timed: this step compiled the kernels
    t_first = time.perf_counter() - t0
    sim.timers.reset()
    steps_in_loop = 0
    interrupted = stop() if stop is not None else None  # a signal during the first step
    total = target_steps if target_steps is not None else until
    bar = Progress(total, "steps" if target_steps is not None else "s", scene.run.log_every, enabled=progress)
    t_loop = time.perf_counter()
    try:
        while interrupted is None:
            if target_steps is not None and sim.step_index >= target_steps:
                break
            if until is not None and sim.t >= until * (1 - 1e-12):
                break
            t_step = time.perf_counter()
            yield from sim.stages(halo, cap())
            now = time.perf_counter()
            if on_step is not None:
                yield from on_step(now - t_step)
            steps_in_loop += 1
            rate = sim.n_particles * steps_in_loop / (now - t_loop)
            bar.update(sim.step_index if target_steps is not None else sim.t, sim.step_index, sim, rate)
            if stop is not None:
                interrupted = stop()
    finally:
        bar.close()
    loop = {"steps": steps_in_loop, "wall_s": time.perf_counter() - t_loop, "first_step_s": t_first}
    if interrupted is not None:
        loop["interrupted"] = interrupted
    return loop


class _EventFeed(logging.Handler):
    """What a peer tells the viewer's event log with its frames (FrameMaker.event): cuts moved by a
    rebalance, a restart from a checkpoint, and its own warnings and errors (the ``sph`` loggers)."""

    def __init__(self, maker, halo, restarts, step: int):
        super().__init__(logging.WARNING)
        self.maker, self.halo = maker, halo
        self.cuts = _cuts(halo)
        if maker is None:
            return
        maker.exchange_bytes = getattr(halo, "bytes_sent", None)  # plotted per exchange by the viewer
        if restarts:
            maker.event("WARN", f"step {step}: restarted from a checkpoint (restart {len(restarts)} of this run)")
        logging.getLogger("sph").addHandler(self)

    def emit(self, record):
        if self.maker is not None:
            self.maker.event("ERROR" if record.levelno >= logging.ERROR else "WARN", record.getMessage()[:500])

    def after_step(self, step: int):
        cuts = _cuts(self.halo)
        if self.maker is not None and cuts != self.cuts:
            self.maker.event("INFO", f"step {step}: rebalanced, cuts now {cuts}")
        self.cuts = cuts

    def close(self):
        logging.getLogger("sph").removeHandler(self)
        super().close()


def _cuts(halo):
    dec = getattr(halo, "dec", None)
    return [[round(float(c), 6) for c in axis] for axis in dec.cuts] if dec is not None else None


def drive(peer: PeerRun, plan: RunPlan, frames: FrameSink | None = None):
    """Generator: run ``peer`` to the end of ``plan``; rank 0 writes the outputs and returns the
    summary (the others return None). Checkpoints: every peer writes its part and sends rank 0 its
    entry, rank 0 commits when every part was written (a part that fails, e.g. on a full disk, drops
    that checkpoint; the run goes on)."""
    sim, scene, halo, endpoint, rank, world = peer.sim, peer.scene, peer.halo, peer.endpoint, peer.rank, peer.world
    single = peer.dec is None
    recorder = None if single else PeerRecorder(sim, endpoint)
    every = scene.output.checkpoint_every if plan.checkpoint_every is None else plan.checkpoint_every
    root = plan.checkpoint_root if plan.checkpoint_root is not None else (
        plan.out / "checkpoints" if plan.out is not None else None)
    saved = Checkpoints(peer, root, every)
    controls = Controls(sim, halo, endpoint, frames.maker if frames is not None else None, rank, world,
                        checkpoint=saved.save if root is not None else None,
                        keep_block=None if single else (lambda: take_block(sim, halo.dec, rank)), stop=plan.stop,
                        on_set=lambda key, value: live_change(key, value),
                        on_hold=lambda held: progress("paused" if held else "running"))
    maker = frames.maker if frames is not None else None
    events = _EventFeed(maker, halo, plan.restarts, sim.step_index)
    probes = None  # rank 0 writes OUT/probes.csv (a resumed run keeps the rows up to its step)
    if plan.out is not None:  # before the first step: a run that cannot keep its result does not start
        prepare_output(plan.out)
        if rank == 0 and sim.probes.items:  # before the summary: a probes.csv it refuses leaves no "running" run
            probes = ProbeWriter(plan.out / "probes.csv", sim.probes, sim.step_index)
        write_summary(plan.out / "summary.json", progress_summary(sim, scene, world, peer.t_start, "running"))
    last_summary = [time.perf_counter()]
    vtk = None
    if scene.output.vtk_every:
        from sphcore.vtk import VtkWriter  # VTK is loaded only by runs that write it
        vtk = VtkWriter(root.parent, scene, rank, world)

    def progress(status: str):
        """Rank 0 rewrites summary.json while the run goes on: where it is, what was applied."""
        if plan.out is not None:
            write_summary(plan.out / "summary.json", dict(progress_summary(sim, scene, world, peer.t_start, status),
                                                          controls=[list(c) for c in controls.applied]))
        last_summary[0] = time.perf_counter()

    def live_change(key, value):
        """A key changed during the run (control ``set``) that the driver itself reads: how often it
        writes checkpoints and VTK files, and how often and by what the peers balance."""
        nonlocal every, vtk
        if key == "output.checkpoint_every":
            every = saved.record["every"] = value
        elif key == "output.vtk_every" and root is not None:
            if vtk is None and value:
                from sphcore.vtk import VtkWriter
                vtk = VtkWriter(root.parent, sim.scene, rank, world)
            if vtk is not None:
                vtk.every = value
        elif key in ("decomposition.balance_every", "decomposition.balance_by") and not single:
            setattr(halo, key.split(".")[1], value)

    def block_box():
        if single:
            return None
        lo, hi = halo.dec.cell_box(rank)
        g = sim.grid
        return g.origin + lo * g.cell.astype(np.float64), g.origin + hi * g.cell.astype(np.float64)

    if maker is not None:
        maker.block_box = block_box  # the live surface's nodes: this peer's block, wherever rebalancing moved it

    def on_step(seconds):
        if recorder is not None:
            recorder(seconds)
        yield from controls.after_step()
        if every and sim.step_index % every == 0 and controls.checkpointed != sim.step_index:
            yield from saved.save()
        if plan.report is not None:
            plan.report(sim.step_index)
        if probes is not None:
            probes.after_step()
        if vtk is not None and vtk.due(sim):
            vtk.write(sim, block_box())
        if frames is not None:
            events.after_step(sim.step_index)
            frames.show(sim)
        if time.perf_counter() - last_summary[0] >= plan.summary_every_s:
            progress("running")

    try:
        loop = yield from advance(sim, halo, scene, plan.steps, plan.until, plan.progress and rank == 0,
                                  on_step=on_step, stop=plan.stop)
    except SimulationError as e:  # a health stop: summary.json says so; no final.npz (the step is half done)
        if plan.out is not None and rank == 0:
            write_summary(plan.out / "summary.json", dict(
                progress_summary(sim, scene, world, peer.t_start, "stopped"), stopped=str(e),
                health=sim.health.summary(), controls=[list(c) for c in controls.applied]))
        raise
    finally:
        events.close()
        if probes is not None:
            probes.close()
        if frames is not None:
            frames.close()
    controls.finish()
    if single:
        arrays = sim.final_arrays()
        summary = make_summary(sim, scene, loop, peer.t_setup, time.perf_counter() - peer.t_start)
    else:
        gathered = yield from _gather(peer, recorder, controls, loop)
        if gathered is None:  # not rank 0: rank 0 has written the outputs and said "bye"
            return None
        arrays, peers = gathered
        summary = make_summary(sim, scene, loop, peer.t_setup, time.perf_counter() - peer.t_start)
        summary.update(peer_summary(peers, summary, world, sim.dtype.itemsize))
    step = sim.step_index
    summary["controls"] = [list(c) for c in controls.applied]  # [step, command] (every peer applied the same)
    if every or saved.record["written"] or saved.record["failed"]:
        summary["checkpoints"] = saved.record
    if plan.restarts is not None:
        summary["restarts"] = plan.restarts
    if sim.probes.items:
        summary["probes"] = sim.probes.summary()
    summary["status"] = "complete"
    if "interrupted" in loop:  # stopped by a signal at the end of a step: the state is that step's
        summary["status"] = "interrupted"
        summary["interrupted"] = {"signal": loop["interrupted"], "step": step}
        arrays = dict(arrays, interrupted_step=np.array(step, dtype=np.int64))
    shown = frames.summary() if frames is not None else None
    if shown is not None:
        summary["viewer"] = shown
    if plan.out is not None:
        if any(scene.origin):  # world coordinates, in float64: origin + x is exact there (scene_origin)
            arrays = dict(arrays, x=arrays["x"].astype(np.float64) + np.array(scene.origin))
        write_outputs(plan.out, resolved_scene(scene, sim), arrays, summary)
    for q in range(1, world):
        endpoint.send(q, (step, "bye"), {})
    endpoint.wait_until_alone()
    if frames is not None:
        frames.end(step)
    return summary


class Checkpoints:
    """A run's checkpoints: every peer writes its part of the step and sends rank 0 its entry (or
    the error that kept it from writing it); rank 0 commits when every part was written, else drops
    the step (one warning, counted in ``record``: summary.json's "checkpoints")."""

    def __init__(self, peer: PeerRun, root: Path | None, every: int):
        self.peer, self.root = peer, root
        self.record = checkpoint_record(every)

    def save(self):
        """Generator: checkpoint the peer's current step."""
        sim, scene, endpoint, rank = self.peer.sim, self.peer.scene, self.peer.endpoint, self.peer.rank
        step = sim.step_index
        who = "" if self.peer.dec is None else f"peer {rank}: "  # one process: the error alone
        try:
            part = checkpoint.write_part(self.root, step, rank, sim)
        except checkpoint.CheckpointWriteError as e:
            part = {"error": f"{who}{e}"}
        if rank != 0:
            endpoint.send(0, (step, "ckpt"), {"entry": np.frombuffer(json.dumps(part).encode(), dtype=np.uint8)})
            return
        parts = [part]
        for q in range(1, self.peer.world):
            msg = yield from endpoint.recv(q, (step, "ckpt"), _entry_check)
            parts.append(json.loads(bytes(msg["entry"]).decode()))
        failed = [p["error"] for p in parts if "error" in p]
        if not failed:
            try:
                checkpoint.commit(self.root, step, checkpoint.sim_info(sim), resolved_scene(scene, sim), parts,
                                  sim.scene.output.checkpoint_keep)  # as the run has it now
            except checkpoint.CheckpointWriteError as e:
                failed = [f"{who}{e}"]
        if failed:
            checkpoint.discard(self.root, step)
            checkpoint_failed(self.record, step, "; ".join(failed))
        else:
            self.record["written"] += 1
            self.record["last"] = step


def _gather(peer: PeerRun, recorder: PeerRecorder, controls: Controls, loop: dict):
    """Generator: every rank sends rank 0 its owned particles and statistics; rank 0 returns them
    merged by id and every peer's statistics, the others None once rank 0 has said "bye"."""
    sim, halo, endpoint, rank, world = peer.sim, peer.halo, peer.endpoint, peer.rank, peer.world
    yield from sim.refresh_stages(halo)
    v = sim.synchronised_velocity()
    s = sim.state
    n = s.n_owned
    stats = {
        "rank": rank, "block": list(peer.dec.block_of(rank)), "particles_final": n,
        "particles": recorder.particles, "step_s": recorder.step_s, "wait_s": recorder.wait_s,
        "stages": sim.timers.summary(), "loop": loop, "setup_s": peer.t_setup,
        "bytes_sent": dict(endpoint.bytes_sent), "array_bytes_sent": dict(halo.bytes_sent),
        "wait_s_per_phase": dict(recorder.wait_s_per_phase),
        "ghosts": int(s.n - n), "ghosts_received": halo.ghosts_received, "leaks": sim.leaks,
        "kinetic_energy": sim.kinetic_energy(),
        "neighbours_sum": sim.neighbours_sum, "neighbours_max": sim.neighbours_max,
        "neighbours_max_over_run": sim.max_neighbours, "rebalances": halo.rebalances,
        "dropped_messages": endpoint.dropped, "dropped": endpoint.drops, "resends": endpoint.resends,
        "threads": numba.get_num_threads(),
        "device_transfer": sim.engine.transfer(),
        "overlap": {"interior_rows": halo.overlapped_rows, "boundary_rows": halo.after_rows},
        "cuts": [list(c) for c in halo.dec.cuts], "controls": controls.applied,
    }
    final = {"id": s.id[:n], "x": s.x[:n], "v": np.ascontiguousarray(v[:n]), "rho": s.rho[:n],
             "stats": np.frombuffer(json.dumps(stats).encode(), dtype=np.uint8)}
    step = sim.step_index
    if rank != 0:
        endpoint.send(0, (step, "final"), final)
        yield from endpoint.recv(0, (step, "bye"), _empty_check)
        return None
    parts, peers = [final], [stats]
    for q in range(1, world):
        parts.append((yield from endpoint.recv(q, (step, "final"), _final_check(sim, q, stats, parts, peers))))
    peers[0].update(dropped_messages=endpoint.dropped, dropped=endpoint.drops,  # what came in while gathering too
                    resends=endpoint.resends)
    arrays = merge_by_id(parts, ("id", "x", "v", "rho"))
    if len(arrays["id"]) != sim.n_particles or np.any(np.diff(arrays["id"]) <= 0):
        raise RuntimeError(f"gathered {len(arrays['id'])} particles with "
                           f"{len(arrays['id']) - len(np.unique(arrays['id']))} duplicates; the scene has "
                           f"{sim.n_particles}")
    return arrays, peers


def run_peer(scene: Scene, rank: int, world: int, endpoint: Endpoint, plan: RunPlan, precision: str | None = None,
             backend: str = "cpu", device: int | None = None, resume=None, frames: bool = True,
             startup_timeout: float = 120.0) -> dict | None:
    """Run peer ``rank`` of ``world`` over ``endpoint`` (a ZenohEndpoint: it blocks) to the end of
    ``plan``; rank 0 writes ``plan.out`` and returns the summary. With ``frames`` (and render.every
    > 0) the peer renders and publishes a framelet every render.every steps while a viewer is
    subscribed. ``resume``: a loaded checkpoint (any number of peers may have written it). One GPU
    per peer: rank r takes GPU r modulo the GPUs visible, unless ``device`` says otherwise."""
    t_start = time.perf_counter()
    sim = Simulation(scene, precision, backend, rank if device is None else device)
    if resume is not None:
        checkpoint.restore(sim, resume)
    dec = decomposition_for(scene, sim.grid, world, sim.state.x)
    take_block(sim, dec, rank)
    halo = PeerHalo(dec, rank, endpoint, scene.decomposition.balance_every, scene.decomposition.balance_by,
                    scene.decomposition.overlap)
    endpoint.at_step(sim.step_index)  # earlier steps are replays; steps far ahead are not from this run
    endpoint.set_message_limit(message_limit(sim))
    t_setup = time.perf_counter() - t_start
    peer_log.info("peer %d/%d: block %s of %s, %d of %d particles, %d numba threads", rank, world,
                  dec.block_of(rank), dec.dims, sim.state.n_owned, sim.n_particles, numba.get_num_threads())
    endpoint.wait_for_peers(startup_timeout)
    sink = None
    if frames and scene.render.every:
        sink = PublishFrames(FrameMaker(scene, domain_box(scene), rank, world, sim.n_particles), endpoint)
    peer = PeerRun(sim, scene, halo, endpoint, rank, world, dec, t_start, t_setup)
    return run_blocking(drive(peer, plan, sink))


def listen_for_control(out: Path, secure: bool = True):
    """The control channel of a single-process run (``sph run --control``): this process as peer 0
    of 1 on a Zenoh endpoint listening on a free loopback port, with the run's credentials in
    OUT/tls (as a multi-peer run makes them: ``sph control OUT CMD`` uses the controller's) and
    OUT/run.json saying where; ``secure`` False: plain TCP (``--insecure``). Returns the endpoint
    (close it after the run). OutputError if OUT cannot be written, TransportError if Zenoh cannot
    listen there."""
    import shutil
    import socket
    import uuid

    from nodes import security
    from nodes.zenoh_transport import ZenohEndpoint
    out = Path(out)
    prepare_output(out)
    run_id = uuid.uuid4().hex[:12]
    trust, folder = None, None
    if secure:
        folder = out / "tls"
        if folder.exists():
            shutil.rmtree(folder)
        ids = security.make_run_credentials(folder, [["127.0.0.1"]])
        trust = security.Trust(ids[security.peer_name(0)], run_id, 1)
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    where = f"{'tls' if secure else 'tcp'}/127.0.0.1:{port}"
    try:
        endpoint = ZenohEndpoint(run_id, 0, 1, [where], [], trust=trust)
    except Exception as e:  # zenoh raises its own ZError for an endpoint it cannot open
        raise TransportError(f"cannot listen for sph control at {where}: {e}") from None
    info = {"run_id": run_id, "world": 1, "endpoints": [where],
            "tls": str(folder.resolve()) if folder is not None else None, "launcher_pid": os.getpid()}
    tmp = out / ".run.json.tmp"
    tmp.write_text(json.dumps(info, indent=1) + "\n")
    os.replace(tmp, out / "run.json")
    log.info("run %s: listening for sph control %s COMMAND at %s", run_id, out, where)
    return endpoint


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


def progress_summary(sim: Simulation, scene: Scene, world: int, t_start: float, status: str) -> dict:
    """summary.json while the run goes on (written at the start and every RunPlan.summary_every_s):
    where it is; the full summary replaces it at the end."""
    return {"status": status, "scene": scene.scene.name, "source": scene.source, "version": __version__,
            "particles": sim.n_particles, "peers": world, "steps": sim.step_index, "sim_time": sim.t,
            "dt": {"last": sim.dt}, "wall_s": time.perf_counter() - t_start, "backend": sim.backend,
            "precision": sim.precision, "leaks": sim.leaks, "updated": time.strftime("%Y-%m-%dT%H:%M:%S%z")}


def _per_step(transfer: dict, steps: int) -> dict:
    """summary.json's ``device_transfer``: the bytes copied between host and device over the run (the
    set-up's upload of the state included) and their mean per step."""
    total = transfer["to_device_bytes"] + transfer["to_host_bytes"]
    return {**transfer, "per_step_bytes": total / max(steps, 1),
            "note": "explicit copies between host and device (state, halo rows, read-backs, moving walls)"}


def make_summary(sim: Simulation, scene: Scene, loop: dict, t_setup: float, wall_total: float) -> dict:
    """The summary.json every run writes (a multi-peer run adds ``nodes.peer.peer_summary``)."""
    stages = sim.timers.summary()
    n = sim.state.n_owned
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
        "origin": list(scene.origin),
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
        "neighbours": {"mean": sim.neighbours_sum / n if n else 0.0, "max": sim.neighbours_max,
                       "max_over_run": sim.max_neighbours, "search": sim.model.neighbours,
                       **({"skin": sim.grid.skin, "list_builds": sim.grid.builds, "list_reuses": sim.grid.reuses}
                          if sim.grid.skin else {})},
        "leaks": sim.leaks,
        **({"device_transfer": _per_step(sim.engine.transfer(), sim.step_index)} if sim.backend == "cuda" else {}),
        "max_compression": sim.max_compression,
        "kinetic_energy": sim.kinetic_energy(),
        "health": sim.health.summary(),
        **({"open_boundaries": sim.open.summary()} if sim.open.active else {}),
        "bodies": [{"obstacle": b.wall - sim.model.walls.container_walls - len(scene.domain.planes), "mass": b.mass,
                    "displacement": [float(c) for c in b.x], "velocity": [float(c) for c in b.v],
                    "force": [float(c) for c in b.force],
                    **({"orientation": [[float(c) for c in row] for row in b.R],
                        "angular_velocity": [float(c) for c in b.w], "torque": [float(c) for c in b.torque]}
                       if b.rotates else {})} for b in sim.model.walls.bodies],
        "bytes_sent": 0,
        "machine": {"python": platform.python_version(), "platform": platform.platform(),
                    "numba": numba.__version__, "numpy": np.__version__},
    }
