"""Halo exchanges of a step: what a peer sends and receives, independent of how bytes travel.

``Simulation.stages`` calls three hooks; each is a generator that yields while it waits for
messages (a single process never waits):

    exchange_positions   1a migrants change owner; 1b ghosts' id, x, v, m arrive (exchange 1)
    exchange_fields      ghosts' rho, p arrive, in the order of exchange 1     (exchange 2)
    exchange_ghosts      any other per-particle value of the ghosts (vorticity omega), same order
    reduce_max           the global max of the step statistics (adaptive dt, health check)

Load balancing (``balance_every`` > 0): at the start of exchange 1 of every K-th step the peers sum
their per-axis particle histograms, all compute the same balanced cuts
(``Decomposition.from_histograms``) and send each particle straight to its new owner. Results stay
bitwise identical because every sum runs in (cell, id) order whatever the cuts.

``NULL_HALO`` is the single-process halo. ``PeerHalo`` implements the zone model of
``sphcore.decomposition`` over any transport endpoint with ``send(dest, tag, arrays)`` and a
generator ``recv(source, tag)`` (nodes/transport.py). Exchange 1 has two rounds: migrants first,
so that the ghosts each peer sends are drawn from its owned set *after* migration (a particle that
just crossed a cut can be a third peer's ghost; only its new owner knows to send it).
"""
from __future__ import annotations

import json

import numpy as np

from sphcore.state import ParticleState


class NullHalo:
    """No other peers: nothing to send, nothing to wait for."""

    def exchange_positions(self, sim):
        return
        yield

    def exchange_fields(self, sim):
        return
        yield

    def exchange_ghosts(self, sim, phase, arrays, kind=None):
        return
        yield

    def reduce_max(self, sim, stats):
        return stats
        yield

    def reduce_sum(self, sim, phase, value):
        return value
        yield


NULL_HALO = NullHalo()


def _carried(state, n) -> dict:
    """What travels with a particle to another peer: id, x, v, m and the state's extra arrays."""
    arrays = {name: getattr(state, name)[:n] for name in ("id", "x", "v", "m")}
    arrays.update({"extra_" + k: a[:n] for k, a in state.extra.items()})
    return arrays


def _state_of(parts, dtype) -> ParticleState:
    """A state from particle messages (_carried dicts), in order."""
    cat = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    extra = {k[len("extra_"):]: a for k, a in cat.items() if k.startswith("extra_")}
    return ParticleState.create(cat["id"], cat["x"], cat["v"], cat["m"], dtype, extra=extra)


def encode_commands(commands: list) -> np.ndarray:
    """Control commands (plain JSON-able dicts, nodes/control.py) as bytes for a halo message."""
    return np.frombuffer(json.dumps(commands).encode(), dtype=np.uint8)


def decode_commands(array: np.ndarray) -> list:
    return json.loads(bytes(array).decode())


class PeerHalo:
    """Halo of peer ``rank`` in decomposition ``dec`` over ``transport``."""

    def __init__(self, dec, rank: int, transport, balance_every: int = 0, balance_by: str = "particles"):
        self.rank = rank
        self.transport = transport
        self.balance_every = balance_every
        self.balance_by = balance_by
        self._compute_s = 0.0    # the stage timers' total at the last rebalance
        self._set_decomposition(dec)
        self.bytes_sent = {"positions": 0, "fields": 0, "reduce": 0}  # array bytes per phase (no headers)
        self.control_source = None  # rank 0: a callable returning commands to announce (nodes/control.py)
        self.announced = []          # commands announced in this step's reduction, applied after it
        self.rebalances = 0
        self.ghosts_received = 0  # ghost rows received over the run (the halo's minimum traffic)
        self.migrated = 0         # particles this peer handed to another owner over the run
        self.cut_moves = 0        # rebalances that moved a cut
        self._balanced_at = -1
        self._sent_rows = {}     # neighbour -> rows (before the grid sort) sent as its ghosts
        self._ghost_rows = {}    # neighbour -> (first, last) rows (before the sort) of its ghosts

    def _set_decomposition(self, dec):
        self.dec = dec
        self.neighbours = dec.neighbours(self.rank)
        self.others = [q for q in range(dec.n_peers) if q != self.rank]


    def _send(self, dest, tag, arrays, kind):
        self.bytes_sent[kind] = self.bytes_sent.get(kind, 0) + sum(a.nbytes for a in arrays.values())
        self.transport.send(dest, tag, arrays)

    _extra_shapes = {}  # the state's extra arrays (name -> a row-shaped array), set by exchange_positions

    def _check_particles(self, msg, dtype, q, step):
        """Particle arrays of a received message have the fields, lengths and dtypes we expect."""
        n = len(msg.get("id", ()))  # the ids set the length the others must have
        expected = {"id": ((n,), np.int64), "x": ((n, 3), dtype), "v": ((n, 3), dtype), "m": ((n,), dtype)}
        expected.update({"extra_" + k: ((n,) + a.shape[1:], dtype) for k, a in self._extra_shapes.items()})
        for k, (shape, dt) in expected.items():
            a = msg.get(k)
            if a is None or a.shape != shape or a.dtype != dt:
                got = "missing" if a is None else f"{a.dtype}{list(a.shape)}"
                raise RuntimeError(f"peer {self.rank}, step {step}: particle message from peer {q}: {k} is "
                                   f"{got}, expected {np.dtype(dt)}{list(shape)}")

    def _seconds_per_particle(self, sim, n):
        """This peer's compute seconds per owned particle and step since the last rebalance."""
        total = sum(sum(v) for v in sim.timers.samples.values())
        spent = total - self._compute_s if total >= self._compute_s else total  # timers were reset
        self._compute_s = total
        return spent / self.balance_every / max(n, 1) if spent > 0 else 1.0

    def rebalance(self, sim):
        """Move the cuts so that peers hold near-equal particle counts; particles go to their new
        owners directly (any peer, not only neighbours). All peers call this at the same step."""
        step = sim.step_index
        s = sim.state
        n = s.n_owned
        cells = sim.grid.cells_of(s.x[:n])
        ncell = self.dec.ncell
        weight = self._seconds_per_particle(sim, n) if self.balance_by == "time" else 1.0
        hist = {f"h{a}": np.bincount(cells[:, a], minlength=ncell[a]) * weight for a in range(3)}
        for q in self.others:
            self._send(q, (step, "balance"), hist, "balance")
        received = {self.rank: hist}
        for q in self.others:
            received[q] = yield from self.transport.recv(q, (step, "balance"))
        # summed in rank order on every peer, so that every peer gets the same bits and the same cuts
        total = {k: sum(received[q][k] for q in range(self.dec.n_peers)) for k in hist}
        new = type(self.dec).from_histograms(ncell, self.dec.dims, [total[f"h{a}"] for a in range(3)],
                                             self.dec.periodic)
        owner = new.owner(cells)
        own = _carried(s, n)
        for q in self.others:
            self._send(q, (step, "migrate"), {k: v[owner == q] for k, v in own.items()}, "migrate")
        self.migrated += int(np.count_nonzero(owner != self.rank))
        self.cut_moves += int(new.cuts != self.dec.cuts)
        parts = [{k: v[owner == self.rank] for k, v in own.items()}]
        for q in self.others:
            parts.append((yield from self.transport.recv(q, (step, "migrate"))))
            self._check_particles(parts[-1], sim.dtype, q, step)
        new_state = _state_of(parts, sim.dtype)
        new_state.n_owned = new_state.n
        sim.state = new_state
        sim._resize_scratch(new_state.n)
        self._set_decomposition(new)
        self.rebalances += 1

    def exchange_positions(self, sim):
        step = sim.step_index
        if self.balance_every and step > 0 and step % self.balance_every == 0 and self._balanced_at != step:
            self._balanced_at = step
            yield from self.rebalance(sim)
        s = sim.state
        n = s.n_owned
        # 1a: particles that crossed into a neighbour's block go to it (they moved less than a cell)
        own = _carried(s, n)
        self._extra_shapes = {k: a[:0] for k, a in s.extra.items()}
        cells = sim.grid.cells_of(own["x"])
        owner = self.dec.owner(cells)
        keep = owner == self.rank
        n_leaving = n - int(np.count_nonzero(keep))
        self.migrated += n_leaving
        if n_leaving and np.any(~keep & ~np.isin(owner, self.neighbours)):
            raise RuntimeError(f"peer {self.rank}, step {step}: a particle moved beyond the neighbouring peers")
        for q in self.neighbours:
            to_q = owner == q if n_leaving else slice(0, 0)
            self._send(q, (step, "migrants"), {k: v[to_q] for k, v in own.items()}, "migrants")
        parts = [own if not n_leaving else {k: v[keep] for k, v in own.items()}]
        cell_parts = [cells if not n_leaving else cells[keep]]
        for q in self.neighbours:
            parts.append((yield from self.transport.recv(q, (step, "migrants"))))
            self._check_particles(parts[-1], sim.dtype, q, step)
            cell_parts.append(sim.grid.cells_of(parts[-1]["x"]))
        owned = {k: np.concatenate([p[k] for p in parts]) for k in own}
        cells = np.concatenate(cell_parts)
        # 1b: ghosts come from the owned set after migration (a migrant can be another peer's ghost)
        for q in self.neighbours:
            rows = np.nonzero(self.dec.outgoing(cells, self.rank, q))[0]
            self._sent_rows[q] = rows
            self._send(q, (step, "positions"), {k: v[rows] for k, v in owned.items()}, "positions")
        ghosts = []
        first = n_own = len(owned["id"])
        for q in self.neighbours:
            ghosts.append((yield from self.transport.recv(q, (step, "positions"))))
            self._check_particles(ghosts[-1], sim.dtype, q, step)
            count = len(ghosts[-1]["id"])
            self.ghosts_received += count
            self._ghost_rows[q] = (first, first + count)
            first += count
        new = _state_of([owned] + ghosts, sim.dtype)
        new.n_owned = n_own
        sim.state = new
        sim._resize_scratch(new.n)

    def exchange_fields(self, sim):
        s = sim.state
        yield from self.exchange_ghosts(sim, "fields", {"rho": s.rho, "p": s.p})

    def exchange_ghosts(self, sim, phase, arrays, kind=None):
        """Send the rows of ``arrays`` (per-row arrays of the sorted state) that are the neighbours'
        ghosts, in the order of exchange 1; fill our ghost rows with theirs. ``phase`` names the
        message (unique within a step); bytes are counted under ``kind`` (default: the phase)."""
        step = sim.step_index
        s = sim.state
        where = np.empty(s.n, dtype=np.int64)  # row before the grid sort -> row after it
        where[sim.grid.last_permutation] = np.arange(s.n)
        for q in self.neighbours:
            rows = where[self._sent_rows[q]]
            self._send(q, (step, phase), {k: a[rows] for k, a in arrays.items()}, kind or phase)
        for q in self.neighbours:
            msg = yield from self.transport.recv(q, (step, phase))
            lo, hi = self._ghost_rows[q]
            rows = where[lo:hi]
            for k, a in arrays.items():
                if msg[k].shape != (hi - lo,) + a.shape[1:]:
                    raise RuntimeError(f"peer {self.rank}, step {step}: {phase} message from peer {q} has {k} of "
                                       f"shape {msg[k].shape}, expected {(hi - lo,) + a.shape[1:]}")
                a[rows] = msg[k]

    def reduce_sum(self, sim, phase, value: int):
        """Global sum of an integer (exact, so every peer gets the same total in any order); the
        DFSPH solvers' error in 2^-32 units. ``phase`` names the message (unique within a step)."""
        step = sim.step_index
        message = {"sum": np.array([value], dtype=np.int64)}
        for q in self.others:
            self._send(q, (step, phase), message, "reduce")
        total = int(value)
        for q in self.others:
            msg = yield from self.transport.recv(q, (step, phase))
            total += int(msg["sum"][0])
        return total

    def reduce_max(self, sim, stats):
        """Global max of |v|^2, |a|^2, compression and the NaN count; rank 0's message also carries
        any control commands, so every peer learns them in the same step."""
        step = sim.step_index
        mine = np.array(stats, dtype=np.float64)
        commands = self.control_source() if (self.rank == 0 and self.control_source is not None) else []
        message = {"stats": mine}
        if commands:
            message["control"] = encode_commands(commands)
        for q in self.others:
            self._send(q, (step, "reduce"), message, "reduce")
        result = mine.copy()
        self.announced = list(commands)
        for q in self.others:
            msg = yield from self.transport.recv(q, (step, "reduce"))
            result[:3] = np.maximum(result[:3], msg["stats"][:3])
            result[3] += msg["stats"][3]
            if q == 0 and "control" in msg:
                self.announced = decode_commands(msg["control"])
        return result[0], result[1], result[2], int(result[3])
