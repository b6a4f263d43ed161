"""CPU backend: one ``@njit(parallel=True)`` driver per stage, generated from ``sphcore/stages.py``.

Every driver loops over the owned rows i (``prange``) and calls the stage's row function, which
visits i's neighbours j in list order and writes only row i (gather, never scatter: no atomics, no
races, reproducible sums). The drivers' source is generated (``backends/generate.cpu_source``):
choices (kernel, EOS, viscosity model, integrator, periodicity...) are compile-time literals
(``numba.literally``), so each scene compiles, and caches, a driver containing only the branches it
uses; a stage's reductions (``Stage.reduce``) are prange reductions (integer sums and maxima: the
same result in any order).
"""
import numpy as np

from sphcore.backends.engine import Engine
from sphcore.backends.generate import cpu_source, load_cpu_module
from sphcore.stages import STAGES
from sphcore.state import FIELDS as STATE_FIELDS

DRIVERS = load_cpu_module(cpu_source(STAGES))  # module of drivers, one per stage, named as the stage


class CpuStages(Engine):
    """The stages of ``Simulation.stages`` on the CPU: the generated drivers over the simulation's
    host state (the only copy, so the host <-> device hooks do nothing)."""

    def __init__(self, sim):
        self.dtype = sim.dtype
        super().__init__(sim)
        self.drivers = {s.name: getattr(DRIVERS, s.name) for s in STAGES}

    def allocate(self, shape, initial):
        return np.full(shape, initial, dtype=self.dtype)

    def begin(self):
        self.scratch.resize(self.sim._state.n)

    def n_owned(self):
        return self.sim._state.n_owned

    def array(self, name):
        sim = self.sim
        s = sim._state
        if name in STATE_FIELDS:
            return getattr(s, name)
        if name == "kappa":
            return s.extra["kappa"]
        if name == "rho_c":  # the carried density; unused (a placeholder row) with summation density
            return s.extra["density"] if self.model.continuity else self.scratch.drho
        if name in self.scratch.arrays:
            return self.scratch.arrays[name]
        if name in ("nbr", "counts", "cells", "cell_begin", "cell_end"):
            return getattr(sim.grid, name)
        if name == "lo":
            return self.model.lo
        return getattr(self.model.walls, name[len("wall_"):])  # wall_kind, wall_data, wall_tables

    def launch(self, stage, choices, n, arguments):
        return self.drivers[stage.name](*choices, n, *arguments)

    # -- host <-> device: nothing to move ----------------------------------------------------------
    def pull(self, state):
        pass

    def to_device(self, names):
        pass

    def fetch(self, name):
        """The array a halo exchange reads and fills (omega, lam, v, v_star): here the array itself."""
        self.begin()
        return self.array(name)

    def store(self, name, host):
        pass

    def bin(self):
        """x -> (cell, id) order, and the neighbour lists unless the passes walk the cells."""
        if self.model.neighbours == "walk":
            self.sim.grid.sort(self.sim._state)
        else:
            self.sim.grid.bin(self.sim._state)
