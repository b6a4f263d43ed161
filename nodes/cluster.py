"""Run N peers inside one process, round-robin, with the in-process transport.

No threads: each peer's step is a generator (``Simulation.stages``) that yields while it waits for
a message; the scheduler resumes the peers in turn until all have finished the step. ``step`` and
``final_arrays`` let the tests check that N peers reproduce a single-process run bit for bit;
``run`` runs every peer through the run driver (``nodes.driver.drive``, the loop of every run) to
the end, outputs included.
"""
from __future__ import annotations

import dataclasses
import time

from nodes.driver import PeerRun, RunPlan, drive
from nodes.peer import decomposition_for, take_block
from nodes.transport import InProcessNetwork
from sphcore.halo import PeerHalo
from sphcore.state import merge_by_id
from sphcore.solver import Simulation, SimulationError


class DeadlockError(RuntimeError):
    pass


def _drive(generators, max_rounds: int = 100, network: InProcessNetwork | None = None):
    """Resume the generators in turn until all are exhausted. A step needs a handful of rounds (one
    per exchange); many more means the peers wait for messages nobody sends. With ``network`` the
    rounds are not counted (a whole run takes many): a round in which no peer sent anything and
    none finished is the deadlock, since a peer yields only for a message that is not there yet.

    A peer that stops (SimulationError: a health stop, which every peer decides alike at the same
    step) leaves the others to reach their own stop, as separate processes would, so that rank 0
    writes what it writes when it stops whichever peer got there first; then the lowest rank's stop
    is raised (rank 0's, which names its own particles, as its summary.json does), also where the
    others wait for a stopped peer instead."""
    live = list(generators)
    rank = {id(gen): r for r, gen in enumerate(live)}
    rounds = 0
    stops = {}
    while live:
        sends = network.sends if network is not None else None
        finished = False
        for gen in list(live):
            try:
                next(gen)
            except StopIteration:
                live.remove(gen)
                finished = True
            except SimulationError as e:
                live.remove(gen)
                finished = True
                stops[rank[id(gen)]] = e
        rounds += 1
        if not live:
            break
        deadlock = None
        if network is None and rounds >= max_rounds:
            deadlock = f"in-process peers still waiting after {max_rounds} rounds: a message was never sent"
        if network is not None and network.sends == sends and not finished:
            deadlock = "in-process peers all wait for messages nobody sends"
        if deadlock:
            if stops:
                raise stops[min(stops)]
            raise DeadlockError(deadlock)
    if stops:
        raise stops[min(stops)]


class InProcessCluster:
    """``n_peers`` peers of ``scene``, each owning a block of the global grid (``dims`` overrides the
    scene's decomposition.dims)."""

    def __init__(self, scene, n_peers: int, precision: str = "f64", dims=None, backend: str = "cpu"):
        if dims is not None:
            scene = dataclasses.replace(scene, decomposition=dataclasses.replace(scene.decomposition,
                                                                                 dims=tuple(dims)))
        t_start = time.perf_counter()
        self.scene = scene
        self.network = InProcessNetwork()
        self.peers = []
        self.halos = []
        self.endpoints = []
        probe = Simulation(scene, precision, backend)
        self.dec = decomposition_for(scene, probe.grid, n_peers, probe.state.x)
        for rank in range(self.dec.n_peers):
            sim = probe if rank == 0 else Simulation(scene, precision, backend)
            take_block(sim, self.dec, rank)
            self.peers.append(sim)
            self.endpoints.append(self.network.endpoint(rank))
            self.halos.append(PeerHalo(self.dec, rank, self.endpoints[rank],
                                       scene.decomposition.balance_every, scene.decomposition.balance_by,
                                       scene.decomposition.overlap))
        self.t_start, self.t_setup = t_start, time.perf_counter() - t_start

    def step(self):
        _drive([sim.stages(halo) for sim, halo in zip(self.peers, self.halos)])

    def final_arrays(self) -> dict:
        _drive([sim.refresh_stages(halo) for sim, halo in zip(self.peers, self.halos)])
        parts = [sim.owned_arrays() for sim in self.peers]
        return merge_by_id(parts, ("id", "x", "v", "rho"))

    def run(self, plan: RunPlan) -> dict:
        """Every peer through the run driver to the end of ``plan``, as peer processes would run
        (checkpoints, gather, outputs); rank 0's summary. Rank 0 alone writes ``plan.out``."""
        root = plan.checkpoint_root if plan.checkpoint_root is not None else (
            plan.out / "checkpoints" if plan.out is not None else None)
        summaries = {}

        def peer(rank, sim, halo, endpoint):
            own = plan if rank == 0 else dataclasses.replace(plan, out=None, restarts=None)
            run = PeerRun(sim, self.scene, halo, endpoint, rank, self.dec.n_peers, self.dec, self.t_start,
                          self.t_setup)
            summaries[rank] = yield from drive(run, dataclasses.replace(own, checkpoint_root=root))

        _drive([peer(r, *p) for r, p in enumerate(zip(self.peers, self.halos, self.endpoints))],
               network=self.network)
        return summaries[0]
