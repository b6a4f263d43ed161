"""The simulation: a model's particles advanced in time, and the one place that orders a step.

``Simulation(scene, precision, backend)`` builds the ``Model`` (model.py: resolution, choices, walls,
grid geometry, Params), the particles (``ParticleState``), the solver plug-in (solvers.py) and the
backend (``backends/cpu.py`` CpuStages or ``backends/cuda.py`` CudaStages, which owns the scratch).
``step()`` runs one time step as a flat list of timed stages, each declared in stages.py (what it
reads and writes); optional terms appear in the list only when the scene enables them.
"""
from __future__ import annotations

import math

import numpy as np

from sphcore import stages as st
from sphcore.backends import cpu
from sphcore.choices import Integrator
from sphcore.halo import MOVED, NULL_HALO, POSITIONS
from sphcore.health import Health
from sphcore.initial import check_full, generate_particles
from sphcore.model import Model
from sphcore.motion import FloatingBody
from sphcore.open_boundary import OpenBoundaries
from sphcore.physics import traction
from sphcore.probes import Probes
from sphcore.scene import Scene, pressure_scale
from sphcore.solvers import SOLVERS
from sphcore.state import EXTRA_ROW_SHAPE, ParticleState
from sphcore.timers import StageTimers
from sphcore.timestep import LIMITS, choose_dt

CFL_LIMIT = 1.0  # a fixed time.dt beyond the CFL-1 acoustic/force/viscous limit stops the run


# What a live change (``Simulation.change_scene``) may replace in the Model; every other attribute
# must come out equal, or the change is refused (MODEL_PARTS names them for the refusal).
LIVE_MODEL = ("scene", "prm", "nu", "mass", "force_terms")
MODEL_PARTS = {
    "choices": "a compile-time choice", "kernel": "the kernel", "eos": "the EOS", "viscosity": "the viscosity model",
    "integrator": "the integrator", "use_xsph": "the XSPH stage", "use_shifting": "the shifting stage",
    "use_drift": "the drift", "use_vorticity": "the vorticity stages",
    "use_balsara": "Balsara's switch", "use_diffusion": "the delta-SPH stage",
    "use_damping": "the damping stage", "continuity": "the density scheme", "dfsph": "the solver",
    "extra_names": "the carried arrays",
    "force_terms": "the force-term stages", "walls": "the walls", "host_grid": "the grid", "grid_lo": "the grid",
    "lo": "the grid", "periodic": "the periodic axes", "dx": "the spacing", "H": "the support radius",
    "h": "the support radius", "gradient_moment": "the kernel gradient", "precision": "the precision",
    "dtype": "the precision",
}


def _same(a, b) -> bool:
    """Equal values: numbers, enums, tuples and dicts by ==, arrays by their bits, objects (the walls,
    the grid's geometry) attribute by attribute; a grid's per-step arrays (counts, order) are not its
    geometry and are skipped, nor is where moving walls are now (the attributes in an object's STATE)."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.dtype == b.dtype
                and a.shape == b.shape and np.array_equal(a, b))
    if hasattr(a, "__dict__") and not isinstance(a, type) and type(a) is type(b):
        geometry = GRID_GEOMETRY if hasattr(a, "cells_of") else None
        names = geometry or sorted(set(vars(a)) - set(getattr(a, "STATE", ())))  # the walls' motion: not their definition
        return all(_same(getattr(a, n, None), getattr(b, n, None)) for n in names)
    if isinstance(a, (tuple, list)) and isinstance(b, (tuple, list)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    try:
        return bool(a == b)
    except (TypeError, ValueError):
        return False


GRID_GEOMETRY = ("origin", "ncell", "cell", "period", "periodic")
# What switching an optional stage on or off changes in the Model (a term from or to 0, sph.delta
# from or to 0): a restart in place from the current state (``Simulation.change_scene``).
RESTARTABLE = ("choices", "use_xsph", "use_shifting", "use_drift", "use_vorticity", "use_diffusion", "force_terms")


class SimulationError(RuntimeError):
    """The run became unphysical; the message names the step, the cause and the particles."""


BACKENDS = ("cpu", "cuda")


class Simulation:
    """A run in progress. Its own state: the particles (``state``), time (t, step_index, dt, dt_prev,
    dt_flow), the health and limit counters (leaks, max_neighbours, max_compression, limit_counts,
    last_limit), ``timers``, the solver plug-in and the backend ``engine`` with its ``grid``. What the
    scene fixes (H, kernel, walls, prm, flags...) is the ``model``'s, read through the simulation
    (``sim.H`` is ``sim.model.H``)."""

    def __init__(self, scene: Scene, precision: str | None = None, backend: str = "cpu", device: int | None = None):
        """``backend`` "cpu" or "cuda"; ``device``: the GPU index for cuda (modulo the GPUs visible)."""
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
        self.backend = backend
        self.device_name = "cpu"
        if backend == "cuda":  # fail before any set-up work when there is no GPU
            from sphcore.backends import cuda as cuda_backend
            self.device_name = cuda_backend.require(device)
        self.model = model = Model(scene, precision, backend)
        ids, x, v = generate_particles(scene, model.walls)
        self.open = OpenBoundaries(scene, model.walls)  # inlets and outlets (open_boundary.py)
        if self.open.active:
            ids, x, v = self.open.initial(ids, x, v)
        self._state = ParticleState.create(ids, x, v, np.full(len(ids), model.mass), model.dtype)
        self.n_particles = len(ids)  # all peers' particles now (inlets add, outlets remove: open_boundary.py)
        self.n_ids = self.open.n_initial if self.open.active else len(ids)  # the blocks' ids: 0 .. n_ids - 1
        if scene.forces.hydrostatic == "removed":
            check_full(scene, model.walls, self.n_particles)
        self._add_extra(self._state)
        self.grid = model.host_grid
        self._early = None  # (rows, their density's counts or None): lists filtered before the decision
        self.rows_before_decision = 0  # over the run: rows a peer listed (and summed) while the decision travelled
        self.solver = SOLVERS[scene.sph.solver](self)  # the pressure solver's hooks into the step (solvers.py)

        self.t = 0.0
        self.step_index = 0
        self.dt_prev = 0.0  # leapfrog: the previous step, for the combined kick
        self.dt = 0.0
        self.dt_flow = 0.0
        self.leaks = 0
        self.max_neighbours = 0
        self.neighbours_sum = 0  # neighbours of the owned rows at the last density pass: their sum
        self.neighbours_max = 0  # and the most of one row
        self.max_compression = 0.0
        self.limit_counts = {name: 0 for name in LIMITS}
        self.last_limit = ""
        self.prm_now = model.prm
        self.timers = StageTimers()
        if backend == "cuda":
            self.engine = cuda_backend.CudaStages(self)
            self.grid = self.engine.grid  # the device grid: counts, permutation downloaded on demand
        else:
            self.engine = cpu.CpuStages(self)
        self.health = Health(self)  # unconverged solves, the energy watchdog (health.py)
        self.probes = Probes(self)  # the scene's [[probes]] (probes.py)

    @property
    def prm(self):
        """The model's Params (replaced, e.g. by a test, for the following steps)."""
        return self.model.prm

    @prm.setter
    def prm(self, value):
        self.model.prm = value

    def __getattr__(self, name):
        """The model's attributes (H, kernel, walls, prm, use_xsph...) read through the simulation."""
        model = self.__dict__.get("model")
        if model is None:
            raise AttributeError(name)
        return getattr(model, name)

    @property
    def solver_stats(self) -> dict:
        """Iterations of the solver's iterative solves (solvers.DFSPH.stats; {} for WCSPH)."""
        return self.solver.stats

    @property
    def rho_ref(self) -> float:
        """The density the pressure solve drives to (rho0, or a closed flow's mean density)."""
        return self.solver.rho_ref

    @property
    def state(self) -> ParticleState:
        """The particles (host arrays). With the CUDA backend this is a mirror of the device arrays,
        downloaded when read after the device has run a stage."""
        self.engine.pull(self._state)
        return self._state

    @state.setter
    def state(self, new: ParticleState):
        """Replace the particles (halo exchange, checkpoint restore); a device uploads them before
        its next stage. Carried arrays the new state lacks start cold (zeros)."""
        self._add_extra(new)
        self._state = new
        if self.backend == "cuda":
            self.engine.device_stale = True

    def ids_valid(self, ids: np.ndarray) -> bool:
        """Every id is one a particle of this run can have now (a wire or checkpoint check)."""
        if self.open.inlets:
            return self.open.ids_valid(ids, self.t)
        return bool(len(ids) == 0 or (ids.min() >= 0 and ids.max() < self.n_ids))

    def ids_text(self) -> str:
        """The ids ``ids_valid`` accepts, in words."""
        text = f"0..{self.n_ids - 1}"
        for lat in self.open.inlets:
            text += f", {lat.base}..{lat.base + len(lat.nodes) * lat.layers(self.t) - 1}"
        return text

    def _add_extra(self, state: ParticleState):
        for name in self.extra_names:
            if name not in state.extra:
                state.extra[name] = np.zeros((state.x.shape[0],) + EXTRA_ROW_SHAPE.get(name, ()), dtype=self.dtype)

    def set_parameter(self, key: str, value):
        """Change the value of scene key ``key`` (one that may change during a run, scene.LIVE) from
        the next step on; ``value`` as the scene holds it (a tuple for a vector). ValueError if the
        key cannot change during a run or the change would alter more than the Params."""
        from sphcore.scene import SceneError, live_change, _toml_exact
        try:
            _, scene = live_change(self.scene, f"{key}={_toml_exact(value)}")
        except SceneError as e:
            raise ValueError(str(e)) from None
        self.change_scene(scene)

    def _structure_changes(self, new: Model) -> list[str]:
        """The Model attributes, besides LIVE_MODEL's, that differ between this run's and ``new``."""
        old = self.model
        changed = [name for name in sorted(vars(new)) if name not in LIVE_MODEL
                   and not _same(getattr(old, name, None), getattr(new, name))]
        if [term.name for term, _ in old.force_terms] != [term.name for term, _ in new.force_terms]:
            changed.append("force_terms")
        return changed

    def changed_model(self, scene: Scene) -> Model:
        """The Model of ``scene``, a live change of this run's scene: ValueError naming what else the
        change would alter (the compile-time choices of the physics, the grid, the walls), which no
        running run can follow. Switching optional stages on or off (RESTARTABLE) is allowed: the
        change is then a restart in place (``change_scene``)."""
        new = Model(scene, self.precision, self.backend)
        changed = [name for name in self._structure_changes(new) if name not in RESTARTABLE]
        if changed:
            what = sorted({MODEL_PARTS.get(name, name) for name in changed})
            raise ValueError(f"it changes the compiled step or the world ({', '.join(what)}), which a running run "
                             "cannot follow (start a new run)")
        return new

    def change_scene(self, scene: Scene):
        """Run on with ``scene``, which differs from this run's scene only in keys that may change
        during a run (``scene.live_change``): the Params, the viscosity, the mass of new particles (a
        reset's) and the force terms' values are rebuilt from it exactly as a new run of ``scene``
        would build them, so a run changed after step k is bitwise a run resumed from step k's
        checkpoint with the new values. A change that switches optional stages on or off (a term
        from or to 0, sph.delta) restarts the run in place from its current state, as that resumed
        run starts: the new Model whole, its scratch and backend (a stage run for the first time
        compiles then). ValueError (``changed_model``) leaves the run unchanged."""
        new = self.changed_model(scene)
        if self._structure_changes(new):
            state = self.state  # on a GPU: downloaded, and uploaded again by the new backend
            kept = {body.wall: body for body in self.model.walls.bodies}  # floating bodies go on where they are
            new.walls.moves = tuple((q, kept.get(q, m) if isinstance(m, FloatingBody) else m) for q, m in new.walls.moves)
            self.model = new
            old_grid, self.grid = self.grid, new.host_grid
            # with a skin: the lists as the resumed run rebuilds them, from the reference positions
            self.grid.from_reference = True
            self.grid.builds, self.grid.reuses = old_grid.builds, old_grid.reuses
            self._add_extra(state)
            if self.backend == "cuda":
                from sphcore.backends import cuda as cuda_backend
                self.engine = cuda_backend.CudaStages(self)
                self.grid = self.engine.grid
            else:
                self.engine = cpu.CpuStages(self)
        else:
            for name in LIVE_MODEL:
                setattr(self.model, name, getattr(new, name))
        stats = self.solver.stats
        self.solver = SOLVERS[scene.sph.solver](self)  # its reference density is the new scene's
        self.solver.stats = stats

    def reset(self):
        """Back to the initial particles: the scene's blocks (with the current values of the keys
        changed during the run), t = 0 and a cold start (no previous step, carried arrays zero), as
        a new run starts; the step count and the run's statistics go on. A peer then keeps its
        block of them (nodes/peer.py take_block)."""
        ids, x, v = generate_particles(self.scene, self.model.walls)
        self.state = ParticleState.create(ids, x, v, np.full(len(ids), self.model.mass), self.model.dtype)
        self.t = 0.0
        self.dt = self.dt_prev = self.dt_flow = 0.0
        self.prm_now = self.model.prm
        stats = self.solver.stats
        self.solver = SOLVERS[self.scene.sph.solver](self)
        self.solver.stats = stats

    @staticmethod
    def grid_for(scene: Scene, backend: str = "cpu"):
        """The global grid of ``scene`` on ``backend`` without generating particles (to check a
        decomposition)."""
        return Model.grid_for(scene, backend)

    # -- stages --------------------------------------------------------------------------------
    def _ramped_params(self):
        """Params with the body forces scaled by the ramp factor zeta(t) (physics/external.py)."""
        self.prm_now = self.model.ramped_params(self.t)
        return self.prm_now

    def _neighbours(self):
        self.engine.bin()  # x -> (cell, id) order; the lists too, unless the passes walk the cells

    def step(self, dt_cap: float | None = None, halo=NULL_HALO):
        """Advance one time step; ``dt_cap`` shortens the last step of an --until run. ``halo`` must
        block while it waits (NULL_HALO, or a PeerHalo over a Zenoh endpoint)."""
        for _ in self.stages(halo, dt_cap):
            raise RuntimeError("a step yielded: its halo's transport does not block (use a cluster driver)")
        return self.dt

    def _run(self, stage, timer=None, **values):
        """Run a declared stage (stages.py) on the backend, timed as ``timer`` (default: its name; a
        peer that overlaps a stage with a halo exchange times its two parts as two calls)."""
        with self.timers(timer or stage.name):
            return self.engine.run(stage, **values)

    def stages(self, halo, dt_cap: float | None = None):
        """The one place that orders a step, as a generator: it yields only while ``halo`` waits for
        messages from other peers (never for a single process, whose halo is NULL_HALO), so the same
        ordered step runs in one process, in a peer process, or in an in-process cluster. What each
        stage reads and writes is declared in stages.py."""
        f = self.dtype.type
        prm = self._ramped_params()
        self._move_walls(self.t)                                   # moving walls (motion.py) to t
        yield from self._fields(halo, prm, commit=True)            # exchanges 1, 2; neighbours; rho, p
        yield from self.solver.prepare(halo, prm)                  # DFSPH: v -> v (divergence-free)
        yield from self._accelerations(halo, prm)                  # x, v, rho, p     -> a (+ drho)
        body_forces = yield from self._body_forces(halo, prm)      # floating bodies: the fluid's force, torque
        if self.use_xsph:
            self._run(st.XSPH, prm=prm)                            # x, v, rho        -> dv
        if self.use_shifting:
            self._run(st.SHIFTING, prm=prm)                        # x, v, m, rho     -> dv (+=)
        if self.open.active:
            self._run(st.OPEN_BOUNDARY)                            # inlets: v = U, a = 0; outlets: a = 0
        stats = self._run(st.STATISTICS, "timestep", rho0=self.prm.rho0)  # local max |v|, |a|, compression
        stats = yield from halo.reduce_max(self, stats)            # global max |v|, |a|, compression
        dt = self._choose_dt(dt_cap, stats)                        # -> dt (+ health check)
        yield from self.solver.correct(halo, prm, dt)              # DFSPH: a -> a (+ pressure), kappa, p
        with self.timers("integrate"):                             # a                -> v, x; walls, periodic
            e = self.engine
            if self.use_diffusion:
                e.run(st.DENSITY_UPDATE, dt=f(dt))                 # drho             -> carried rho
            e.run(st.INTEGRATE, dt=f(dt), dt_prev=f(self.dt_prev))
            for body, (force, torque) in zip(self.model.walls.bodies, body_forces):  # floating bodies: F, T, b ->
                body.advance(force, self.model.body_acceleration(prm, self.t, body), dt, torque)  # a, u, X (alpha,
                                                                                                  # Omega, R)
                self._check_body(body)
            self._move_walls(self.t + dt)                          # the collision guard: walls at t + dt
            self.leaks += int(e.run(st.BOUNDARIES, prm=prm))
        if self.open.active:                                       # rows past outlets out, inlets' new layers in
            with self.timers("open_boundaries"):
                yield from self.open.after_step(self, halo, self.t, self.t + dt)
        self.dt_prev = dt
        self.dt = dt
        self.t += dt
        self.step_index += 1
        yield from self.probes.after_step(halo)                   # every K steps: the probes (x, m, rho, p)
        yield from self.health.after_step(halo)                   # every K steps: the energy watchdog

    def _body_forces(self, halo, prm):
        """Generator: the fluid's force (N; N/m in 2D) and torque about its centre (N m; N) on each
        floating body, summed exactly over all peers (physics/bodies.py)."""
        out = []
        for k, body in enumerate(self.model.walls.bodies):
            if body.surface:  # sph.body_force = "traction"
                out.append((yield from self._body_traction(halo, k, body)))
                continue
            f = self.dtype.type
            quantum = f(body.quantum((prm.gravity_x + prm.external_x, prm.gravity_y + prm.external_y,
                                      prm.gravity_z + prm.external_z)))  # the kernel's, exactly
            torque_quantum = f(float(quantum) * body.reach)
            units = self._run(st.BODY_REACTION, prm=prm, wall=body.wall, quantum=quantum,
                              torque_quantum=torque_quantum, dt_prev=f(self.dt_prev))
            units = yield from halo.reduce_sums(self, f"body{k}", units)
            units = np.array(units, dtype=np.float64)
            out.append((units[:3] * float(quantum), units[3:] * float(torque_quantum)))
        return out

    def _body_traction(self, halo, k, body):
        """Generator: (F, T) of floating body ``body`` as the surface integral of the fluid's traction
        (physics/traction.py): each peer's owned rows near the body give integer moments at its
        surface points, summed exactly over the peers; every peer then fits and sums the same."""
        with self.timers("body_traction"):
            w = self.model.walls
            centre = w.rest[body.wall, 0:3] + body.x
            rel_points, rel_normals, areas = body.surface
            points = centre + rel_points @ body.R.T
            normals = rel_normals @ body.R.T
            arm = points - centre
            wall_velocity = body.v + np.cross(body.w, arm)  # U + Omega x (s - c)
            s = self.state
            n = s.n_owned
            H = float(self.model.H)
            reach = body.surface_reach + 1.001 * H  # a margin over the positions' rounding (float32 runs)
            d = s.x[:n] - centre.astype(s.x.dtype)
            rows = np.nonzero((d * d).sum(axis=1) < reach * reach)[0].astype(np.int64)
            scales = self._traction_scales()
            moments = np.zeros((points.shape[0], traction.MOMENTS), dtype=np.int64)
            traction.traction_moments(points, wall_velocity, rows, s.x, s.v, s.m, s.rho, s.p, int(self.model.kernel),
                                      H, float(self.prm.s_w), scales[0], scales[1], moments)
        moments = yield from halo.reduce_sums(self, f"body{k}", moments.ravel())
        with self.timers("body_traction"):
            F, T, _ = traction.traction_from_moments(np.asarray(moments, dtype=np.int64).reshape(points.shape[0], -1),
                                                     points, normals, areas, centre, self.scene.dim, H, scales[0],
                                                     scales[1], scales[2])
        return F, T

    def _traction_scales(self):
        """(p_scale, v_scale, mu) of the traction's moments: rho0 c0^2 (or rho0 |g| L), c0, and the
        laminar viscosity's mu (0 with artificial viscosity or none)."""
        sc = self.scene
        L = float(np.linalg.norm(self.model.walls.hi - self.model.walls.lo))  # the domain's diagonal
        laminar = sc.sph.viscosity in ("morris", "muller")
        return (pressure_scale(sc, L), max(sc.sph.sound_speed, 1.0),
                (sc.fluid.rest_density * sc.sph.nu if laminar else 0.0))

    def _check_body(self, body):
        """A floating body whose reference point leaves the domain's box (body-wall contact is not
        modelled: a body heavier than the fluid sinks through the floor) stops the run."""
        w = self.model.walls
        where = w.rest[body.wall, 0:3] + body.x
        d = self.scene.dim
        index = body.wall - w.container_walls - len(self.scene.domain.planes)
        if not (np.all(np.isfinite(body.R)) and np.all(np.isfinite(body.w))):
            self._fail(f"floating body obstacles[{index}] turns at a rate that is not finite (Omega = "
                       f"{np.array2string(body.w, precision=3)} rad/s)", rows="fastest")
        if not (np.all(np.isfinite(where)) and np.all(where[:d] >= w.lo[:d]) and np.all(where[:d] <= w.hi[:d])):
            self._fail(f"floating body obstacles[{index}] left the domain (its centre at "
                       f"{np.array2string(where[:d], precision=4)} m, moving at "
                       f"{np.array2string(body.v[:d], precision=3)} m/s): contact between a body and the walls is "
                       "not modelled (a body denser than the fluid sinks through the floor)", rows="fastest")

    def _move_walls(self, t: float):
        """Moving walls (motion.py) to time t, on the backend too; nothing for static walls."""
        if self.model.walls.at(t):
            self.engine.walls_moved()

    def _reuse_lists(self, halo, density=None):
        """Generator: whether this step filters the lists it holds (run.neighbour_skin; grid.py) instead
        of building them, decided alike on every peer from the global largest displacement of a row
        from its reference position. A build comes when some row moved REUSE_SHARE of the skin, or
        when some peer's rows were replaced (an inlet, an outlet): the rows' reference positions then
        become their positions. A step that may reuse but whose rows moved between peers or were
        loaded (a rebalance, a resume, a restart in place) sorts and lists them anew from the saved
        reference positions: exactly the lists a single, uninterrupted run holds, so neither changes
        the bits. A peer whose own rows allow a reuse sends exchange 1 (``halo.send_moved``) before the
        decision, so that the two travel together, and filters its interior rows' lists while they
        travel (their candidates hold no ghost), and sums their ``density(rows)`` if given (it must
        change nothing a build would not compute again: no carried density); if some peer needs a
        build, the early exchange 1s are received, checked and left unused, and every row is listed
        and summed anew."""
        grid, e = self.grid, self.engine
        self._early = None
        if not grid.skin:
            return False
        restore = grid.from_reference
        grid.from_reference = False
        same_rows = restore or grid.listed(self._state)
        moved2 = e.displacement2() if same_rows else math.inf
        early = None
        may_send = not restore and not halo.rebalance_due(self)    # alike on every peer: then every peer
        if may_send and moved2 < grid.reuse_limit2:                # whose rows allow a reuse sends exchange
            halo.send_moved(self)                                  # 1 with the decision
            early = halo.early_interior_rows(self)

        def filter_early():                                        # the interior rows' lists meanwhile
            with self.timers("grid"):
                e.neighbours(early, filter_only=True)
            self._early = (early, None if density is None else density(early))
            self.rows_before_decision += early.shape[0]

        every = yield from halo.reduce_values(self, "lists", min(moved2, 1e300) if moved2 == moved2 else 1e300,
                                              meanwhile=None if early is None else filter_early)
        grid.reusing = max(v for _, v in every) < grid.reuse_limit2
        if not grid.reusing:                                       # no peer uses an early exchange 1: those
            if may_send:                                           # sent are read (and checked) unused
                yield from halo.forget_moved(self, {r for r, v in every if v < grid.reuse_limit2}, same_rows)
            e.set_reference()                                      # x_ref = x: a fresh build
            return False
        if restore or halo.rebalance_due(self):
            grid.restoring = True                                  # the build's lists from x_ref
            return False
        return True

    def _fields(self, halo, prm, commit):
        """Exchange 1, the neighbour lists, density and pressure (DFSPH: its factors and the
        reference density), exchange 2: everything the accelerations need."""
        def density(rows):                                         # x, m (v) -> rho, p, fill; continuity:
            return self._run(st.DENSITY, prm=prm, dt_prev=self.dtype.type(self.dt_prev), commit=bool(commit),
                             rows=rows)                            # commit the carried rho

        early_density = None if self.model.continuity else density  # (committed twice if the step builds)
        reuse = yield from self._reuse_lists(halo, early_density)  # a skin: the lists still hold on every peer
        if not reuse:
            self._early = None                                     # a build after all: every row listed anew
        if reuse:
            yield from halo.exchange_moved(self)                   # ghosts' x, v, m (exchange 1, no migrants)
        else:
            yield from halo.exchange_positions(self)               # migrants; ghosts' id, x, v, m (exchange 1)

        def listed_density(rows, wait):
            if self._early is not None and rows is self._early[0]:  # a reusing peer's interior rows: listed
                if self._early[1] is not None:                     # (and summed) while the decision travelled
                    return self._early[1]
            else:
                with self.timers("grid"):
                    self.engine.neighbours(rows)                   # x                -> the rows' lists
            return density(rows)

        if halo.pending(POSITIONS):                                # the ghosts travel: a CPU peer sorts
            with self.timers("grid"):                              # and lists its owned rows meanwhile
                self.engine.sort()                                 # x (owned)        -> order
            counts = yield from self._overlapped(halo, POSITIONS, listed_density, after=self._sort_ghosts)
        elif reuse:                                                # the rows stay; the lists are filtered
            counts = yield from self._overlapped(halo, MOVED, listed_density)
        else:
            with self.timers("grid"):
                self._neighbours()                                 # x                -> order, neighbour lists
            counts = [density(None)]
        self.engine.lists_done()
        self.neighbours_sum = sum(int(found) for found, _ in counts)
        self.neighbours_max = max(int(most) for _, most in counts)
        if self.open.outlets:
            self._run(st.OUTLET_PRESSURE, prm=prm)                 # outlets: rho = rho0, p = p_out
        self.max_neighbours = max(self.max_neighbours, self.neighbours_max)
        yield from self.solver.fields(halo, prm)                   # DFSPH: 1/D, g^wall, p = 0; rho_ref
        fields = ("rho", "p")
        if self.use_balsara:
            self._run(st.BALSARA, prm=prm)                         # x, v, m, rho     -> Balsara's f
            fields += ("balsara",)
        halo.send_ghosts(self, "fields", fields)                   # ghosts' rho, p (f) (exchange 2): received
                                                                   # by the accelerations, or DFSPH's solve

    def _accelerations(self, halo, prm):
        """a of the owned rows from every force term the scene enables (pressure, viscosity, body
        forces, walls; surface tension; vorticity confinement; damping zones), and the delta-SPH density rate; a
        peer computes its interior rows while exchange 2 travels."""
        f = self.dtype.type
        enabled = {st.FORCES: {}, **({st.DIFFUSION: {}} if self.use_diffusion else {}),
                   **{term: {"coefficient": f(value), "dt_prev": f(self.dt_prev)} for term, value in self.force_terms}}

        def accelerations(rows, wait):                             # x, v, rho, p -> a; drho; a (+=) of the terms
            for stage in st.ACCELERATIONS:
                if stage in enabled:
                    self._run(stage, prm=prm, rows=rows, wait=wait, **enabled[stage])
        yield from self._overlapped(halo, "fields", accelerations)  # ghosts' rho, p   (exchange 2)
        if self.use_vorticity:
            self._run(st.VORTICITY, prm=prm)                       # x, v, rho        -> omega
            halo.send_ghosts(self, "omega", ("omega",))            # ghosts' omega    (exchange 3)
            yield from self._overlapped(halo, "omega", lambda rows, wait: self._run(  # omega -> a (+=)
                st.CONFINEMENT, prm=prm, rows=rows, wait=wait))
        if self.use_damping:
            self._run(st.DAMPING)                                  # damping zones: a -= k(x) v

    def _sort_ghosts(self):
        with self.timers("grid"):
            self.engine.sort_ghosts()                              # the ghosts after the owned rows

    def _overlapped(self, halo, phase, run, after=None):
        """``run(rows, wait)`` over every owned row once the ghost rows of ``phase`` arrived: on a peer
        whose rows of ``phase`` are on their way, over the interior rows (no ghost within their reach)
        while they travel, then over the others; else in one pass (``rows`` None). The bits are those of one
        pass: a row's sums read only rows its stages do not write (stages.overlap_group), in the same
        order. ``wait=False``: a device may still run the interior rows while the host waits. ``after``
        runs once the phase has arrived (exchange 1: the ghosts' sort). Returns what each call of
        ``run`` returned (a stage's reductions: the caller combines them)."""
        split = halo.split_rows(self, phase) if phase is not None else None
        if split is None:
            if phase is not None:
                yield from halo.receive_ghosts(self, phase)        # nothing if it has arrived
            if after is not None:
                after()
            return [run(None, True)]
        interior, boundary = split
        first = run(interior, False)
        yield from halo.receive_ghosts(self, phase)
        if after is not None:
            after()
        return [first, run(boundary, True)]

    def _choose_dt(self, dt_cap, stats):
        vmax2, amax2, dev, bad = stats
        if bad:
            self._fail("NaN or Inf in position, velocity, acceleration or density")
        self.max_compression = max(self.max_compression, float(dev))
        if 1.0 + dev > self.scene.run.max_density_ratio:
            self._fail(f"density ratio rho/rho0 reached {1.0 + dev:.3g} (run.max_density_ratio = "
                       f"{self.scene.run.max_density_ratio:g}): the time step or the speed of sound is too "
                       "small for this flow", density=True)
        tm = self.scene.time
        c0 = self.solver.sound_speed  # 0 for DFSPH: no sound speed limits its step
        self.solver.check_flow(math.sqrt(vmax2))
        shift_a = self.scene.terms.shifting
        travel = self.solver.travel
        dt, limit = choose_dt(tm.mode, tm.dt, tm.cfl, self.h, c0, math.sqrt(vmax2), math.sqrt(amax2), self.nu,
                              shift_a, travel)
        if tm.mode == "fixed":
            # the explicit scheme's stability limit is CFL ~ 1; a fixed step beyond it diverges
            bound, name = choose_dt("adaptive", math.inf, CFL_LIMIT, self.h, c0, math.sqrt(vmax2),
                                    math.sqrt(amax2), self.nu, shift_a, travel)
            if dt > bound:
                self._fail(f"CFL violation: time.dt = {dt:.3g} s exceeds the {name} stability limit "
                           f"{bound:.3g} s (CFL {CFL_LIMIT:g}); use a smaller time.dt or time.mode = 'adaptive'",
                           rows="fastest")
        self.solver.check_dt(dt, math.sqrt(vmax2))
        self.dt_flow = dt  # the step the flow allows, before an output time shortens it
        if dt_cap is not None and dt_cap < dt:
            dt, limit = dt_cap, "until"
        self.limit_counts[limit] += 1
        self.last_limit = limit
        return dt

    def _fail(self, cause: str, density: bool = False, rows: str = "bad"):
        """Raise SimulationError naming the step, the cause and the particles concerned: the
        over-compressed ones (density), the fastest and most accelerated ten (rows="fastest"), the
        ten farthest from the solve's reference density (rows="densest"), or those holding NaN/Inf."""
        s = self.state
        n = s.n_owned
        if density:
            rows = np.nonzero(s.rho[:n] / self.prm.rho0 > self.scene.run.max_density_ratio)[0]
        elif rows == "fastest":
            score = np.einsum("ij,ij->i", s.v[:n], s.v[:n]) + np.einsum("ij,ij->i", s.a[:n], s.a[:n]) * self.h
            rows = np.argsort(-score, kind="stable")[:10]
        elif rows == "densest":
            rows = np.argsort(-np.abs(s.rho[:n] / self.rho_ref - 1.0), kind="stable")[:10]
        else:
            finite = np.isfinite(s.x[:n]).all(1) & np.isfinite(s.v[:n]).all(1) & np.isfinite(s.a[:n]).all(1)
            rows = np.nonzero(~(finite & np.isfinite(s.rho[:n])))[0]
        ids = ", ".join(str(i) for i in sorted(s.id[rows][:10]))
        more = f" and {len(rows) - 10} more" if len(rows) > 10 else ""
        raise SimulationError(f"step {self.step_index} (t = {self.t:.6g} s): {cause}; particles {ids}{more}")

    # -- outputs ---------------------------------------------------------------------------------
    def refresh(self, halo=NULL_HALO):
        """Recompute neighbours, density and pressure (and a) for the current positions, so that
        outputs are consistent; for leapfrog returns velocities synchronised to the full step."""
        for _ in self.refresh_stages(halo):
            raise RuntimeError("a refresh yielded: its halo's transport does not block")
        return self.synchronised_velocity()

    def refresh_stages(self, halo):
        """refresh() as a generator over a halo (see stages): the step's fields and accelerations at
        the current positions, every force term included (the leapfrog output velocity uses a)."""
        prm = self._ramped_params()
        self._move_walls(self.t)
        yield from self._fields(halo, prm, commit=False)  # continuity: the next step applies the pending update
        yield from self._accelerations(halo, prm)
        if self.open.active:
            self._run(st.OPEN_BOUNDARY)
        yield from self.solver.refresh(halo, prm)  # DFSPH: the pressure the next step would solve for

    def synchronised_velocity(self):
        """Owned rows' velocity at the full step (leapfrog stores half-step velocities)."""
        s = self.state
        if self.integrator == Integrator.LEAPFROG:
            return s.v + 0.5 * self.dt_prev * s.a
        return s.v

    def final_arrays(self) -> dict:
        """id, x, v, rho of all particles sorted by id (the final.npz contract)."""
        v = self.refresh()
        s = self.state
        order = np.argsort(s.id[: s.n_owned], kind="stable")
        return {"id": s.id[order], "x": s.x[order], "v": v[order], "rho": s.rho[order]}

    def owned_arrays(self) -> dict:
        """id, x, v (synchronised), rho of the owned rows, in row order (after a refresh)."""
        s = self.state
        n = s.n_owned
        return {"id": s.id[:n], "x": s.x[:n], "v": self.synchronised_velocity()[:n], "rho": s.rho[:n]}

    def kinetic_energy(self) -> float:
        s = self.state
        n = s.n_owned
        return float(0.5 * np.sum(s.m[:n].astype(np.float64) * np.einsum("ij,ij->i", s.v[:n], s.v[:n])))
