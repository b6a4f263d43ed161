"""Run N peers inside one process, round-robin, with the in-process transport.

No threads: each peer's step is a generator (``Simulation.stages``) that yields while it waits for
a message; the scheduler resumes the peers in turn until all have finished the step. Used by the
tests to check that N peers reproduce a single-process run bit for bit.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from nodes.peer import decomposition_for, take_block
from nodes.transport import InProcessNetwork
from sphcore.halo import PeerHalo
from sphcore.state import merge_by_id
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
    """``n_peers`` peers of ``scene``, each owning a block of the global grid (``dims`` overrides the
    scene's decomposition.dims)."""

    def __init__(self, scene, n_peers: int, precision: str = "f64", dims=None, backend: str = "cpu"):
        if dims is not None:
            scene = dataclasses.replace(scene, decomposition=dataclasses.replace(scene.decomposition,
                                                                                 dims=tuple(dims)))
        self.network = InProcessNetwork()
        self.peers = []
        self.halos = []
        probe = Simulation(scene, precision, backend)
        self.dec = decomposition_for(scene, probe.grid, n_peers, probe.state.x)
        for rank in range(self.dec.n_peers):
            sim = probe if rank == 0 else Simulation(scene, precision, backend)
            take_block(sim, self.dec, rank)
            self.peers.append(sim)
            self.halos.append(PeerHalo(self.dec, rank, self.network.endpoint(rank),
                                       scene.decomposition.balance_every, scene.decomposition.balance_by))

    def step(self):
        _drive([sim.stages(halo) for sim, halo in zip(self.peers, self.halos)])

    def final_arrays(self) -> dict:
        _drive([sim.refresh_stages(halo) for sim, halo in zip(self.peers, self.halos)])
        parts = [sim.owned_arrays() for sim in self.peers]
        return merge_by_id(parts, ("id", "x", "v", "rho"))
