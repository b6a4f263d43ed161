"""The simulation: set-up from a scene, and the one place that orders a step.

``Simulation(scene, precision, backend)`` builds the particles, walls, grid and parameters;
``step()`` runs one time step as a flat list of timed stages (what each reads and writes is noted
beside it); optional terms appear in the list only when the scene enables them. The backend
(``backends/cpu.py`` CpuStages or ``backends/cuda.py`` CudaStages) does the work of each stage.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from sphcore import grid as grid_mod
from sphcore.backends import cpu
from sphcore.boundaries import (build_walls, lattice_gradient_moment, lattice_jacobi_ratio, lattice_pressure_diagonal,
                                lattice_sum, table_end)
from sphcore.choices import EOSES, INTEGRATORS, KERNELS, VISCOSITIES, Integrator, Viscosity
from sphcore.halo import NULL_HALO
from sphcore.initial import generate_particles
from sphcore.params import make_params
from sphcore.physics.dfsph import ERROR_QUANTUM, MIN_ITERATIONS, reference_density, relaxation, step_length
from sphcore.physics.external import ramp_factor
from sphcore.physics.kernels import kernel_constants, w
from sphcore.scene import Scene
from sphcore.state import ParticleState
from sphcore.timers import StageTimers
from sphcore.timestep import LIMITS, choose_dt

DTYPES = {"f32": np.float32, "f64": np.float64}


def _make_grid(scene, walls, H, dtype):
    """The global grid: the walls' bounding box plus one cell of margin on non-periodic axes."""
    periodic = tuple(bool(p) for p in scene.domain.periodic)
    lo, hi = walls.lo.copy(), walls.hi.copy()
    for d in range(3):
        if not periodic[d] and d < scene.dim:
            lo[d] -= H
            hi[d] += H
    return grid_mod.Grid(lo, hi, H, periodic, dtype)


CFL_LIMIT = 1.0  # a fixed time.dt beyond the CFL-1 acoustic/force/viscous limit stops the run


class SimulationError(RuntimeError):
    """The run became unphysical; the message names the step, the cause and the particles."""


BACKENDS = ("cpu", "cuda")


class Simulation:
    def __init__(self, scene: Scene, precision: str | None = None, backend: str = "cpu", device: int | None = None):
        """``backend`` "cpu" or "cuda"; ``device``: the GPU index for cuda (modulo the GPUs visible)."""
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
        self.backend = backend
        self.device_name = "cpu"
        if backend == "cuda":  # fail before any set-up work when there is no GPU
            from sphcore.backends import cuda as cuda_backend
            self.device_name = cuda_backend.require(device)
        self.scene = scene
        self.precision = precision or scene.run.precision
        if self.precision == "auto":  # float32 is the GPU's native precision; float64 the CPU's default
            self.precision = "f32" if backend == "cuda" else "f64"
        if self.precision not in DTYPES:
            raise ValueError(f"precision must be one of {', '.join(DTYPES)}, got {self.precision!r}")
        dtype = DTYPES[self.precision]
        self.dtype = np.dtype(dtype)
        sph = scene.sph
        dx = scene.particles.spacing
        self.dx = dx
        self.H = sph.support * dx
        self.h = 0.5 * self.H
        self.kernel = KERNELS[sph.kernel]
        self.eos = EOSES[sph.eos]
        self.viscosity = VISCOSITIES[sph.viscosity]
        self.integrator = INTEGRATORS[scene.time.integrator]
        s_w, s_g, s_l = kernel_constants(self.kernel, scene.dim, self.H)
        self.gradient_moment = lattice_gradient_moment(self.kernel, scene.dim, self.H, dx)
        s_g /= self.gradient_moment  # calibrated kernel gradient (boundaries.lattice_gradient_moment)

        self.walls = build_walls(scene, self.kernel, self.H, dtype)
        ids, x, v = generate_particles(scene, self.walls)
        rho0 = scene.fluid.rest_density
        S = lattice_sum(self.kernel, scene.dim, self.H, dx)
        mass = rho0 / S
        self._state = ParticleState.create(ids, x, v, np.full(len(ids), mass), dtype)
        self.n_particles = len(ids)

        self.host_grid = _make_grid(scene, self.walls, self.H, dtype)
        self.grid = self.host_grid
        self.grid_lo = self.grid.origin.astype(np.float64)
        self.periodic = int(self.grid.periodic)
        nu = sph.nu if self.viscosity in (Viscosity.MULLER, Viscosity.MORRIS) else 0.0
        self.nu = nu
        self.dfsph = dfsph = sph.solver == "dfsph"
        self.prm = make_params(
            dtype, H=self.H, h=self.h, s_w=s_w, s_g=s_g, s_l=s_l, w0=w(int(self.kernel), 0.0, self.H, s_w),
            rho0=rho0, c0=sph.sound_speed, clamp_negative=bool(sph.clamp_negative_pressure), alpha=sph.alpha,
            mu=rho0 * nu, gravity=scene.forces.gravity, external=scene.forces.external,
            central_omega2=scene.forces.central_omega ** 2, central=scene.forces.central_center,
            period=tuple(self.grid.period), xsph_eps=scene.terms.xsph, shift_a=scene.terms.shifting,
            sigma=scene.terms.surface_tension,
            st_threshold=scene.terms.surface_threshold / dx, vorticity_eps=scene.terms.vorticity_confinement,
            restitution=scene.boundary.restitution, friction=scene.boundary.friction,
            wall_gap=scene.boundary.gap * dx, dx=dx, inv_s=1.0 / S, dim3=scene.dim == 3,
            wall_table_end=table_end(self.H, dx),
            dfsph_d0=lattice_pressure_diagonal(self.kernel, scene.dim, self.H, dx, rho0) if dfsph else 1.0,
            dfsph_omega=relaxation(lattice_jacobi_ratio(self.kernel, scene.dim, self.H, dx)) if dfsph else 0.5,
            delta_hc0=sph.delta * self.h * sph.sound_speed,
        )
        self.use_xsph = scene.terms.xsph > 0.0
        self.use_shifting = scene.terms.shifting > 0.0
        self.use_drift = self.use_xsph or self.use_shifting  # the drift uses v + dv
        self.use_surface_tension = scene.terms.surface_tension > 0.0
        self.use_vorticity = scene.terms.vorticity_confinement > 0.0
        self.continuity = sph.density == "continuity"
        self.use_diffusion = self.continuity and sph.delta > 0.0
        self.use_divergence_solve = self.dfsph and sph.divergence_tolerance > 0.0
        # per solver ("density", "divergence"): steps solved, iterations in all, most in one step,
        # steps that stopped at sph.max_iterations, and the last step's iterations and mean error
        self.solver_stats = {name: {"steps": 0, "iterations": 0, "max": 0, "unconverged": 0, "last": 0,
                                    "last_error": 0.0} for name in ("density", "divergence")}
        # per-particle arrays that follow their particle (ParticleState.extra): DFSPH's kappa = p / rho^2,
        # the next step's warm start (physics/dfsph.py); the carried density (physics/continuity.py).
        # 0 means a cold start: kappa = 0, density = rho0.
        self.extra_names = (("kappa",) if self.dfsph else ()) + (("density",) if self.continuity else ())
        self._add_extra(self._state)
        self._resize_scratch(self.n_particles)
        self._lo = self.grid_lo.astype(dtype)

        self.t = 0.0
        self.step_index = 0
        self.dt_prev = 0.0  # leapfrog: the previous step, for the combined kick
        self.dt = 0.0
        self.dt_flow = 0.0
        self.rho_ref = scene.fluid.rest_density  # the density solve's target (_reference_density)
        self.leaks = 0
        self.max_neighbours = 0
        self.max_compression = 0.0
        self.limit_counts = {name: 0 for name in LIMITS}
        self.last_limit = ""
        self.prm_now = self.prm
        self.timers = StageTimers()
        if backend == "cuda":
            self.engine = cuda_backend.CudaStages(self)
            self.grid = self.engine.grid  # the device grid: counts, permutation downloaded on demand
        else:
            self.engine = cpu.CpuStages(self)

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

    def _add_extra(self, state: ParticleState):
        for name in self.extra_names:
            if name not in state.extra:
                state.extra[name] = np.zeros(state.x.shape[0], dtype=self.dtype)

    def set_parameter(self, key: str, value):
        """Change a run-time settable value (nodes/control.py SETTABLE: body forces, viscosity, wall
        friction/restitution) from the next step on; ``value`` is already validated."""
        section, name = key.split(".")
        self.scene = dataclasses.replace(self.scene, **{section: dataclasses.replace(getattr(self.scene, section),
                                                                                  **{name: value})})
        p, f = self.prm, self.dtype.type
        if key in ("forces.external", "forces.gravity"):
            self.prm = p._replace(**{f"{name}_{a}": f(value[i]) for i, a in enumerate("xyz")})
        elif key == "sph.alpha":
            self.prm = p._replace(alpha=f(value))
        elif key == "sph.nu":
            if self.viscosity in (Viscosity.MULLER, Viscosity.MORRIS):
                self.nu = value
                self.prm = p._replace(mu=f(self.scene.fluid.rest_density * value))
        elif key in ("boundary.friction", "boundary.restitution"):
            self.prm = p._replace(**{name: f(value)})
        else:
            raise ValueError(f"{key} cannot be changed during a run")

    @staticmethod
    def grid_for(scene: Scene):
        """The global grid of ``scene`` without generating particles (to check a decomposition)."""
        kernel = KERNELS[scene.sph.kernel]
        H = scene.sph.support * scene.particles.spacing
        return _make_grid(scene, build_walls(scene, kernel, H, np.float64), H, np.float64)

    def _resize_scratch(self, n: int):
        """Per-step work arrays for n rows (owned + ghosts); reallocated only when n changes."""
        if getattr(self, "_scratch_n", None) == n:
            return
        dtype = self.dtype
        self._xsph_dv = np.zeros((n if self.use_drift else 0, 3), dtype=dtype)  # drift correction dv
        self._omega = np.zeros((n if self.use_vorticity else 0, 3), dtype=dtype)
        self._leaked = np.zeros(n, dtype=np.int8)
        self._fill = np.ones(n, dtype=dtype)  # wall fill fraction theta (physics/walls.py)
        self._drho = np.zeros(n if self.continuity else 1, dtype=dtype)  # delta-SPH drho (kg/m^3/s; continuity.py)
        m = n if self.dfsph else 0  # DFSPH (physics/dfsph.py):
        self._wgrad = np.zeros((m, 3), dtype=dtype)   # wall gradient g^wall (kg/m^4)
        self._inv_d = np.zeros(m, dtype=dtype)        # 1 / D_i (m^8/kg^2 in 3D)
        self._lam = np.zeros(m, dtype=dtype)          # lambda_i = kappa_i dt^2 of this iteration (m^3/kg ...)
        self._lam_sum = np.zeros(m, dtype=dtype)      # sum of lambda_i over the density solve
        self._v_star = np.zeros((m, 3), dtype=dtype)  # predicted velocity v* (m/s)
        self._scratch_n = n

    # -- stages --------------------------------------------------------------------------------
    def _ramped_params(self):
        """Params with the body forces scaled by the ramp factor zeta(t) (physics/external.py)."""
        zeta = ramp_factor(self.t, self.scene.forces.ramp_time)
        if zeta == 1.0:
            self.prm_now = self.prm
        else:
            f = self.dtype.type(zeta)
            p = self.prm
            self.prm_now = p._replace(gravity_x=p.gravity_x * f, gravity_y=p.gravity_y * f, gravity_z=p.gravity_z * f,
                                      external_x=p.external_x * f, external_y=p.external_y * f,
                                      external_z=p.external_z * f, central_omega2=p.central_omega2 * f)
        return self.prm_now

    def _neighbours(self):
        self.max_neighbours = max(self.max_neighbours, self.engine.bin())  # x -> (cell, id) order, lists

    def step(self, dt_cap: float | None = None, halo=NULL_HALO):
        """Advance one time step; ``dt_cap`` shortens the last step of an --until run. ``halo`` must
        block while it waits (NULL_HALO, or a PeerHalo over a Zenoh endpoint)."""
        for _ in self.stages(halo, dt_cap):
            raise RuntimeError("a step yielded: its halo's transport does not block (use a cluster driver)")
        return self.dt

    def stages(self, halo, dt_cap: float | None = None):
        """The one place that orders a step, as a generator: it yields only while ``halo`` waits for
        messages from other peers (never for a single process, whose halo is NULL_HALO), so the same
        ordered step runs in one process, in a peer process, or in an in-process cluster."""
        t, e = self.timers, self.engine
        prm = self._ramped_params()
        yield from halo.exchange_positions(self)                   # migrants; ghosts' id, x, v, m (exchange 1)
        with t("grid"):
            self._neighbours()                                     # x                -> order, neighbour lists
        with t("density"):
            e.density(prm)                                         # x, m (v)         -> rho, p
        if self.dfsph:
            with t("dfsph_factor"):
                offset = e.dfsph_factor(prm)                       # x, m, rho        -> 1/D, g^wall; p = 0
            yield from self._reference_density(halo, offset)      # closed flows: the mean density
        yield from self._exchange_fields(halo)                     # ghosts' rho, p   (exchange 2)
        if self.use_divergence_solve:                              # v                -> v (div-free)
            yield from self._pressure_solve(halo, prm, True, self.dt_flow or self.scene.time.dt)
        with t("forces"):
            e.forces(prm)                                          # x, v, rho, p     -> a
        if self.use_diffusion:
            with t("diffusion"):
                e.diffusion(prm)                                   # x, m, rho        -> delta-SPH drho
        if self.use_surface_tension:
            with t("surface_tension"):
                e.surface_tension(prm)                             # x, m, rho        -> a (+=)
        if self.use_vorticity:
            with t("vorticity"):
                e.vorticity(prm)                                   # x, v, rho        -> omega
            omega = e.fetch("omega")
            yield from halo.exchange_ghosts(self, "omega", {"omega": omega})  # ghosts' omega (exchange 3)
            if halo is not NULL_HALO:
                e.store("omega", omega)
            with t("confinement"):
                e.confinement(prm)                                 # omega            -> a (+=)
        if self.use_xsph:
            with t("xsph"):
                e.xsph(prm)                                        # x, v, rho        -> xsph_dv
        if self.use_shifting:
            with t("shifting"):
                e.shifting(prm)                                    # x, v, m, rho     -> xsph_dv (+=)
        with t("timestep"):
            stats = e.statistics()                                 # local max |v|, |a|, compression
        stats = yield from halo.reduce_max(self, stats)            # global max |v|, |a|, compression
        dt = self._choose_dt(dt_cap, stats)                        # -> dt (+ health check)
        if self.dfsph:
            with t("dfsph_kick"):
                e.dfsph_kick(self.dtype.type(dt))                  # v, a (non-pressure) -> v*
            yield from self._pressure_solve(halo, prm, False, dt,  # v*               -> v* (rho* = rho0)
                                            share=min(dt / self.dt_flow, 1.0) ** 2)
            with t("dfsph_kick"):
                e.dfsph_finish(self.dtype.type(1.0 / dt), dt >= self.dt_flow)  # v*, lambda -> a, kappa, p
        with t("integrate"):                                       # a                -> v, x; walls, periodic
            if self.use_diffusion:
                e.density_update(self.dtype.type(dt))              # drho             -> carried rho
            self.leaks += e.integrate(prm, self.dtype.type(dt), self.dtype.type(self.dt_prev))
        self.dt_prev = dt
        self.dt = dt
        self.t += dt
        self.step_index += 1

    def _pressure_solve(self, halo, prm, divergence, dt, record=True, share=1.0):
        """DFSPH's iterative solve (physics/dfsph.py): the divergence solver on v, or the density
        solver on v*. Each iteration: lambda from the velocities, the global mean error, and unless
        converged the pressure velocity update; ghosts' lambda and velocities follow every update."""
        e, t = self.engine, self.timers
        sph = self.scene.sph
        name, field = ("divergence", "v") if divergence else ("density", "v_star")
        tolerance = sph.divergence_tolerance if divergence else sph.density_tolerance
        stage = f"{name}_solve"
        dt_ = self.dtype.type(dt)
        inv_dt = self.dtype.type(1.0 / dt)
        if not divergence:  # warm start: apply the previous step's pressure (lam = kappa dt^2, set by the kick)
            yield from self._exchange_rows(halo, "warm_lam", "lam")
            with t(stage):
                e.dfsph_update(prm, divergence, inv_dt)
            yield from self._exchange_rows(halo, "warm_v", field)  # ghosts' v* after kick and warm start
        it = 0
        while True:
            with t(stage):
                err = e.dfsph_source(prm, divergence, dt_, self.dtype.type(share), self.dtype.type(self.rho_ref))
            err = yield from halo.reduce_sum(self, f"{name}_err{it}", err)
            mean = err / ERROR_QUANTUM / max(self.n_particles, 1)
            if (mean <= tolerance and it >= MIN_ITERATIONS) or it >= sph.max_iterations:
                break
            yield from self._exchange_rows(halo, f"{name}_lam{it}", "lam")
            with t(stage):
                e.dfsph_update(prm, divergence, inv_dt)
            yield from self._exchange_rows(halo, f"{name}_v{it}", field)
            it += 1
        if not record:
            return
        st = self.solver_stats[name]
        st["steps"] += 1
        st["iterations"] += it
        st["max"] = max(st["max"], it)
        st["unconverged"] += int(mean > tolerance)
        st["last"] = it
        st["last_error"] = mean

    def _reference_density(self, halo, offset):
        """rho_ref of the density solve: rho0 with free surfaces, the mean density of a closed flow
        (``sph.clamp_negative_pressure`` false; physics/dfsph.reference_density)."""
        rho0 = self.scene.fluid.rest_density
        if self.scene.sph.clamp_negative_pressure:
            self.rho_ref = rho0
            return
        total = yield from halo.reduce_sum(self, "rho_offset", offset)
        self.rho_ref = reference_density(rho0, total, self.n_particles)

    def _exchange_rows(self, halo, phase, name):
        """Ghost rows of a per-row array (lam, v, v*) from their owners; nothing for one process."""
        if halo is NULL_HALO:
            return
        host = self.engine.fetch(name)
        yield from halo.exchange_ghosts(self, phase, {name: host}, kind="solver")
        self.engine.store(name, host)

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
        c0 = 0.0 if self.dfsph else self.scene.sph.sound_speed  # DFSPH: no sound speed limits its step
        if vmax2 >= c0 * c0 and not self.dfsph:
            # weak compressibility assumes |v| << c0 (Mach 0.1); at Mach 1 the run is blowing up
            self._fail(f"flow speed reached the speed of sound (max |v| = {math.sqrt(vmax2):.3g} m/s >= "
                       f"sph.sound_speed = {c0:g} m/s): energy blow-up; raise sph.sound_speed or shorten the "
                       "time step", rows="fastest")
        shift_a = self.scene.terms.shifting
        travel = step_length(self.scene.particles.spacing, self.scene.boundary.gap) if self.dfsph else 0.0
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
        if self.dfsph and dt < 1.0e-6 * tm.dt:
            # without a speed of sound nothing else stops a run whose velocities blow up: the CFL step collapses
            self._fail(f"time step collapsed to {dt:.3g} s (time.dt = {tm.dt:g} s; max |v| = {math.sqrt(vmax2):.3g} "
                       "m/s): energy blow-up; tighten sph.density_tolerance or lower time.cfl", rows="fastest")
        self.dt_flow = dt  # the step the flow allows, before an output time shortens it
        if dt_cap is not None and dt_cap < dt:
            dt, limit = dt_cap, "until"
        self.limit_counts[limit] += 1
        self.last_limit = limit
        return dt

    def _fail(self, cause: str, density: bool = False, rows: str = "bad"):
        """Raise SimulationError naming the step, the cause and the particles concerned: the
        over-compressed ones (density), the fastest and most accelerated ten (rows="fastest"), or
        those holding NaN/Inf."""
        s = self.state
        n = s.n_owned
        if density:
            rows = np.nonzero(s.rho[:n] / self.prm.rho0 > self.scene.run.max_density_ratio)[0]
        elif rows == "fastest":
            score = np.einsum("ij,ij->i", s.v[:n], s.v[:n]) + np.einsum("ij,ij->i", s.a[:n], s.a[:n]) * self.h
            rows = np.argsort(-score, kind="stable")[:10]
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
        """refresh() as a generator over a halo (see stages)."""
        prm = self._ramped_params()
        e = self.engine
        yield from halo.exchange_positions(self)
        self._neighbours()
        e.density(prm, commit=False)  # continuity: the pending update is applied by the next step
        if self.dfsph:
            yield from self._reference_density(halo, e.dfsph_factor(prm))
        yield from self._exchange_fields(halo)
        e.forces(prm)
        if self.dfsph:  # the pressure the next step would solve for (p = 0 otherwise)
            dt = self.dt_flow or self.scene.time.dt  # a full step, not a shortened last one
            e.dfsph_kick(self.dtype.type(dt))
            yield from self._pressure_solve(halo, prm, False, dt, record=False)
            e.dfsph_finish(self.dtype.type(1.0 / dt), True)

    def _exchange_fields(self, halo):
        """Exchange 2; a device takes the ghosts' rho, p the halo wrote into the host mirror."""
        yield from halo.exchange_fields(self)
        if halo is not NULL_HALO:
            self.engine.to_device(("rho", "p"))

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
