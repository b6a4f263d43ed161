"""The pressure solvers a scene chooses with ``sph.solver``: what each adds to the step.

A solver contributes its stages (``stages.py``), the arrays it carries with the particles
(``carried``: ``state.extra``), its parameters (``params``) and its time-step rule
(``sound_speed``, ``travel``, ``check_dt``). ``Simulation.stages`` calls its hooks at fixed points
of the one ordered step; each hook is a generator over the halo, like the step itself:

=========  =========================================  ==============================================
hook       where in the step                          DFSPH (Bender & Koschier 2017; physics/dfsph.py)
=========  =========================================  ==============================================
fields     after the density, before exchange 2       1/D_i, wall gradient, p = 0; reference density
prepare    after exchange 2, before the forces        the divergence solve on v
correct    after dt is chosen, before integrating     v* = v + dt a; density solve; a = (v* - v) / dt
refresh    outputs: the pressure of a full step       the density solve for dt_flow, stored
=========  =========================================  ==============================================

WCSPH (weakly compressible SPH, Monaghan 1994) needs none of them: its pressure comes from the
equation of state in the density stage, and the speed of sound limits its step.
"""
from __future__ import annotations

from sphcore import stages as st
from sphcore.boundaries import lattice_jacobi_ratio, lattice_pressure_diagonal
from sphcore.physics.dfsph import ERROR_QUANTUM, MIN_ITERATIONS, reference_density, relaxation, step_length


class WCSPH:
    """Weakly compressible SPH: nothing to solve; the acoustic CFL limit and the Mach-1 check."""

    name = "wcsph"
    carried = ()

    def __init__(self, sim):
        self.sim = sim
        self.rho_ref = sim.scene.fluid.rest_density  # the density the pressure is relative to
        self.stats = {}  # per iterative solve (DFSPH): iteration counts

    @staticmethod
    def params(scene, kernel, H, dx) -> dict:
        """The solver's Params fields (unused by WCSPH: neutral values)."""
        return {"dfsph_d0": 1.0, "dfsph_omega": 0.5}

    @property
    def sound_speed(self) -> float:
        """The c0 of the acoustic time-step limit (m/s)."""
        return self.sim.scene.sph.sound_speed

    @property
    def travel(self) -> float:
        """The longest distance a particle may move in one step (m); 0 = no such limit."""
        return 0.0

    def check_dt(self, dt: float, vmax: float):
        """Stop a run whose chosen step ``dt`` shows it is blowing up (max |v| = ``vmax``)."""

    def check_flow(self, vmax: float):
        """Stop a run whose flow reached the speed of sound (weak compressibility assumes Mach << 1)."""
        c0 = self.sound_speed
        if vmax >= c0:
            # weak compressibility assumes |v| << c0 (Mach 0.1); at Mach 1 the run is blowing up
            self.sim._fail(f"flow speed reached the speed of sound (max |v| = {vmax:.3g} m/s >= "
                           f"sph.sound_speed = {c0:g} m/s): energy blow-up; raise sph.sound_speed or shorten the "
                           "time step", rows="fastest")

    def fields(self, halo, prm):
        yield from ()

    def prepare(self, halo, prm):
        yield from ()

    def correct(self, halo, prm, dt):
        yield from ()

    def refresh(self, halo, prm):
        yield from ()


class DFSPH(WCSPH):
    """Divergence-free SPH: two iterative pressure solves per step, no speed of sound.

    ``stats`` per solve ("density", "divergence"): steps solved, iterations in all, most in one step,
    steps that stopped at sph.max_iterations, and the last step's iterations and mean error.
    ``rho_ref`` is the density solve's target: rho0, or the mean density of a closed flow."""

    name = "dfsph"
    carried = ("kappa",)  # kappa = p / rho^2: the next step's warm start (0 = a cold start)

    def __init__(self, sim):
        super().__init__(sim)
        self.stats = {name: {"steps": 0, "iterations": 0, "max": 0, "unconverged": 0, "last": 0,
                             "last_error": 0.0} for name in ("density", "divergence")}

    @staticmethod
    def params(scene, kernel, H, dx) -> dict:
        """D of a full neighbourhood (the Jacobi diagonal floor) and the Jacobi relaxation."""
        return {"dfsph_d0": lattice_pressure_diagonal(kernel, scene.dim, H, dx, scene.fluid.rest_density),
                "dfsph_omega": relaxation(lattice_jacobi_ratio(kernel, scene.dim, H, dx))}

    @property
    def sound_speed(self) -> float:
        return 0.0  # no sound speed limits the step

    def check_flow(self, vmax: float):
        pass  # incompressible: no Mach number

    @property
    def travel(self) -> float:
        scene = self.sim.scene
        return step_length(scene.particles.spacing, scene.boundary.gap)

    def check_dt(self, dt: float, vmax: float):
        """Without a speed of sound nothing else stops a run whose velocities blow up: the CFL step
        collapses."""
        tm = self.sim.scene.time
        if dt < 1.0e-6 * tm.dt:
            self.sim._fail(f"time step collapsed to {dt:.3g} s (time.dt = {tm.dt:g} s; max |v| = {vmax:.3g} "
                           "m/s): energy blow-up; tighten sph.density_tolerance or lower time.cfl", rows="fastest")

    def fields(self, halo, prm):
        """1/D, the wall gradient and p = 0 at the step's positions; the reference density."""
        sim = self.sim
        offset = sim._run(st.DFSPH_FACTOR, prm=prm)               # x, m, rho        -> 1/D, g^wall; p = 0
        rho0 = sim.scene.fluid.rest_density
        if sim.scene.sph.clamp_negative_pressure:  # free surfaces: rho0
            self.rho_ref = rho0
            return
        # a closed flow: its mean density (physics/dfsph.reference_density)
        total = yield from halo.reduce_sum(sim, "rho_offset", int(offset))
        self.rho_ref = reference_density(rho0, total, sim.n_particles)

    def prepare(self, halo, prm):
        """The divergence solve on v (if sph.divergence_tolerance > 0)."""
        sim = self.sim
        if sim.scene.sph.divergence_tolerance > 0.0:               # v                -> v (div-free)
            # no ghost's rho or p is read here: exchange 2 travels on while the solve runs (the forces
            # pass receives it)
            yield from self.solve(halo, prm, True, sim.dt_flow or sim.scene.time.dt)

    def correct(self, halo, prm, dt):
        """v* = v + dt a (non-pressure), the density solve on v*, then a = (v* - v) / dt so that the
        integrator's kick lands on v*."""
        sim = self.sim
        f = sim.dtype.type
        sim._run(st.DFSPH_KICK, dt=f(dt))                          # v, a (non-pressure) -> v*
        yield from self.solve(halo, prm, False, dt,                # v*               -> v* (rho* = rho0)
                              share=min(dt / sim.dt_flow, 1.0) ** 2)
        sim._run(st.DFSPH_FINISH, inv_dt=f(1.0 / dt), store=dt >= sim.dt_flow)  # v*, lambda -> a, kappa, p

    def refresh(self, halo, prm):
        """The pressure the next step would solve for (a full step, not a shortened last one)."""
        sim = self.sim
        f = sim.dtype.type
        dt = sim.dt_flow or sim.scene.time.dt
        sim.engine.run(st.DFSPH_KICK, dt=f(dt))
        yield from self.solve(halo, prm, False, dt, record=False)
        sim.engine.run(st.DFSPH_FINISH, inv_dt=f(1.0 / dt), store=True)

    def solve(self, halo, prm, divergence, dt, record=True, share=1.0):
        """The iterative solve (physics/dfsph.py): the divergence solver on v, or the density solver
        on v*. Each iteration: lambda from the velocities, the global mean error, and unless
        converged the pressure velocity update; ghosts' lambda and velocities follow every update."""
        sim = self.sim
        sph = sim.scene.sph
        name, field = ("divergence", "v") if divergence else ("density", "v_star")
        tolerance = sph.divergence_tolerance if divergence else sph.density_tolerance
        timer = f"{name}_solve"
        on = {"v": field}  # the velocities the solve works on
        f = sim.dtype.type
        dt_, inv_dt = f(dt), f(1.0 / dt)
        def update(rows, wait):                                    # lambda -> v (the pressure velocity update)
            sim._run(st.DFSPH_UPDATE, timer, arrays=on, rows=rows, wait=wait, prm=prm, inv_dt=inv_dt)

        def source(rows, wait):                                    # v -> lambda; the density error it removes
            return sim._run(st.DFSPH_SOURCE, timer, arrays=on, rows=rows, prm=prm, divergence=int(divergence),
                            dt=dt_, share=f(share), rho_ref=f(self.rho_ref))

        # Each update and each source reads the ghosts' rows the last stage wrote: a peer sends its rows
        # and computes its interior rows while they travel (Simulation._overlapped)
        travelling = None  # the phase carrying the ghosts' velocities the next source reads
        if not divergence:  # warm start: apply the previous step's pressure (lam = kappa dt^2, set by the kick)
            # the ghosts' lambda too, from the kappa they carry: the owners' bits, a message (a latency) fewer
            ghosts = sim.engine.ghost_rows()
            if ghosts.shape[0]:                                    # (a single process has none: no launch)
                sim._run(st.DFSPH_WARM_GHOSTS, timer, rows=ghosts, dt=dt_)
            update(None, True)
            travelling = "warm_v"                                  # ghosts' v* after kick and warm start
            halo.send_ghosts(sim, travelling, (field,), kind="solver")
        it = 0
        while True:
            parts = yield from sim._overlapped(halo, travelling, source)
            # the ghosts' lambda leaves before the error's sum says whether an update follows: both travel
            # at once, a latency less an iteration. After the last iteration it arrives unused (it is
            # received at once, with the sum, and overwritten before any pass reads a ghost's lambda).
            halo.send_ghosts(sim, f"{name}_lam{it}", ("lam",), kind="solver")
            # below the minimum an update follows whatever the error: its sum over the peers is formed
            # (and waited for) only where it decides, a latency less an iteration below the minimum
            if it >= MIN_ITERATIONS[name] or it >= sph.max_iterations:
                err = yield from halo.reduce_sum(sim, f"{name}_err{it}", sum(int(e) for e in parts))
                mean = err / ERROR_QUANTUM / max(sim.n_particles, 1)
                if (mean <= tolerance and it >= MIN_ITERATIONS[name]) or it >= sph.max_iterations:
                    yield from halo.receive_ghosts(sim, f"{name}_lam{it}")
                    break
            yield from sim._overlapped(halo, f"{name}_lam{it}", update)
            travelling = f"{name}_v{it}"
            halo.send_ghosts(sim, travelling, (field,), kind="solver")
            it += 1
        if not record:
            return
        stats = self.stats[name]
        stats["steps"] += 1
        stats["iterations"] += it
        stats["max"] = max(stats["max"], it)
        stats["unconverged"] += int(mean > tolerance)
        stats["last"] = it
        stats["last_error"] = mean
        sim.health.solve_ended(halo, name, stats, mean, tolerance)  # warn or stop if unconverged


SOLVERS = {"wcsph": WCSPH, "dfsph": DFSPH}  # sph.solver -> its class


def solver_for(sim):
    """The solver of ``sim``'s scene (sph.solver)."""
    return SOLVERS[sim.scene.sph.solver](sim)

