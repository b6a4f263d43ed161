"""Run N peers inside one process, round-robin, with the in-process transport.

No threads: each peer's step is a generator (``Simulation.stages``) that yields while it waits for
a message; the scheduler resumes the peers in turn until all have finished the step. Used by the
tests to check that N peers reproduce a single-process run bit for bit.
"""
from __future__ import annotations

import numpy as np

from nodes.transport import InProcessNetwork
from sphcore.decomposition import Decomposition, choose_dims
from sphcore.halo import PeerHalo
from sphcore.solver import Simulation


class DeadlockError(RuntimeError):
    pass


def _drive(generators, max_rounds: int = 100):
    """Resume the generators in turn until all are exhausted. A step needs a handful of rounds (one
    per exchange); many more means the peers wait for messages nobody sends."""
    live = list(generators)
    for _ in range(max_rounds):
        for gen in list(live):
            try:
                next(gen)
            except StopIteration:
                live.remove(gen)
        if not live:
            return
    raise DeadlockError(f"in-process peers still waiting after {max_rounds} rounds: a message was never sent")


class InProcessCluster:
    """``n_peers`` peers of ``scene``, each owning a block of the global grid."""

    def __init__(self, scene, n_peers: int, precision: str = "f64", layout: str = "auto", dims=None):
        self.network = InProcessNetwork()
        self.peers = []
        self.halos = []
        probe = Simulation(scene, precision)
        grid = probe.grid
        dims = dims or choose_dims(n_peers, grid.ncell, scene.dim, layout)
        periodic = tuple(bool(p > 0) for p in grid.period)
        self.dec = Decomposition.uniform(tuple(int(n) for n in grid.ncell), dims, periodic)
        for rank in range(self.dec.n_peers):
            sim = probe if rank == 0 else Simulation(scene, precision)
            s = sim.state
            cells = np.clip(np.floor((s.x - grid.origin) * grid.inv_cell).astype(np.int64), 0, grid.ncell - 1)
            mine = self.dec.owner(cells) == rank
            for name in ("id", "x", "v", "m", "a", "rho", "p"):
                setattr(s, name, np.ascontiguousarray(getattr(s, name)[mine]))
            s.n_owned = int(mine.sum())
            sim._resize_scratch(s.n)
            self.peers.append(sim)
            self.halos.append(PeerHalo(self.dec, rank, self.network.endpoint(rank)))

    def step(self):
        _drive([sim.stages(halo) for sim, halo in zip(self.peers, self.halos)])

    def final_arrays(self) -> dict:
        _drive([sim.refresh_stages(halo) for sim, halo in zip(self.peers, self.halos)])
        parts = [sim.owned_arrays() for sim in self.peers]
        out = {k: np.concatenate([p[k] for p in parts]) for k in ("id", "x", "v", "rho")}
        order = np.argsort(out["id"], kind="stable")
        return {k: v[order] for k, v in out.items()}
