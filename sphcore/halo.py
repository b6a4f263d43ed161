"""Halo exchanges of a step: what a peer sends and receives, independent of how bytes travel.

``Simulation.stages`` calls these hooks; each but ``send_ghosts`` and ``split_rows`` is a generator
that yields while it waits for messages (a single process never waits):

    exchange_positions   1a migrants change owner; 1b ghosts' id, x, v, m go out and arrive (exchange
                         1), or, where the backend sorts the ghosts apart (a CPU peer with
                         overlap), stay pending ("positions") while the owned rows are worked on
    send_ghosts          the ghosts' rows of per-particle values go out, in the order of exchange 1:
                         rho, p (exchange 2), vorticity omega, a DFSPH solve's lambda and v
    receive_ghosts       ... and the neighbours' arrive into our ghost rows ("positions": appended)
    pending              whether a phase was sent and is not received yet
    split_rows           while a phase is on its way: (interior, boundary) owned rows, the interior
                         ones out of reach of every ghost (computed meanwhile: solver._overlapped)
    reduce_max           the global max of the step statistics (adaptive dt, health check)
    reduce_values        every peer's value of one number: with a skin, whether every peer's lists hold
    exchange_moved       exchange 1 of a step that reuses its lists (every peer agreed): the same
                         ghost rows' x, v, m, in the order of the last build, pending ("moved") like
                         exchange 2; no migrants (a particle keeps its owner until the next build)
    send_moved           ... sent with the decision by a peer whose own rows allow a reuse
    forget_moved         ... received, checked and left unused when the step builds after all

Load balancing (``balance_every`` > 0): at the start of exchange 1 of every K-th step the peers sum
their per-axis particle histograms, all compute the same balanced cuts
(``Decomposition.from_histograms``) and send each particle straight to its new owner. Results stay
bitwise identical because every sum runs in (cell, id) order whatever the cuts.

``NULL_HALO`` is the single-process halo. ``PeerHalo`` implements the zone model of
``sphcore.decomposition`` over any ``Transport`` (nodes/transport.py, nodes/zenoh_transport.py).
Exchange 1 has two rounds: migrants first, so that the ghosts each peer sends are drawn from its
owned set *after* migration (a particle that just crossed a cut can be a third peer's ghost; only
its new owner knows to send it).

Nothing received is used before it is checked against what this peer expects from that source at
that step and phase: the array names, the run's dtype, the counts the protocol fixes (the rows of
exchange 2 and later exchanges are the ghosts of exchange 1 from that peer; a reduction has
exactly its arrays; only rank 0 announces commands), finite values, positive masses, ids of this
scene, and positions where the protocol puts them (a migrant in this peer's block, a ghost in its
incoming zone next to the sender's block; with a skin, by the reference positions, and a ghost of
"moved" within the skin's reach of its reference position). A message that fails raises ``Reject`` in the check;
the transport drops and counts it and waits for the next one from that source.
"""
from __future__ import annotations

import json
from typing import Protocol

import numpy as np

from sphcore.state import EXTRA_PREFIX, ParticleState, carried_layout


class Reject(ValueError):
    """A received message that is not what this peer expects from that source at that step and
    phase: the transport drops it, counts it under ``reason`` (a short name: arrays, dtype, shape,
    count, not finite, mass, ids, owner, stats, control) and keeps waiting for a valid one."""

    def __init__(self, reason: str, detail: str):
        super().__init__(f"{reason}: {detail}")
        self.reason, self.detail = reason, detail


class Transport(Protocol):
    """What a peer's halo needs from the network (one endpoint per peer)."""

    def send(self, dest: int, tag: tuple, arrays: dict) -> None:
        """Send ``arrays`` (name -> numpy array) to peer ``dest`` under ``tag`` = (step, phase)."""

    def recv(self, source: int, tag: tuple, check=None):
        """Generator that returns the first message ``tag`` from ``source`` for which
        ``check(arrays)`` does not raise ``Reject`` (rejected ones are dropped and counted); it
        yields while it waits (in-process) or blocks (between processes)."""

    @property
    def drops(self) -> dict:
        """Messages dropped so far, never used: {source: {reason: count}}."""


def expect_arrays(msg: dict, expected: dict, what: str):
    """``msg`` has exactly the arrays of ``expected`` (name -> (shape, dtype)), of those shapes and
    dtypes, and floats that are finite; else Reject naming the first difference."""
    if set(msg) != set(expected):
        raise Reject("arrays", f"{what}: arrays {sorted(msg)[:8]}, expected {sorted(expected)}")
    for name, (shape, dtype) in expected.items():
        a = msg[name]
        if a.dtype != dtype:
            raise Reject("dtype", f"{what}: {name} is {a.dtype}, expected {np.dtype(dtype)}")
        if a.shape != tuple(shape):
            reason = "count" if a.shape[1:] == tuple(shape)[1:] else "shape"
            raise Reject(reason, f"{what}: {name} has shape {list(a.shape)}, expected {list(shape)}")
        if a.dtype.kind == "f" and not np.isfinite(a).all():
            raise Reject("not finite", f"{what}: {name} holds NaN or Inf")


def has_repeats(ids: np.ndarray) -> bool:
    """Whether a 1-D id array holds a value twice. By sorting: numpy 2.4's hash-based np.unique took
    0.94 ms for a peer's 3,072 ghost ids, a sort and a compare 0.06 ms (2026-12-05), and every ghost
    and migrant message is checked every step."""
    s = np.sort(ids)
    return bool((s[1:] == s[:-1]).any())


# Ghost arrays of exchange 2 and later whose values a row's physics bounds: name -> (low, high, why).
# A value outside is dropped as "range" (a negative f would make the artificial viscosity put energy in).
GHOST_RANGES = {"balsara": (0.0, 1.0, "Balsara's switch f, physics/balsara.py")}

POSITIONS = "positions"  # exchange 1b's phase: the ghost rows' id, x, v, m (and carried extras)
MOVED = "moved"          # exchange 1 of a step that reuses its lists (run.neighbour_skin): the same ghost
                         # rows' x, v, m (and the carried extras but the reference positions), no migrants


class NullHalo:
    """No other peers: nothing to send, nothing to wait for."""

    def pending(self, phase) -> bool:
        return False

    def exchange_positions(self, sim):
        return
        yield

    def exchange_moved(self, sim):
        return
        yield

    def send_moved(self, sim):
        pass

    def forget_moved(self, sim, senders, same_rows):
        return
        yield

    def rebalance_due(self, sim) -> bool:
        return False

    def reduce_values(self, sim, phase, value: float, meanwhile=None):
        return [(0, value)]  # nothing travels: ``meanwhile`` is not run
        yield

    def early_interior_rows(self, sim):
        return None

    def send_ghosts(self, sim, phase, names, kind=None):
        pass

    def receive_ghosts(self, sim, phase):
        return
        yield

    def split_rows(self, sim, phase):
        return None

    def reduce_max(self, sim, stats):
        return stats
        yield

    def reduce_sum(self, sim, phase, value):
        return value
        yield

    def owns(self, sim, x):
        """Which of the points x (n, 3) lie in this process's block: all."""
        return np.ones(len(x), dtype=bool)

    def reduce_sums(self, sim, phase, values, step=None):
        return np.asarray(values, dtype=np.int64)
        yield


NULL_HALO = NullHalo()


def _state_of(parts, dtype) -> ParticleState:
    """A state from particle messages (``ParticleState.carried_arrays`` dicts), joined in order."""
    return ParticleState.from_carried({k: np.concatenate([p[k] for p in parts]) for k in parts[0]}, dtype)


def encode_commands(commands: list) -> np.ndarray:
    """Control commands (plain JSON-able dicts, nodes/control.py) as bytes for a halo message."""
    return np.frombuffer(json.dumps(commands).encode(), dtype=np.uint8)


def decode_commands(array: np.ndarray) -> list:
    return json.loads(bytes(array).decode())


MAX_CONTROL_BYTES = 64 * 1024  # the commands of one step, as JSON
STATS = 4                      # max |v|^2, max |a|^2, max compression, rows holding NaN/Inf


class PeerHalo:
    """Halo of peer ``rank`` in decomposition ``dec`` over ``transport``."""

    def __init__(self, dec, rank: int, transport, balance_every: int = 0, balance_by: str = "particles",
                 overlap: bool = True):
        self.rank = rank
        self.overlap = overlap   # split_rows answers (decomposition.overlap); else every exchange is awaited first
        self.transport = transport
        self.balance_every = balance_every
        self.balance_by = balance_by
        self._compute_s = 0.0    # the stage timers' total at the last rebalance
        self._set_decomposition(dec)
        self.bytes_sent = {"positions": 0, "fields": 0, "reduce": 0}  # array bytes per phase (no headers)
        self.control_source = None  # rank 0: a callable returning commands to announce (nodes/control.py)
        self.control_check = None   # a callable raising Reject for announced commands that are not commands
        self.announced = []          # commands announced in this step's reduction, applied after it
        self.rebalances = 0
        self.ghosts_received = 0  # ghost rows received over the run (the halo's minimum traffic)
        self.migrated = 0         # particles this peer handed to another owner over the run
        self.moved_unused = 0     # steps whose early exchange 1 (send_moved) this peer sent and dropped
        self.cut_moves = 0        # rebalances that moved a cut
        self._balanced_at = -1
        self._sent_rows = {}     # neighbour -> rows (before the grid sort) sent as its ghosts
        self._ghost_rows = {}    # neighbour -> (first, last) rows (before the sort) of its ghosts
        self._pending = {}       # phase -> names: ghost rows sent and not yet received (send_ghosts);
                                 # "positions" -> (first ghost row, empty carried arrays) (exchange 1b)
        self.overlapped_rows = 0  # rows computed while a phase travelled (split_rows), over the run
        self.after_rows = 0       # rows computed after it arrived
        self.overlapped_by_phase = {}  # phase -> the rows of overlapped_rows computed while it travelled

    def _set_decomposition(self, dec):
        self.dec = dec
        self.neighbours = dec.neighbours(self.rank)
        self.others = [q for q in range(dec.n_peers) if q != self.rank]


    def _send(self, dest, tag, arrays, kind):
        self.bytes_sent[kind] = self.bytes_sent.get(kind, 0) + sum(a.nbytes for a in arrays.values())
        self.transport.send(dest, tag, arrays)

    _extra_shapes = {}  # the state's extra arrays (name -> a row-shaped array), set by exchange_positions

    def _particles_check(self, sim, q, phase, placed, cells_out: dict):
        """Check of a particle message (migrants, ghosts, migrate) from peer ``q``: the fields of a
        particle in the run's dtype, finite, m > 0, distinct ids of this scene, and every particle
        where the protocol puts it: ``placed(cells)`` (their (n, 3) grid cells) all true. The
        accepted message's cells are left in ``cells_out["cells"]`` (the caller needs them)."""
        dtype = sim.dtype

        def check(msg):
            what = f"{phase} from peer {q}"
            ids = msg.get("id")
            if ids is None or ids.ndim != 1:
                raise Reject("arrays", f"{what}: no 1-D id array")
            n = len(ids)
            if n > sim.n_particles:
                raise Reject("count", f"{what}: {n} particles, the scene has {sim.n_particles}")
            expect_arrays(msg, carried_layout(n, dtype, self._extra_shapes), what)
            if not (msg["m"] > 0).all():
                raise Reject("mass", f"{what}: a mass m <= 0")
            if n and (not sim.ids_valid(ids) or has_repeats(ids)):
                raise Reject("ids", f"{what}: ids this run's particles cannot have ({sim.ids_text()}), or repeated")
            # with a skin, the rows are placed by their reference positions (Simulation._reuse_lists)
            cells = sim.grid.cells_of(msg[EXTRA_PREFIX + "x_ref"] if sim.grid.skin else msg["x"])
            if not placed(cells).all():
                raise Reject("owner", f"{what}: particles outside the cells the protocol sends them from")
            cells_out["cells"] = cells

        return check

    def _ghost_rows_check(self, q, phase, layout, lo, hi):
        """Check of exchange 2 and later from peer ``q``: exactly the arrays sent, one row per ghost
        that ``q`` sent in exchange 1, in the run's dtype, finite, within GHOST_RANGES (``layout``:
        name -> (the shape of a row, dtype))."""
        expected = {k: ((hi - lo,) + tuple(shape), dtype) for k, (shape, dtype) in layout.items()}
        bounded = [(k, GHOST_RANGES[k]) for k in layout if k in GHOST_RANGES]

        def check(msg):
            expect_arrays(msg, expected, f"{phase} from peer {q}")
            for name, (low, high, meaning) in bounded:
                a = msg[name]
                if not ((a >= low) & (a <= high)).all():
                    raise Reject("range", f"{phase} from peer {q}: {name} outside [{low:g}, {high:g}] ({meaning})")

        return check

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
        cells = sim.grid.cells_of((s.extra["x_ref"] if sim.grid.skin else s.x)[:n])  # where the rows are placed
        ncell = self.dec.ncell
        weight = self._seconds_per_particle(sim, n) if self.balance_by == "time" else 1.0
        hist = {f"h{a}": np.bincount(cells[:, a], minlength=ncell[a]) * weight for a in range(3)}
        for q in self.others:
            self._send(q, (step, "balance"), hist, "balance")
        received = {self.rank: hist}
        expected = {k: (h.shape, np.float64) for k, h in hist.items()}
        for q in self.others:
            received[q] = yield from self.transport.recv(q, (step, "balance"), self._histogram_check(q, expected))
        # summed in rank order on every peer, so that every peer gets the same bits and the same cuts
        total = {k: sum(received[q][k] for q in range(self.dec.n_peers)) for k in hist}
        new = type(self.dec).from_histograms(ncell, self.dec.dims, [total[f"h{a}"] for a in range(3)],
                                             self.dec.periodic, reach=self.dec.reach)
        owner = new.owner(cells)
        own = s.carried_arrays(n)
        for q in self.others:
            self._send(q, (step, "migrate"), {k: v[owner == q] for k, v in own.items()}, "migrate")
        self.migrated += int(np.count_nonzero(owner != self.rank))
        self.cut_moves += int(new.cuts != self.dec.cuts)
        parts = [{k: v[owner == self.rank] for k, v in own.items()}]
        for q in self.others:
            check = self._particles_check(sim, q, "migrate", lambda cells: new.owner(cells) == self.rank, {})
            parts.append((yield from self.transport.recv(q, (step, "migrate"), check)))
        new_state = _state_of(parts, sim.dtype)
        new_state.n_owned = new_state.n
        sim.state = new_state
        self._set_decomposition(new)
        self.rebalances += 1

    @staticmethod
    def _histogram_check(q, expected):
        def check(msg):
            expect_arrays(msg, expected, f"balance from peer {q}")
            if any((msg[k] < 0).any() for k in expected):
                raise Reject("count", f"balance from peer {q}: a negative histogram count")
        return check

    def exchange_positions(self, sim):
        step = sim.step_index
        if self._pending:
            raise RuntimeError(f"peer {self.rank}, step {step}: ghost rows of {sorted(self._pending)} were sent and "
                               "never received")
        if self.rebalance_due(sim):
            self._balanced_at = step
            yield from self.rebalance(sim)
        engine = sim.engine
        names = engine.carried_names()
        self._extra_shapes = {k[len(EXTRA_PREFIX):]: np.empty((0,) + tuple(shape), dtype)
                              for k in names if k.startswith(EXTRA_PREFIX) for shape, dtype in [engine.row_layout(k)]}
        empty = {k: np.empty(shape, dtype) for k, (shape, dtype) in carried_layout(0, sim.dtype, self._extra_shapes).items()}
        # which owned rows leave, and which are a neighbour's ghosts: asked where the rows live, so that
        # only those rows are read (on a GPU, only they cross PCIe)
        rows, owner, mask = engine.zone_rows(self.dec, self.rank, self.neighbours)
        leaving = owner != self.rank
        n_leaving = int(np.count_nonzero(leaving))
        self.migrated += n_leaving
        if n_leaving and np.any(leaving & ~np.isin(owner, self.neighbours)):
            raise RuntimeError(f"peer {self.rank}, step {step}: a particle moved beyond the neighbouring peers")
        # 1a: particles that crossed into a neighbour's block go to it (they moved less than a cell)
        for q in self.neighbours:
            self._send(q, (step, "migrants"), engine.rows_of(names, rows[owner == q], renumber=False), "migrants")
        arrivals, arrival_cells = [empty], [np.empty((0, 3), dtype=np.int64)]
        mine = self.rank
        for q in self.neighbours:
            got = {}
            check = self._particles_check(sim, q, "migrants", lambda cells: self.dec.owner(cells) == mine, got)
            arrivals.append((yield from self.transport.recv(q, (step, "migrants"), check)))
            arrival_cells.append(got["cells"])
        migrants = {k: np.concatenate([a[k] for a in arrivals]) for k in names}
        cells_in = np.concatenate(arrival_cells)
        # 1b: ghosts come from the owned set after migration (a migrant can be another peer's ghost):
        # the kept rows (renumbered past the leaving ones), then the migrants, in that order
        gone = rows[leaving]
        kept, kept_mask = rows[~leaving], mask[~leaving]
        kept_now = kept - np.searchsorted(gone, kept)
        n_kept = engine.n_owned() - n_leaving
        for b, q in enumerate(self.neighbours):
            own_q = ((kept_mask >> b) & 1).astype(bool)
            in_q = np.nonzero(self.dec.outgoing(cells_in, self.rank, q))[0]
            self._sent_rows[q] = np.concatenate([kept_now[own_q], n_kept + in_q])
            part = engine.rows_of(names, kept[own_q], renumber=False)
            self._send(q, (step, POSITIONS), {k: np.concatenate([part[k], migrants[k][in_q]]) for k in names},
                       POSITIONS)
        first = n_kept + len(migrants["id"])
        if self.overlap and engine.sorts_ghosts_apart:
            # the ghosts travel while the owned rows are sorted and the interior rows' density runs
            # (Simulation._fields); receive_ghosts(sim, "positions") appends them
            engine.rebuild(gone, migrants, empty)
            self._pending[POSITIONS] = (first, empty)
            return
        ghosts = yield from self._receive_positions(sim, first, empty)
        engine.rebuild(gone, migrants, ghosts)

    def rebalance_due(self, sim) -> bool:
        """Whether this step's exchange 1 moves the cuts (every balance_every steps, once a step)."""
        step = sim.step_index
        return bool(self.balance_every and step > 0 and step % self.balance_every == 0 and self._balanced_at != step)

    def exchange_moved(self, sim):
        """Exchange 1 of a step that reuses its lists (every peer agreed, Simulation._reuse_lists): no
        particle changes owner; the neighbours' ghost rows of the last build get their rows' new x, v,
        m and carried extras (not their ids or reference positions, which stay), in the order of that
        build, overlapped like exchange 2 (``receive_ghosts``; a backend that does not sort its ghosts
        apart waits here). Every peer sent it with the decision (``send_moved``): a reuse means every
        peer's rows allowed one."""
        if not (self.overlap and sim.engine.sorts_ghosts_apart):
            yield from self.receive_ghosts(sim, MOVED)

    def send_moved(self, sim):
        """Exchange 1 of a step that will likely reuse its lists, sent before the peers have agreed
        (Simulation._reuse_lists): it travels with the decision instead of after it, a latency less a
        step. ``exchange_moved`` receives it, or ``forget_moved`` drops it if the step builds after all."""
        if self._pending:
            raise RuntimeError(f"peer {self.rank}, step {sim.step_index}: ghost rows of {sorted(self._pending)} were "
                               "sent and never received")
        self.send_ghosts(sim, MOVED, self._moved_names(sim), POSITIONS)

    def forget_moved(self, sim, senders, same_rows):
        """Generator: the step builds its lists after all, so no exchange 1 of ``send_moved`` is used.
        Ours is withdrawn; those of the neighbours in ``senders`` (the peers whose displacements, as
        the decision showed, let them send one) are received and checked as on a reusing step, then
        set aside: every message on the wire is read or counted as dropped. Where this peer's rows
        were replaced since the last build (``same_rows`` false: an inlet, an outlet), its ghost rows'
        reference positions are no longer at hand, and the messages are checked for their shape."""
        if self._pending.pop(MOVED, None) is not None:
            self.moved_unused += 1
        step = sim.step_index
        layout = {k: sim.engine.row_layout(k) for k in self._moved_names(sim)}
        for q in self.neighbours:
            if q in senders:
                lo, hi = self._ghost_rows[q]
                check = self._ghost_rows_check(q, MOVED, layout, lo, hi)
                if same_rows:
                    check = self._moved_check(sim, q, check, lo, hi)
                yield from self.transport.recv(q, (step, MOVED), check)

    @staticmethod
    def _moved_names(sim) -> tuple:
        """The arrays of exchange 1 on a reusing step: the carried ones but the ids and reference
        positions, which stay."""
        kept = (EXTRA_PREFIX + "x_ref", "id")
        return tuple(k for k in sim.engine.carried_names() if k not in kept)

    def _moved_check(self, sim, q, check, lo, hi):
        """``check`` of exchange 1 on a step that reuses its lists, and every ghost within the skin's
        reach of its reference position (as its owner found its own rows) and of positive mass."""
        reference = sim.engine.rows_of((EXTRA_PREFIX + "x_ref",), np.arange(lo, hi))[EXTRA_PREFIX + "x_ref"]

        def moved(msg):
            check(msg)
            d = (msg["x"] - reference).astype(np.float64)
            period = sim.grid.period.astype(np.float64)
            wrap = period > 0
            d[:, wrap] -= period[wrap] * np.round(d[:, wrap] / period[wrap])
            if len(d) and float((d * d).sum(axis=1).max()) >= sim.grid.reuse_limit2 * (1.0 + 1e-6):
                raise Reject("owner", f"{MOVED} from peer {q}: a ghost moved farther from where the lists were "
                                      "built than the skin allows")
            if not (msg["m"] > 0).all():
                raise Reject("mass", f"{MOVED} from peer {q}: a mass m <= 0")

        return moved

    def _receive_positions(self, sim, first, empty):
        """Generator: the neighbours' rows of exchange 1b (their id, x, v, m... for our ghost rows,
        numbered from ``first`` in the order of the neighbours), joined in that order."""
        ghosts = [empty]
        step, mine = sim.step_index, self.rank
        for q in self.neighbours:
            check = self._particles_check(sim, q, POSITIONS,
                                          lambda cells, q=q: self.dec.outgoing(cells, q, mine), {})
            ghosts.append((yield from self.transport.recv(q, (step, POSITIONS), check)))
            count = len(ghosts[-1]["id"])
            self.ghosts_received += count
            self._ghost_rows[q] = (first, first + count)
            first += count
        return {k: np.concatenate([g[k] for g in ghosts]) for k in empty}

    def pending(self, phase) -> bool:
        """Whether the ghost rows of ``phase`` were sent and are not received yet."""
        return phase in self._pending

    def send_ghosts(self, sim, phase, names, kind=None):
        """Send the rows of the per-row arrays ``names`` that are the neighbours' ghosts, in the order of
        exchange 1 (``receive_ghosts`` takes theirs). The backend packs the rows where the arrays live
        (``Engine.rows_of``: on a GPU only these rows cross PCIe). ``phase`` names the message
        (unique within a step); bytes are counted under ``kind`` (default: the phase)."""
        if phase in self._pending:
            raise RuntimeError(f"peer {self.rank}, step {sim.step_index}: phase {phase!r} sent twice")
        step = sim.step_index
        engine = sim.engine
        for q in self.neighbours:
            self._send(q, (step, phase), engine.rows_of(names, self._sent_rows[q]), kind or phase)
        self._pending[phase] = tuple(names)

    def receive_ghosts(self, sim, phase):
        """Fill our ghost rows with the neighbours' rows of ``phase`` (``Engine.set_rows``: on a GPU
        only they cross PCIe); nothing if that phase was received already."""
        if phase not in self._pending:
            return
        names = self._pending.pop(phase)
        if phase == POSITIONS:  # exchange 1b: the ghost rows themselves
            first, empty = names
            sim.engine.append_ghosts((yield from self._receive_positions(sim, first, empty)))
            return
        step = sim.step_index
        engine = sim.engine
        layout = {k: engine.row_layout(k) for k in names}
        for q in self.neighbours:
            lo, hi = self._ghost_rows[q]
            check = self._ghost_rows_check(q, phase, layout, lo, hi)
            if phase == MOVED:
                check = self._moved_check(sim, q, check, lo, hi)
            msg = yield from self.transport.recv(q, (step, phase), check)
            engine.set_rows({k: msg[k] for k in names}, np.arange(lo, hi))
            if phase == MOVED:
                self.ghosts_received += hi - lo  # exchange 1's rows: the halo's minimum traffic counts them

    def split_rows(self, sim, phase):
        """While ``phase`` is on its way: (interior, boundary), the owned rows out of reach of every
        ghost and the others (``Engine.split_rows``); None once it has arrived, or when the peer does
        not overlap (decomposition.overlap = false)."""
        if phase not in self._pending or not self.overlap:
            return None
        interior, boundary = sim.engine.split_rows(self.dec, self.rank, self.neighbours)
        self.overlapped_rows += interior.shape[0]
        self.after_rows += boundary.shape[0]
        self.overlapped_by_phase[phase] = self.overlapped_by_phase.get(phase, 0) + interior.shape[0]
        return interior, boundary

    def owns(self, sim, x):
        """Which of the points x (n, 3) lie in this peer's block (the cells it owns)."""
        return self.dec.owner(sim.grid.cells_of(x)) == self.rank

    def _reduce_one(self, sim, phase, key, value, dtype, meanwhile=None):
        """Generator: ``value`` and every other peer's value of ``phase`` (a one-element ``dtype`` array
        ``key``), this peer's first, then the others' in rank order; ``meanwhile()`` runs once the
        value is sent, while the others' travel."""
        step = sim.step_index
        message = {key: np.array([value], dtype=dtype)}
        for q in self.others:
            self._send(q, (step, phase), message, "reduce")
        if meanwhile is not None:
            meanwhile()
        values = [value]
        expected = {key: ((1,), dtype)}
        for q in self.others:
            msg = yield from self.transport.recv(
                q, (step, phase), lambda m, q=q: expect_arrays(m, expected, f"{phase} from peer {q}"))
            values.append(msg[key][0])
        return values

    def reduce_sum(self, sim, phase, value: int):
        """Global sum of an integer (exact, so every peer gets the same total in any order); the
        DFSPH solvers' error in 2^-32 units. ``phase`` names the message (unique within a step)."""
        values = yield from self._reduce_one(sim, phase, "sum", value, np.int64)
        return sum(int(v) for v in values)

    def reduce_values(self, sim, phase, value: float, meanwhile=None):
        """Every peer's finite float64 ``value`` of ``phase``, as [(rank, value)] (every peer gets the
        same): the displacements that decide whether every peer's lists still hold
        (Simulation._reuse_lists). ``meanwhile()`` runs while the others' values travel (a single
        process, whose halo has nothing to wait for, does not run it)."""
        values = yield from self._reduce_one(sim, phase, "max", value, np.float64, meanwhile)
        return [(r, float(v)) for r, v in zip([self.rank, *self.others], values)]

    def early_interior_rows(self, sim):
        """The interior rows of a step that will likely reuse its lists (``split_rows``' first part,
        the same array), before exchange 1 is sent; None where this peer does not overlap."""
        if not (self.overlap and sim.engine.sorts_ghosts_apart):
            return None
        return sim.engine.split_rows(self.dec, self.rank, self.neighbours)[0]

    def reduce_sums(self, sim, phase, values, step=None):
        """Global sums of an int64 vector (exact and order independent, like ``reduce_sum``): the
        probes' partial sums (sphcore/probes.py). ``step`` tags the message (default: the step the
        simulation is at); ``phase`` must be unique within that step."""
        step = sim.step_index if step is None else step
        mine = np.ascontiguousarray(values, dtype=np.int64)
        for q in self.others:
            self._send(q, (step, phase), {"sums": mine}, "reduce")
        total = mine.copy()
        expected = {"sums": (mine.shape, np.int64)}
        for q in self.others:
            msg = yield from self.transport.recv(
                q, (step, phase), lambda m, q=q: expect_arrays(m, expected, f"{phase} from peer {q}"))
            total += msg["sums"]
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
            got = {}
            msg = yield from self.transport.recv(q, (step, "reduce"), self._reduce_check(sim, q, got))
            result[:3] = np.maximum(result[:3], msg["stats"][:3])
            result[3] += msg["stats"][3]
            if "commands" in got:
                self.announced = got["commands"]
        return result[0], result[1], result[2], int(result[3])

    def _reduce_check(self, sim, q, got: dict):
        """Check of peer ``q``'s reduction message: ``stats`` (non-negative, finite, a whole count of
        bad rows within the scene's particles) and, from rank 0 only, ``control``: commands that
        ``control_check`` accepts (left in ``got["commands"]``)."""

        def check(msg):
            what = f"reduce from peer {q}"
            if "control" in msg and q != 0:
                raise Reject("control", f"{what}: a control array; only rank 0 announces commands")
            control = msg.get("control")
            expected = {"stats": ((STATS,), np.float64)}
            if control is not None:
                expected["control"] = ((control.size,), np.uint8)
            expect_arrays(msg, expected, what)
            stats = msg["stats"]
            if (stats < 0).any() or stats[3] != np.floor(stats[3]) or stats[3] > sim.n_particles:
                raise Reject("stats", f"{what}: statistics {stats.tolist()} are not maxima of squares and a count")
            got.pop("commands", None)
            if control is not None:
                if len(control) > MAX_CONTROL_BYTES:
                    raise Reject("control", f"{what}: {len(control)} bytes of commands, at most {MAX_CONTROL_BYTES}")
                try:
                    commands = decode_commands(control)
                except (ValueError, RecursionError) as e:
                    raise Reject("control", f"{what}: unreadable commands ({e})") from None
                if self.control_check is not None:
                    self.control_check(commands)
                elif not isinstance(commands, list):
                    raise Reject("control", f"{what}: commands are not a list")
                got["commands"] = commands

        return check
