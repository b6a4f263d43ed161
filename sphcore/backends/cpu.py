"""CPU backend: one ``@njit(parallel=True)`` driver per stage, generated from ``sphcore/stages.py``.

Every driver loops over the owned rows i (``prange``) and calls the stage's row function, which
visits i's neighbours j in list order and writes only row i (gather, never scatter: no atomics, no
races, reproducible sums). The drivers' source is generated (``backends/generate.cpu_source``),
one module per stage and combination of choices (kernel, EOS, viscosity model, integrator,
periodicity...), with the choices as its constants, so each scene compiles, and caches, drivers
containing only the branches it uses; a stage's reductions (``Stage.reduce``) are integer sums and
maxima (the same result in any order).
"""
import numpy as np

from sphcore.backends.engine import Engine
from sphcore.backends.generate import cpu_source, load_cpu_module
from sphcore.decomposition import zone_codes, zone_tables
from sphcore.state import CARRIED, DERIVED, EXTRA_PREFIX, FIELDS as STATE_FIELDS, ParticleState

_DRIVERS = {}  # (stage name, choice values) -> the driver


def driver(stage, choices: tuple):
    """The generated driver of ``stage`` for the choice values ``choices`` (a tuple, in
    ``stage.choices`` order, as ``Engine.run`` picks them), imported on first use."""
    key = (stage.name, choices)
    found = _DRIVERS.get(key)
    if found is None:
        module = load_cpu_module(cpu_source(stage, dict(zip(stage.choices, choices))), f"cpu_{stage.name}")
        found = _DRIVERS[key] = getattr(module, stage.name)
    return found


class CpuStages(Engine):
    """The stages of ``Simulation.stages`` on the CPU: the generated drivers over the simulation's
    host state (the only copy, so the host <-> device hooks do nothing)."""

    def __init__(self, sim):
        self.dtype = sim.dtype
        self._where = None
        self._split = None
        self.all_rows = np.empty(0, dtype=np.int64)
        self._grad_w = np.empty((3, 0, 0), dtype=self.dtype)
        super().__init__(sim)

    def allocate(self, shape, initial):
        return np.full(shape, initial, dtype=self.dtype)

    def begin(self):
        self.scratch.resize(self.sim._state.n)

    def n_owned(self):
        return self.sim._state.n_owned

    def ghost_rows(self):
        s = self.sim._state
        return np.arange(s.n_owned, s.n, dtype=np.int64)

    def array(self, name):
        sim = self.sim
        s = sim._state
        if name in STATE_FIELDS:
            return getattr(s, name)
        if name.startswith(EXTRA_PREFIX):
            return s.extra[name[len(EXTRA_PREFIX):]]
        if name == "kappa":
            return s.extra["kappa"]
        if name == "rho_c":  # the carried density; unused (a placeholder row) with summation density
            return s.extra["density"] if self.model.continuity else self.scratch.drho
        if name in self.scratch.arrays:
            return self.scratch.arrays[name]
        if name in ("nbr", "counts", "cells", "cell_begin", "cell_end"):
            return getattr(sim.grid, name)
        if name == "grad_w":
            return self._pair_array(sim.grid.nbr.shape if self.model.pair_gradients else (1, 1))
        if name == "lo":
            return self.model.lo
        return getattr(self.model.walls, name[len("wall_"):])  # wall_kind, wall_data, wall_tables

    def _pair_array(self, shape):
        """The (3, n, capacity) grad W_ij of the list entries (stages.ARGUMENTS "grad_w"), grown with the
        lists and never shrunk; written by the density pass before any pass reads it. When a peer's
        boundary rows grow the lists' capacity after its interior rows stored theirs, the stored
        entries move along, as the lists do (Grid.build_neighbours)."""
        old = self._grad_w
        if old.shape[1] < shape[0] or old.shape[2] != shape[1]:
            self._grad_w = np.empty((3, max(shape[0], old.shape[1]), shape[1]), dtype=self.dtype)
            kept = min(old.shape[2], shape[1]) - 1  # the lists' spare column holds nothing
            if kept > 0:
                self._grad_w[:, :old.shape[1], :kept] = old[:, :, :kept]
        return self._grad_w

    def launch(self, stage, choices, n, rows, arguments, wait):
        return driver(stage, choices)(n, rows, *arguments)

    def split_rows(self, dec, rank: int, neighbours) -> tuple:
        key = (dec, rank, tuple(neighbours))
        if self._split is None or self._split[0] != key:
            s = self.sim._state
            cells = self.sim.grid.cells_of(self._placed(s)[:s.n_owned])
            owner = np.empty(s.n_owned, dtype=np.int64)
            mask = np.empty(s.n_owned, dtype=np.int64)
            zone_codes(cells, *zone_tables(dec, rank, neighbours), owner, mask)
            self._split = (key, np.flatnonzero(mask == 0), np.flatnonzero(mask))
        return self._split[1], self._split[2]

    # -- host <-> device: nothing to move ----------------------------------------------------------
    def pull(self, state):
        pass

    def _sorted_rows(self, rows):
        """Rows numbered before the grid sort -> their rows now (the sort's inverse permutation, formed
        once per sort: a DFSPH solve exchanges rows twice an iteration)."""
        if self._where is None:
            perm = self.sim.grid.last_permutation
            self._where = np.empty(len(perm), dtype=np.int64)
            self._where[perm] = np.arange(len(perm))
        return self._where[np.asarray(rows, dtype=np.int64)]

    def carried_names(self) -> tuple:
        return CARRIED + tuple(EXTRA_PREFIX + k for k in self.sim._state.extra)

    def rows_of(self, names, rows, renumber: bool = True) -> dict:
        self.begin()
        now = self._sorted_rows(rows) if renumber else np.asarray(rows, dtype=np.int64)
        return {name: self.array(name)[now] for name in names}

    def set_rows(self, values: dict, rows):
        now = self._sorted_rows(rows)
        for name, v in values.items():
            self.array(name)[now] = v

    def zone_rows(self, dec, rank: int, neighbours) -> tuple:
        s = self.sim._state
        n = s.n_owned
        cells = self.sim.grid.cells_of(self._placed(s)[:n])
        owner = np.empty(n, dtype=np.int64)
        mask = np.empty(n, dtype=np.int64)
        zone_codes(cells, *zone_tables(dec, rank, neighbours), owner, mask)
        rows = np.nonzero((owner != rank) | (mask != 0))[0]
        return rows, owner[rows], mask[rows]

    def rebuild(self, leaving, owned_in: dict, ghosts_in: dict):
        s = self.sim._state
        n = s.n_owned
        own = s.carried_arrays(n)
        if len(leaving):  # (most steps none leaves: no boolean selection of every owned row, 0.45 ms a peer step)
            keep = np.ones(n, dtype=bool)
            keep[leaving] = False
            own = {k: a[keep] for k, a in own.items()}
        new = ParticleState.from_carried({k: np.concatenate([a, owned_in[k], ghosts_in[k]]) for k, a in own.items()},
                                         self.dtype)
        new.n_owned = n - len(leaving) + len(owned_in["id"])
        self.sim.state = new

    def bin(self):
        """x -> (cell, id) order, and the neighbour lists unless the passes walk the cells."""
        self.sort()
        self.neighbours()

    def _placed(self, s):
        """The positions that place the rows in cells: x, or with a skin the reference positions
        (Simulation._reuse_lists: x itself at a build, the saved ones when a resumed run rebuilds the
        continuous run's lists)."""
        return s.extra["x_ref"] if self.sim.grid.skin else s.x

    sorts_ghosts_apart = True

    def sort(self):
        self._where = None  # the new sort's inverse permutation is formed when a halo first needs it
        self._split = None  # and the interior and boundary rows when a halo first asks for them
        s = self.sim._state
        self.sim.grid.sort(s, self._placed(s))

    def sort_ghosts(self):
        # The owned rows stay where they are, so their lists, density and interior/boundary split
        # stay valid. The step's permutation from the order of exchange 1 is the owned rows' sort
        # followed by the ghosts' sort.
        s = self.sim._state
        grid = self.sim.grid
        owned = grid.last_permutation[:s.n_owned].copy()
        self._where = None
        grid.sort_ghosts(s, self._placed(s))
        grid.last_permutation = np.concatenate([owned, grid.last_permutation[s.n_owned:]])

    def neighbours(self, rows=None, filter_only=False):
        if self.model.neighbours == "walk":
            return
        s, grid = self.sim._state, self.sim.grid
        if not grid.skin:
            grid.build_neighbours(s.x, s.n_owned, rows)
            return
        if not filter_only and (not grid.reusing or grid.restoring):
            grid.build_candidates(s.extra["x_ref"], s.n_owned, rows)
        grid.filter_neighbours(s.x, s.n_owned, rows)

    def lists_done(self):
        self.sim.grid.lists_done(self.sim._state)

    def displacement2(self) -> float:
        return self.sim.grid.displacement2(self.sim._state)

    def set_reference(self):
        s = self.sim._state
        s.extra["x_ref"][:s.n_owned] = s.x[:s.n_owned]

    def append_ghosts(self, ghosts_in: dict):
        s = self.sim._state
        n = s.n_owned
        new = ParticleState.from_carried({k: np.concatenate([a, ghosts_in[k]]) for k, a in s.carried_arrays(n).items()},
                                         self.dtype)
        new.n_owned = n
        for name in DERIVED:
            getattr(new, name)[:n] = getattr(s, name)[:n]
        self.sim.state = new
        self.scratch.resize(new.n, keep=n)
