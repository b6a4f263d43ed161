"""A peer: owns one block of the decomposition, steps it, exchanges halos, reports at the end.

Every peer builds the whole scene's particles (same global ids as a single process) and keeps the
ones in its block (``take_block``); no master sends it anything. The run driver
(``nodes.driver.drive``) steps the block with the same loop as a single-process run, applies
control commands (``Controls``), records per-step statistics (``PeerRecorder``), then gathers to
rank 0, which checks what it receives (``_final_check``, ``_entry_check``), writes the contract
outputs and adds ``peer_summary``:

    every rank -> 0   "final": owned id, x, v, rho + this peer's statistics (JSON as bytes)
    0 -> every rank   "bye":   outputs written; peers close (rank 0 closes last)
"""
from __future__ import annotations

import json
import logging
import re

import numpy as np

from nodes import control
from nodes.endpoint import PeerTimeout
from sphcore import checkpoint
from sphcore.decomposition import Decomposition, choose_dims
from sphcore.halo import MAX_CONTROL_BYTES, Reject, decode_commands, encode_commands, expect_arrays, has_repeats
from sphcore.physics.traction import MOMENTS
from sphcore.solver import Simulation

log = logging.getLogger("sph.peer")


def decomposition_for(scene, grid, n_peers: int, x=None) -> Decomposition:
    """The starting decomposition of ``scene`` for ``n_peers`` (scene [decomposition] dims/layout):
    cuts balanced by particle count when the initial positions ``x`` are given (every peer has them,
    so every peer computes the same cuts), else uniform. The automatic layout leaves gravity's axis
    uncut where it can and, given ``x``, gives the busiest peer the least work: its particles and its
    share of the halo (``choose_dims``)."""
    dims = scene.decomposition.dims
    if any(dims):
        if int(np.prod(dims)) != n_peers:
            raise ValueError(f"decomposition.dims = {list(dims)} makes {int(np.prod(dims))} blocks, but the run "
                             f"has {n_peers} peers")
    periodic = tuple(bool(p > 0) for p in grid.period)
    ncell = tuple(int(n) for n in grid.ncell)
    cells = None if x is None else grid.cells_of(x)
    if not any(dims):
        g = np.abs(np.asarray(scene.forces.gravity[: scene.dim], dtype=np.float64))
        vertical = int(np.argmax(g)) if g.any() else None
        dims = choose_dims(n_peers, grid.ncell, scene.dim, scene.decomposition.layout, reach=grid.reach,
                           cells=cells, periodic=periodic, vertical=vertical)
    if x is None:
        return Decomposition.uniform(ncell, dims, periodic, reach=grid.reach)
    return Decomposition.balanced(ncell, dims, cells, periodic, reach=grid.reach)


def take_block(sim: Simulation, dec: Decomposition, rank: int):
    """Keep only the particles of ``sim`` in the block of ``rank``: every field and every carried
    array (``state.extra``: DFSPH's kappa, the continuity density) filtered alike (``ParticleState.take``)."""
    s = sim.state
    sim.state = s.take(dec.owner(sim.grid.cells_of(s.x)) == rank)


class PeerRecorder:
    """Per-step bookkeeping of one peer: particles held, step seconds, seconds spent waiting; and
    ``wait_s_per_phase``, the seconds waited per halo phase over the same timed steps (the endpoint's
    own totals also count the first, compiling step, where a peer waits for the others' compilers)."""

    def __init__(self, sim: Simulation, endpoint):
        self.sim, self.endpoint = sim, endpoint
        self.particles, self.step_s, self.wait_s = [], [], []
        self.wait_s_per_phase = {}
        self._waited = 0.0
        self._phases_before = {}  # the endpoint's per-phase totals when the timed steps began

    def __call__(self, seconds: float | None):
        if seconds is None:  # the first step (compilation): not part of the statistics
            self._waited = sum(self.endpoint.wait_s.values())
            self._phases_before = dict(self.endpoint.wait_s)
            return
        waited = sum(self.endpoint.wait_s.values())
        self.particles.append(self.sim.engine.n_owned())  # not sim.state: on a GPU that downloads every row
        self.step_s.append(seconds)
        self.wait_s.append(waited - self._waited)
        self._waited = waited
        self.wait_s_per_phase = {phase: total - self._phases_before.get(phase, 0.0)
                                 for phase, total in self.endpoint.wait_s.items()
                                 if total > self._phases_before.get(phase, 0.0)}
        self.endpoint.check()


class Controls:
    """Control commands (nodes/control.py) on a peer, or in a single process (peer 0 of 1).

    Rank 0 takes what its endpoint received on the controller's key, validates each command against
    the scene (as the commands before it leave it) and answers on the ack key: rejected with the
    reason, or accepted at step N, the step after which every peer applies it. With several peers,
    accepted commands go out in the step's reduction (``PeerHalo.control_source``); the other peers
    check what they are announced (``PeerHalo.control_check``: an announcement that is not a valid
    command is dropped like any forged message), and after the step every peer applies them. A
    single process takes and applies them after each step.

    ``pause`` holds every peer after that step until rank 0 gets ``resume`` or ``step N`` (which
    resumes and holds again N steps later: rank 0 announces that pause itself). While the run is
    held, rank 0 goes on answering: every other command (set, reset, checkpoint, camera, color_by)
    is applied at once, on every peer, at the held step (rank 0 sends what it accepted since its
    last poll to the others in one "hold<i>" message; the last one says resume). Every command is
    acknowledged, so whoever paused a run is told so; a pause while paused or a resume while running
    is rejected with the reason.
    What was applied is ``applied`` [(step, description)] (summary.json) and logged."""

    def __init__(self, sim, halo, endpoint, maker, rank: int = 0, world: int = 1, checkpoint=None, keep_block=None,
                 stop=None, on_set=None, on_hold=None):
        """``checkpoint``: a generator function writing this peer's checkpoint of the current step
        (None: the run writes none, and the command is rejected); ``keep_block``: after a reset,
        keep only this peer's particles (None: a single process keeps them all); ``stop()``: the
        signal asking the run to end, or None (a held single process then goes on, to stop);
        ``on_set(key, value)``: after a ``set``, for the keys the run driver reads itself (how often
        it checkpoints, writes VTK files, balances); ``on_hold(held)``: when the run is held and when it
        goes on (rank 0 marks summary.json "paused")."""
        self.sim, self.halo, self.endpoint, self.maker = sim, halo, endpoint, maker
        self.rank, self.world = rank, world
        self.checkpoint, self.keep_block, self.stop, self.on_set = checkpoint, keep_block, stop, on_set
        self.on_hold = on_hold
        self.applied = []        # (step, description), for the summary
        self.checkpointed = None  # the step of the last checkpoint a command wrote (the run's own is then skipped)
        self._leftover = []      # rank 0: commands that arrived with a resume, validated as in a running run
        self._paused_at = None   # rank 0: the step after which the run is held
        self._pause_after = None  # rank 0: step N's pause: hold after this step
        self.cameras = ["default"] + [c.name for c in sim.scene.render.cameras]
        self.others = [q for q in range(world) if q != rank]
        if world > 1 and rank == 0:
            halo.control_source = self._announce
        elif world > 1:
            halo.control_check = self._check_announced

    def _validate(self, entry: dict, scene, step: int):
        """(command, the scene after it) of a received command ({"id", "text"}), or None after
        acknowledging its rejection (``step``: the step the run is at, for the ack)."""
        try:
            cmd, after = control.validate(scene, control.parse(entry["text"]), self.cameras, self.sim,
                                          self.checkpoint is not None)
            if cmd["op"] == "resume" and self._paused_at is None:
                raise ValueError("resume: the run is not paused")
            if cmd["op"] == "pause" and self._paused_at is not None:
                raise ValueError(f"pause: the run is already paused after step {self._paused_at}")
        except ValueError as e:
            self._reject(entry, step, str(e))
            return None
        return cmd, after

    def _reject(self, entry: dict, step: int, reason: str):
        log.warning("peer 0: rejected control command %r: %s", entry["text"][:80], reason)
        self.endpoint.send_ack(entry["id"], "rejected", step, reason)

    def _accept(self, entry: dict, cmd: dict, step: int):
        self.endpoint.send_ack(entry["id"], "accepted", step)
        log.info("peer 0: accepted control command %r for step %d", control.describe(cmd), step)

    def _batch(self, step: int) -> list:
        """Rank 0, running: the commands to apply after ``step`` (the step in progress, with several
        peers; the step just done, in one process), each answered; step N schedules its pause."""
        out, scene = [], self.sim.scene
        entries, self._leftover = self._leftover + self.endpoint.take_commands(), []
        for entry in entries:
            checked = self._validate(entry, scene, step)
            if checked is None:
                continue
            cmd, scene = checked
            if cmd["op"] == "pause" and (self._pause_after == step or any(c["op"] == "pause" for c in out)):
                self._reject(entry, step, f"pause: a pause is already announced for step {step}")
                continue
            if cmd["op"] == "step":
                self._pause_after = step + cmd["count"]
                self._accept(entry, cmd, self._pause_after)
                continue
            out.append(cmd)
            self._accept(entry, cmd, step)
        if self._pause_after == step:
            self._pause_after = None
            if not any(c["op"] == "pause" for c in out):
                out.append({"op": "pause"})
        return out

    def _announce(self) -> list:
        """Rank 0, in the step's reduction (several peers): the commands to announce now."""
        return self._batch(self.sim.step_index + 1)

    def _check_announced(self, commands):
        try:
            control.check_announced(self.sim.scene, commands, self.cameras, self.sim)
        except ValueError as e:
            raise Reject("control", str(e)) from None

    def after_step(self):
        """Generator: apply the commands announced in this step's reduction (one process: received
        since the last step); a pause waits here."""
        if self.world == 1:
            commands = self._batch(self.sim.step_index)
        else:
            commands, self.halo.announced = self.halo.announced, []
        for cmd in commands:
            yield from self._apply(cmd)

    def _apply(self, cmd: dict):
        """Generator: apply one validated command on this peer."""
        step = self.sim.step_index
        text = control.describe(cmd)
        log.info("peer %d: step %d: %s", self.rank, step, text)
        self.applied.append((step, text))
        if self.maker is not None:
            self.maker.controls.append(text)
        op = cmd["op"]
        if op == "set":
            value = cmd["value"]
            value = tuple(value) if isinstance(value, list) else value
            try:
                self.sim.set_parameter(cmd["key"], value)
            except ValueError as e:  # validated before: only a combination could fail, alike on every peer
                log.error("peer %d: step %d: %s not applied: %s", self.rank, step, text, e)
            else:
                if self.on_set is not None:
                    self.on_set(cmd["key"], value)
        elif op == "camera" and self.maker is not None:
            self.maker.renderer.camera_name = cmd["name"]
        elif op == "color_by" and self.maker is not None:
            self.maker.renderer.set_quantity(cmd["quantity"])
        elif op == "reset":
            self.sim.reset()
            if self.keep_block is not None:
                self.keep_block()
        elif op == "checkpoint" and self.checkpoint is not None:
            yield from self.checkpoint()
            self.checkpointed = step
        elif op == "pause":
            yield from self._paused()

    def _release(self, step: int, index: int, commands: list, resume: bool):
        """Rank 0, held: send the other peers what to apply now (and whether to go on)."""
        for q in self.others:
            self.endpoint.send(q, (step, f"hold{index}"), {"control": encode_commands(commands),
                                                           "resume": np.array([int(resume)], dtype=np.uint8)})

    def _paused(self):
        """Generator: hold until resume (or step N); rank 0 answers the commands that arrive
        meanwhile and applies them at once on every peer."""
        step = self.sim.step_index
        index = 0
        if self.on_hold is not None:
            self.on_hold(True)
        if self.rank == 0:
            self._paused_at = step
            while self._paused_at is not None:
                self.endpoint.check()
                batch, scene, entries = [], self.sim.scene, self.endpoint.take_commands()
                while entries:  # what came in since the last poll, validated in order, goes out as one message
                    entry = entries.pop(0)
                    checked = self._validate(entry, scene, step)
                    if checked is None:
                        continue
                    cmd, scene = checked
                    if cmd["op"] in ("resume", "step"):
                        self._paused_at = None
                        self._pause_after = step + cmd["count"] if cmd["op"] == "step" else None
                        self._accept(entry, cmd, self._pause_after if cmd["op"] == "step" else step)
                        self._leftover = entries  # validated as in a running run, at the next step
                        break
                    batch.append(cmd)
                    self._accept(entry, cmd, step)
                if self._paused_at is not None and self.stop is not None and self.stop() is not None:
                    log.warning("peer 0: %s while paused after step %d: going on, to stop", self.stop(), step)
                    self._paused_at = None
                if batch or self._paused_at is None:
                    self._release(step, index, batch, resume=self._paused_at is None)
                    index += 1
                for cmd in batch:
                    yield from self._apply(cmd)
                if self._paused_at is not None:
                    yield from self.endpoint.idle(0.05)
        else:
            while True:
                try:
                    msg = yield from self.endpoint.recv(0, (step, f"hold{index}"), self._hold_check, patient=True)
                except PeerTimeout:
                    continue  # paused as long as rank 0 says; a lost peer still raises PeerLost
                index += 1
                for cmd in msg["commands"]:
                    yield from self._apply(cmd)
                if msg["resume"]:
                    break
        if self.on_hold is not None:
            self.on_hold(False)
        log.info("peer %d: resumed after step %d", self.rank, step)

    def _hold_check(self, msg: dict):
        """What rank 0 sends while the run is held: {"control": commands as JSON bytes, "resume": one
        byte 0 or 1}, the commands valid ones (never a pause: the run is held already). The decoded
        commands and the flag are left in ``msg`` ("commands", "resume")."""
        if set(msg) != {"control", "resume"}:
            raise Reject("arrays", f"held commands: arrays {sorted(msg)[:8]}, expected control, resume")
        control_bytes, resume = msg["control"], msg["resume"]
        if control_bytes.dtype != np.uint8 or control_bytes.ndim != 1 or len(control_bytes) > MAX_CONTROL_BYTES:
            raise Reject("control", "held commands: not at most 64 kB of JSON bytes")
        if resume.dtype != np.uint8 or resume.shape != (1,) or int(resume[0]) not in (0, 1):
            raise Reject("control", "held commands: resume is not one byte 0 or 1")
        try:
            commands = decode_commands(control_bytes)
            control.check_announced(self.sim.scene, commands, self.cameras, self.sim,
                                    ops=tuple(op for op in control.ANNOUNCED if op != "pause"))
        except (ValueError, RecursionError) as e:
            raise Reject("control", f"held commands: {str(e)[:200]}") from None
        msg["commands"], msg["resume"] = commands, bool(resume[0])

    def finish(self):
        """Rank 0 at the end of the run: commands that came too late are rejected, not left unanswered."""
        if self.rank != 0:
            return
        step = self.sim.step_index
        for entry in self._leftover + self.endpoint.take_commands():
            self._reject(entry, step, f"the run ended at step {step}")
        self._leftover = []


HEADROOM = 1 << 20            # bytes: headers, control commands, checkpoint entries, a peer's statistics
STATS_BYTES_PER_STEP = 256    # the final message's per-step statistics (particles, step_s, wait_s as JSON)


def message_limit(sim: Simulation):
    """(phase, step) -> the most bytes a genuine message of this run can have: every particle of the
    scene with all it carries (a rebalance may move them all to one peer), the balance histograms,
    and room for the rest; the final gather also carries per-step statistics, which grow with the
    step; a floating body's traction sums carry MOMENTS int64 for each point of its surface. Anything
    longer is dropped unread (nodes/zenoh_transport.py)."""
    s = sim.state
    per_row = s.per_particle().values()  # every field and every carried extra array
    row = sum(a.itemsize * int(np.prod(a.shape[1:])) for a in per_row)
    surfaces = sum(len(body.surface[0]) for body in sim.model.walls.bodies if body.surface)
    base = (HEADROOM + sim.n_particles * row + 3 * 8 * int(np.sum(sim.grid.ncell))
            + 8 * MOMENTS * surfaces)

    def limit(phase: str, step: int) -> int:
        return base + (STATS_BYTES_PER_STEP * max(step, 0) if phase == "final" else 0)

    return limit


def _empty_check(msg: dict):
    """The "resume" and "bye" messages carry nothing."""
    if msg:
        raise Reject("arrays", f"arrays {sorted(msg)[:8]} where none belong")


def _json_of(array, what: str):
    if array.dtype != np.uint8 or array.ndim != 1:
        raise Reject("dtype", f"{what} is {array.dtype}{list(array.shape)}, expected bytes")
    try:
        return json.loads(bytes(array).decode())
    except (ValueError, RecursionError) as e:
        raise Reject("malformed", f"{what}: not JSON ({e})") from None


_SHA256 = re.compile(r"^[0-9a-f]{64}$")


def _entry_check(msg: dict):
    """A checkpoint entry (rank 0 commits what every peer wrote into the manifest): a JSON object,
    either {"error": text} or {"file": peer_NNNN.npz, "particles": n, "sha256": hex}; a file name
    with a path in it would make the manifest point outside the checkpoint."""
    if set(msg) != {"entry"}:
        raise Reject("arrays", f"checkpoint entry: arrays {sorted(msg)[:8]}, expected 'entry'")
    entry = _json_of(msg["entry"], "checkpoint entry")
    if isinstance(entry, dict) and set(entry) == {"error"} and isinstance(entry["error"], str):
        return
    if not (isinstance(entry, dict) and set(entry) == {"file", "particles", "sha256"}
            and isinstance(entry["file"], str) and checkpoint.is_part_name(entry["file"])
            and type(entry["particles"]) is int and entry["particles"] >= 0
            and isinstance(entry["sha256"], str) and _SHA256.match(entry["sha256"])):
        raise Reject("malformed", "checkpoint entry: expected {file: peer_NNNN.npz, particles, sha256} or {error}")


def _final_check(sim: Simulation, q: int, own: dict, parts: list, peers: list):
    """Rank 0's check of peer ``q``'s final message: its owned particles (id, x, v, rho in the run's
    dtype, finite, ids of this scene that no other peer reported) and statistics with the same
    fields and number of steps as rank 0's. The accepted one's statistics are appended to ``peers``."""

    def check(msg):
        what = f"final from peer {q}"
        ids = msg.get("id")
        if ids is None or ids.ndim != 1 or len(ids) > sim.n_particles:
            raise Reject("count", f"{what}: no id array of at most {sim.n_particles} particles")
        n, dtype = len(ids), sim.dtype
        expect_arrays(msg, {"id": ((n,), np.int64), "x": ((n, 3), dtype), "v": ((n, 3), dtype), "rho": ((n,), dtype),
                            "stats": (msg["stats"].shape, np.uint8)}, what)
        if n and (not sim.ids_valid(ids) or has_repeats(ids)
                  or any(np.isin(ids, p["id"]).any() for p in parts)):
            raise Reject("ids", f"{what}: ids outside {sim.ids_text()}, repeated, or reported by another peer")
        stats = _json_of(msg["stats"], f"{what}: statistics")
        if not (isinstance(stats, dict) and set(stats) == set(own) and stats["rank"] == q
                and stats["particles_final"] == n
                and all(isinstance(stats[k], list) and len(stats[k]) == len(own[k])
                        for k in ("particles", "step_s", "wait_s"))
                and _counts_ok(stats["device_transfer"], own["device_transfer"])
                and _counts_ok(stats["overlap"], own["overlap"])
                and _tallies_ok(stats["dropped"], 2) and _tallies_ok(stats["resends"], 2)
                and set(stats["resends"]) == set(own["resends"])):
            raise Reject("stats", f"{what}: statistics are not a peer's of this run")
        peers.append(stats)

    return check


def _counts_ok(theirs, own) -> bool:
    """A peer's ``device_transfer`` or ``overlap`` has the form of rank 0's: None, or counts (whole
    numbers >= 0) under the same keys."""
    if own is None or theirs is None:
        return own is None and theirs is None
    return _tallies_ok(theirs, 1) and set(theirs) == set(own)


def _tallies_ok(value, depth: int) -> bool:
    """``value`` is tallies ``depth`` dicts deep, as ``dropped`` ({source: {reason: n}}) and
    ``resends`` ({"asked" or "sent": {rank: n}}) are: short string keys, whole counts >= 0 at the
    bottom. Anything else from a peer would break the summary that adds them up."""
    if depth == 0:
        return type(value) is int and 0 <= value < 2**62
    return (isinstance(value, dict) and len(value) <= 4096
            and all(isinstance(k, str) and len(k) <= 64 and _tallies_ok(v, depth - 1) for k, v in value.items()))


def minimum_halo_bytes(ghosts: int, itemsize: int) -> int:
    """The least a halo exchange can send: per ghost, exchange 1's id (8 bytes) and x, v (3 floats
    each), m (1 float), and exchange 2's rho and p (2 floats); nothing else (no headers, no migrants,
    no reductions)."""
    return ghosts * (8 + 9 * itemsize)


def peer_summary(peers: list[dict], base: dict, world: int, itemsize: int) -> dict:
    """The multi-peer parts of summary.json from every peer's statistics."""
    particles = np.array([p["particles"] for p in peers], dtype=np.float64)    # (peers, steps)
    step_s = np.array([p["step_s"] for p in peers])
    wait_s = np.array([p["wait_s"] for p in peers])
    compute_s = step_s - wait_s
    steps = particles.shape[1]

    def imbalance(a):  # max over peers / mean over peers, per step
        mean = a.mean(0)
        return a.max(0) / np.where(mean > 0, mean, 1.0)

    phases = sorted({k for p in peers for k in p["bytes_sent"]})
    bytes_per_phase = {ph: int(sum(p["bytes_sent"].get(ph, 0) for p in peers)) for ph in phases}
    halo_bytes = sum(b for ph, b in bytes_per_phase.items() if ph != "frames")
    total_neighbours = sum(p["neighbours_sum"] for p in peers)
    minimum = minimum_halo_bytes(sum(p["ghosts_received"] for p in peers), itemsize)
    by_reason = {}
    for p in peers:
        for reasons in p["dropped"].values():
            for reason, count in reasons.items():
                by_reason[reason] = by_reason.get(reason, 0) + count
    out = {
        "peers": world,
        "dropped_messages": int(sum(p["dropped_messages"] for p in peers)),  # by source: per_peer[r]["dropped"]
        "dropped_by_reason": by_reason,
        "resent_messages": int(sum(sum(p["resends"]["sent"].values()) for p in peers)),  # per_peer[r]["resends"]
        "leaks": int(sum(p["leaks"] for p in peers)),
        "kinetic_energy": float(sum(p["kinetic_energy"] for p in peers)),
        "neighbours": {"mean": total_neighbours / base["particles"], "max": max(p["neighbours_max"] for p in peers),
                       "max_over_run": max(p["neighbours_max_over_run"] for p in peers),
                       **{k: base["neighbours"][k] for k in ("skin", "list_builds", "list_reuses")  # every peer's
                          if k in base["neighbours"]}},
        "bytes_sent": int(sum(bytes_per_phase.values())),
        "bytes_sent_per_phase": bytes_per_phase,
        "halo_bytes_minimum": minimum,
        "bytes_over_minimum": (halo_bytes / minimum) if minimum else None,
        "threads": [p["threads"] for p in peers],
        "imbalance": {
            "particles_max_over_mean": {"mean": float(imbalance(particles).mean()) if steps else None,
                                        "max": float(imbalance(particles).max()) if steps else None},
            "compute_s_max_over_mean": {"mean": float(imbalance(compute_s).mean()) if steps else None,
                                        "max": float(imbalance(compute_s).max()) if steps else None},
            "note": "per timed step, max over peers / mean over peers; 1.0 = perfectly balanced",
        },
        "per_peer": [{
            "rank": p["rank"], "block": p["block"], "particles_final": p["particles_final"],
            "particles_mean": float(np.mean(p["particles"])) if p["particles"] else float(p["particles_final"]),
            "ghosts_final": p["ghosts"], "step_s_total": float(np.sum(p["step_s"])),
            "wait_s_total": float(np.sum(p["wait_s"])), "wait_s_per_phase": p["wait_s_per_phase"],
            "compute_s_total": float(np.sum(p["step_s"]) - np.sum(p["wait_s"])),
            "bytes_sent": p["bytes_sent"], "array_bytes_sent": p["array_bytes_sent"],
            "stages": {k: v["total_s"] for k, v in p["stages"].items()},
            "rebalances": p["rebalances"], "dropped_messages": p["dropped_messages"], "dropped": p["dropped"],
            "resends": p["resends"], "cuts": p["cuts"],
            "controls": p["controls"],
            "overlap": p["overlap"],
        } for p in peers],
    }
    interior = sum(p["overlap"]["interior_rows"] for p in peers)
    boundary = sum(p["overlap"]["boundary_rows"] for p in peers)
    out["overlap"] = {
        "interior_fraction": interior / (interior + boundary) if interior + boundary else None,
        "note": "all peers: of the rows whose density (exchange 1), accelerations (exchange 2), vorticity "
                "confinement (exchange 3) or DFSPH passes waited for a halo exchange, the share computed while "
                "its messages travelled (rows out of reach of every ghost)"}
    if steps:
        out["bytes_per_step"] = {ph: b / max(1, base["steps"]) for ph, b in bytes_per_phase.items()}
    if peers[0]["device_transfer"] is not None:  # checked in _final_check: byte counts, or None on every peer
        for p, row in zip(peers, out["per_peer"]):
            row["device_transfer"] = p["device_transfer"]
        total = sum(v for p in peers for v in p["device_transfer"].values())
        out["device_transfer"] = {
            "to_device_bytes": sum(p["device_transfer"]["to_device_bytes"] for p in peers),
            "to_host_bytes": sum(p["device_transfer"]["to_host_bytes"] for p in peers),
            "per_step_bytes": total / max(1, base["steps"]),
            "note": "all peers: explicit copies between host and device (state, halo rows, read-backs, moving walls)"}
    return out
