"""What both backends share: running a declared stage (``sphcore/stages.py``) on named arrays.

``Engine.run(stage, **values)`` binds every argument the stage's row function names: first from
``values`` (scalars the step passes: ``prm``, ``dt``...; choices made per call: ``divergence``), then
from ``arrays`` renames (``arrays={"v": "v_star"}``: the density solve runs on v*), then from the
backend's arrays by name (``array``): the particle state, its carried arrays, the scratch, the grid,
the walls. Compile-time choices not given come from the simulation's ``choices``. A backend provides
``array(name)``, ``allocate(shape, initial)``, ``all_rows`` (an empty int64 array: "every owned row")
and ``launch(stage, choices, n, rows, arguments, wait)``.
"""
from __future__ import annotations

from sphcore import stages as stage_specs


class Scratch:
    """The per-row work arrays of ``stages.SCRATCH`` for the state's n rows (owned + ghosts), owned
    by the backend; an array a model does not need has one row. Reallocated (to its initial value)
    only when n changes."""

    def __init__(self, needs: dict, allocate):
        self.needs = needs          # Simulation flag -> bool (stages.Scratch.needed)
        self.allocate = allocate    # (shape, initial) -> array on the backend's device
        self.n = -1
        self.arrays = {}

    def resize(self, n: int, keep: int = 0):
        """n rows; the first ``keep`` rows keep their values (the owned rows when the ghosts are
        appended after their density was computed), the others start at their initial value."""
        if n == self.n:
            return
        for s in stage_specs.SCRATCH:
            rows = max(n, 1) if (not s.needed or self.needs[s.needed]) else 1
            old = self.arrays.get(s.name)
            self.arrays[s.name] = self.allocate((rows,) if s.components == 1 else (rows, s.components), s.initial)
            kept = min(keep, rows, old.shape[0]) if old is not None and rows > 1 else 0
            if kept:
                self.arrays[s.name][:kept] = old[:kept]
        self.n = n

    def __getattr__(self, name):
        arrays = self.__dict__.get("arrays", {})
        if name in arrays:
            return arrays[name]
        raise AttributeError(name)


class Engine:
    """The stage runner over a Simulation's model (choices, walls) and the backend's arrays."""

    def __init__(self, sim):
        self.sim = sim
        self.model = model = sim.model
        self.scratch = Scratch({s.needed: bool(getattr(model, s.needed)) for s in stage_specs.SCRATCH if s.needed},
                               self.allocate)

    def run(self, stage, arrays=None, rows=None, wait=True, **values):
        """Run ``stage`` over the owned rows, or over ``rows`` (a backend int64 array of owned rows, from
        ``split_rows``); returns its reduced values (a number, a tuple, or None). ``wait=False``: a
        device may return before the stage has run (a stage without reductions), so that the host can
        wait for messages meanwhile."""
        choices = self.model.choices
        picked = tuple(int(values.pop(c)) if c in values else choices[c] for c in stage.choices)
        self.begin()
        arguments = []
        for name in stage.arguments:  # values a stage does not take (a term's coefficient) are not passed
            if name in values:
                arguments.append(values[name])
            else:
                arguments.append(self.array(arrays.get(name, name) if arrays else name))
        if rows is None:
            return self.launch(stage, picked, self.n_owned(), self.all_rows, arguments, wait)
        return self.launch(stage, picked, rows.shape[0], rows, arguments, wait)

    def begin(self):
        """Before a stage: the backend's arrays are current and the scratch fits the state."""
        raise NotImplementedError

    # -- rows for the halo (sphcore/halo.py): only the rows a neighbour needs leave the backend --------
    def carried_names(self) -> tuple:
        """The keys of the carried arrays (state.carried_layout): id, x, v, m, "extra_<name>"..."""
        raise NotImplementedError

    def ghost_rows(self):
        """A backend int64 array of the ghost rows (after the owned ones): a stage run on them."""
        raise NotImplementedError

    def split_rows(self, dec, rank: int, neighbours) -> tuple:
        """(interior, boundary): backend int64 arrays of this step's owned rows (as sorted now) whose
        cells lie in no neighbour's incoming zone (no ghost is within their reach: decomposition.py),
        and of the others; computed once per grid sort."""
        raise NotImplementedError

    def rows_of(self, names, rows, renumber: bool = True) -> dict:
        """{name: a host copy of rows ``rows`` of the per-row array ``name``} (state fields, carried
        arrays as "extra_<name>", scratch). ``renumber``: ``rows`` number the rows as they were before
        this step's grid sort (the order of exchange 1: exchange 2 and later); else as they are now."""
        raise NotImplementedError

    def set_rows(self, values: dict, rows):
        """Write ``values[name]`` into rows ``rows`` (numbered before this step's grid sort) of each
        array."""
        raise NotImplementedError

    def zone_rows(self, dec, rank: int, neighbours) -> tuple:
        """Exchange 1's question to every owned row, answered where the rows live: (rows, owner, mask),
        host int64 arrays, of the owned rows that leave this peer's block (owner != rank) or lie in a
        neighbour's incoming zone (bit b of mask: neighbours[b]; decomposition.zone_code), ascending."""
        raise NotImplementedError

    def rebuild(self, leaving, owned_in: dict, ghosts_in: dict):
        """The particles after exchange 1: the owned rows but ``leaving`` (ascending), in their order,
        then the rows of ``owned_in`` (migrants; carried arrays by key), all owned, then the rows of
        ``ghosts_in`` as ghosts. Derived fields start at zero."""
        raise NotImplementedError

    # Exchange 1 overlapped (a CPU peer): the owned rows are sorted and the interior rows' lists and
    # density computed while the ghosts travel; then the ghosts are appended, sorted after the owned
    # rows (which keep their order), and the boundary rows listed. A backend without it sorts once,
    # after the ghosts arrived (``bin``).
    sorts_ghosts_apart = False

    # Reused lists (run.neighbour_skin, grid.py): the host backend only; scene.py refuses a skin elsewhere.
    def lists_done(self):
        """The step's neighbour lists are complete (a skin counts a build or a reuse)."""

    def displacement2(self) -> float:
        """m^2: the largest squared distance of an owned row from its reference position."""
        raise NotImplementedError

    def set_reference(self):
        """The owned rows' reference positions become their positions (a build)."""
        raise NotImplementedError

    def append_ghosts(self, ghosts_in: dict):
        """The ghost rows of ``ghosts_in`` (carried arrays by key) after the owned rows, which keep their
        carried and derived values and their scratch (their density may have been computed already)."""
        raise NotImplementedError

    def sort(self):
        """x -> (cell, id) order of every row now held (owned rows first, ghosts after them)."""
        raise NotImplementedError

    def sort_ghosts(self):
        """After ``sort`` of the owned rows and ``append_ghosts``: the ghost rows in (cell, id) order
        after the owned rows, which stay where they are; rows exchanged later (``rows_of``,
        ``set_rows``) are still numbered as in exchange 1."""
        raise NotImplementedError

    def neighbours(self, rows=None, filter_only=False):
        """The neighbour lists of the owned rows, or of ``rows`` only (from ``split_rows``), in the
        order of the last sort; nothing when the passes walk the cells. ``filter_only``: with a skin,
        filter the candidates of the last build, whatever this step decides (a peer's interior rows
        while the decision travels: Simulation._reuse_lists)."""
        raise NotImplementedError

    def row_layout(self, name) -> tuple:
        """(the shape of one row, dtype) of per-row array ``name``: what a halo message of it holds."""
        a = self.array(name)
        return a.shape[1:], a.dtype

    def transfer(self) -> dict | None:
        """Bytes copied between host and device so far ({"to_device_bytes", "to_host_bytes"}), or None
        where the particles live on the host."""
        return None

    def walls_moved(self):
        """The model's moving walls were moved (boundaries.Walls.at): where the backend keeps its own
        copy of the wall rows, update it. The host backend reads the model's arrays: nothing to do."""
