"""Halo exchanges of a step: what a peer sends and receives, independent of how bytes travel.

``Simulation.stages`` calls three hooks; each is a generator that yields while it waits for
messages (a single process never waits):

    exchange_positions   migrants change owner; ghosts' id, x, v, m arrive     (exchange 1)
    exchange_fields      ghosts' rho, p arrive, in the order of exchange 1     (exchange 2)
    reduce_max           the global max of the step statistics (adaptive dt, health check)

``NULL_HALO`` is the single-process halo. ``PeerHalo`` implements the zone model of
``sphcore.decomposition`` over any transport endpoint with ``send(dest, tag, arrays)`` and a
generator ``recv(source, tag)`` (nodes/transport.py); migration (ownership changes) and refresh (read-only ghost copies) are
separate steps of exchange 1.
"""
from __future__ import annotations

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

    def reduce_max(self, sim, stats):
        return stats
        yield


NULL_HALO = NullHalo()


class PeerHalo:
    """Halo of peer ``rank`` in decomposition ``dec`` over ``transport``."""

    def __init__(self, dec, rank: int, transport):
        self.dec = dec
        self.rank = rank
        self.transport = transport
        self.neighbours = dec.neighbours(rank)
        self.bytes_sent = {"positions": 0, "fields": 0, "reduce": 0}
        self._sent_rows = {}     # neighbour -> rows (before the grid sort) sent as its ghosts
        self._ghost_rows = {}    # neighbour -> (first, last) rows (before the sort) of its ghosts

    def _cells(self, grid, x):
        return np.clip(np.floor((x - grid.origin) * grid.inv_cell).astype(np.int64), 0, grid.ncell - 1)

    def _send(self, dest, tag, arrays, kind):
        self.bytes_sent[kind] += sum(a.nbytes for a in arrays.values())
        self.transport.send(dest, tag, arrays)

    def exchange_positions(self, sim):
        step = sim.step_index
        s = sim.state
        n = s.n_owned
        own = {name: getattr(s, name)[:n] for name in ("id", "x", "v", "m")}
        owner = self.dec.owner(self._cells(sim.grid, own["x"]))
        keep = owner == self.rank
        kept = {k: v[keep] for k, v in own.items()}
        kept_cells = self._cells(sim.grid, kept["x"])
        for q in self.neighbours:
            out = {f"mig_{k}": v[owner == q] for k, v in own.items()}
            rows = np.nonzero(self.dec.outgoing(kept_cells, self.rank, q))[0]
            self._sent_rows[q] = rows
            out.update({f"gh_{k}": v[rows] for k, v in kept.items()})
            self._send(q, (step, "positions"), out, "positions")
        if np.any(~keep & ~np.isin(owner, self.neighbours)):
            raise RuntimeError(f"peer {self.rank}, step {step}: a particle moved beyond the neighbouring peers")
        received = {}
        for q in self.neighbours:
            received[q] = yield from self.transport.recv(q, (step, "positions"))
        owned = {k: np.concatenate([kept[k]] + [received[q][f"mig_{k}"] for q in self.neighbours])
                 for k in kept}
        ghosts = {k: [received[q][f"gh_{k}"] for q in self.neighbours] for k in kept}
        n_own = len(owned["id"])
        first = n_own
        for q in self.neighbours:
            count = len(received[q]["gh_id"])
            self._ghost_rows[q] = (first, first + count)
            first += count
        new = ParticleState.create(np.concatenate([owned["id"]] + ghosts["id"]),
                                   np.concatenate([owned["x"]] + ghosts["x"]),
                                   np.concatenate([owned["v"]] + ghosts["v"]),
                                   np.concatenate([owned["m"]] + ghosts["m"]), sim.dtype)
        new.n_owned = n_own
        sim.state = new
        sim._resize_scratch(new.n)

    def exchange_fields(self, sim):
        step = sim.step_index
        s = sim.state
        where = np.empty(s.n, dtype=np.int64)  # row before the grid sort -> row after it
        where[sim.grid.last_permutation] = np.arange(s.n)
        for q in self.neighbours:
            rows = where[self._sent_rows[q]]
            self._send(q, (step, "fields"), {"rho": s.rho[rows], "p": s.p[rows]}, "fields")
        for q in self.neighbours:
            msg = yield from self.transport.recv(q, (step, "fields"))
            lo, hi = self._ghost_rows[q]
            rows = where[lo:hi]
            s.rho[rows] = msg["rho"]
            s.p[rows] = msg["p"]

    def reduce_max(self, sim, stats):
        step = sim.step_index
        mine = np.array(stats, dtype=np.float64)
        others = [q for q in range(self.dec.n_peers) if q != self.rank]
        for q in others:
            self._send(q, (step, "reduce"), {"stats": mine}, "reduce")
        result = mine.copy()
        for q in others:
            msg = yield from self.transport.recv(q, (step, "reduce"))
            result[:3] = np.maximum(result[:3], msg["stats"][:3])
            result[3] += msg["stats"][3]
        return result[0], result[1], result[2], int(result[3])
