"""The model of a run: everything a scene fixes before the first particle moves.

``Model(scene, precision, backend)`` resolves the scene's choices (kernel family, EOS, viscosity,
integrator, solver) into their codes and compile-time ``choices``, the resolution (dx, H, h), the
walls, the global grid's geometry, the particle mass and the ``Params`` the stages read, and which
optional terms run. It holds no particles and no per-step state: the ``Simulation`` (solver.py) owns
those, the backend owns the scratch (stages.SCRATCH) and the solver plug-in (solvers.py) its own.
A run changes its model only through ``Simulation.change_scene`` (the keys that may change during a
run, scene.LIVE), which copies the live attributes of a Model rebuilt from the changed scene.
"""
from __future__ import annotations

import numpy as np

from sphcore import grid as grid_mod
from sphcore import stages as st
from sphcore.boundaries import build_walls, lattice_gradient_moment, lattice_sum, near_wall_cells, table_end
from sphcore.choices import EOSES, INTEGRATORS, KERNELS, PRESSURE_GRADIENTS, VISCOSITIES, PressureGradient, Viscosity
from sphcore.params import make_params
from sphcore.physics.external import ramp_factor
from sphcore.physics.kernels import kernel_constants, w
from sphcore.scene import Scene, artificial_alpha, grid_reach, list_skin, stores_pair_gradients
from sphcore.solvers import SOLVERS

DTYPES = {"f32": np.float32, "f64": np.float64}
# How the neighbour passes find their neighbours (run.neighbours; stages.CHOICES "neighbours"; grid.py).
# Both visit the same neighbours in the same order; the walk stores nothing per particle.
NEIGHBOURS = {"lists": grid_mod.NEIGHBOUR_LISTS, "walk": grid_mod.CELL_WALK}


def scene_value(scene: Scene, key: str):
    """The value of scene key "section.name"."""
    section, name = key.split(".")
    return getattr(getattr(scene, section), name)


def make_grid(scene, walls, H, dtype, backend="cpu"):
    """The global grid: the walls' bounding box plus one cell of margin on non-periodic axes; its
    cells sized for the lists' skin (scene.list_skin) on ``backend``."""
    periodic = tuple(bool(p) for p in scene.domain.periodic)
    lo, hi = walls.lo.copy(), walls.hi.copy()
    for d in range(3):
        if not periodic[d] and d < scene.dim:
            lo[d] -= H
            hi[d] += H
    return grid_mod.Grid(lo, hi, H, periodic, dtype, reach=grid_reach(scene),
                         skin=list_skin(scene, backend))


class Model:
    """Attributes (set once; the live ones, solver.LIVE_MODEL, also by ``Simulation.change_scene``):

    scene, precision ("f32"/"f64"), dtype; dx (m, the lattice spacing), H (m, support radius), h = H/2;
    kernel, eos, viscosity, integrator (choices.* IntEnums); neighbours ("lists" or "walk"); choices (stages.CHOICES name -> code);
    gradient_moment (boundaries.lattice_gradient_moment); walls; mass (kg per particle); host_grid,
    grid_lo (float64 origin), lo (origin in the run's dtype), periodic (0/1); nu (m^2/s, 0 without a
    physical viscosity); prm (params.Params); the flags dfsph, pair_gradients (DFSPH reads stored
    m_j grad W_ij), continuity, use_xsph, use_shifting, use_drift, use_vorticity, use_balsara, use_diffusion, use_damping;
    force_terms ((stage, scene value) of stages.FORCE_TERMS that are on); extra_names (the arrays carried
    in state.extra)."""

    def __init__(self, scene: Scene, precision: str | None = None, backend: str = "cpu"):
        self.scene = scene
        self.neighbours = scene.run.neighbours
        self.precision = precision or scene.run.precision
        if self.precision == "auto":  # float32 is the GPU's native precision; float64 the CPU's default
            self.precision = "f32" if backend == "cuda" else "f64"
        if self.precision not in DTYPES:
            raise ValueError(f"precision must be one of {', '.join(DTYPES)}, got {self.precision!r}")
        dtype = DTYPES[self.precision]
        self.dtype = np.dtype(dtype)
        sph, terms = scene.sph, scene.terms
        dx = scene.particles.spacing
        self.dx = dx
        self.H = sph.support * dx
        self.h = 0.5 * self.H
        self.kernel = KERNELS[sph.kernel]
        self.eos = EOSES[sph.eos]
        self.viscosity = VISCOSITIES[sph.viscosity]
        self.pressure_gradient = (PressureGradient.SOLVED if sph.solver == "dfsph"
                                  else PRESSURE_GRADIENTS[sph.pressure_gradient])
        self.integrator = INTEGRATORS[scene.time.integrator]
        s_w, s_g, s_l = kernel_constants(self.kernel, scene.dim, self.H)
        self.gradient_moment = lattice_gradient_moment(self.kernel, scene.dim, self.H, dx)
        s_g /= self.gradient_moment  # calibrated kernel gradient (boundaries.lattice_gradient_moment)
        self.walls = build_walls(scene, self.kernel, self.H, dtype)
        rho0 = scene.fluid.rest_density
        S = lattice_sum(self.kernel, scene.dim, self.H, dx)
        self.mass = rho0 / S  # the full lattice sums to rho0

        self.host_grid = make_grid(scene, self.walls, self.H, dtype, backend)
        self.walls.near = near_wall_cells(self.walls, self.host_grid)  # where the walls' terms can be non-zero
        self.grid_lo = self.host_grid.origin.astype(np.float64)
        self.lo = self.grid_lo.astype(dtype)
        self.periodic = int(self.host_grid.periodic)
        self.nu = sph.nu if self.viscosity in (Viscosity.MULLER, Viscosity.MORRIS) else 0.0
        self.dfsph = sph.solver == "dfsph"
        # DFSPH's factor and dozen solver passes a step read m_j grad W_ij stored per list entry by the density
        # pass (physics/pairs.mass_gradient; 3 numbers per entry, 780 B a particle in f32): on the CPU, with
        # lists. The GPU recomputes (memory is its limit; not measured there).
        self.pair_gradients = stores_pair_gradients(scene, backend)
        self.prm = make_params(
            dtype, H=self.H, h=self.h, s_w=s_w, s_g=s_g, s_l=s_l, w0=w(int(self.kernel), 0.0, self.H, s_w),
            rho0=rho0, c0=sph.sound_speed, clamp_negative=bool(sph.clamp_negative_pressure),
            alpha=artificial_alpha(scene),
            mu=rho0 * self.nu, gravity=self.fluid_gravity(scene), external=scene.forces.external,
            central_omega2=scene.forces.central_omega ** 2, central=scene.forces.central_center,
            period=tuple(self.host_grid.period), xsph_eps=terms.xsph, shift_a=terms.shifting,
            sigma=terms.surface_tension,
            st_threshold=terms.surface_threshold / dx, vorticity_eps=terms.vorticity_confinement,
            restitution=scene.boundary.restitution, friction=scene.boundary.friction,
            wall_gap=scene.boundary.gap * dx, dx=dx, inv_s=1.0 / S, dim3=scene.dim == 3,
            wall_table_end=table_end(self.H, dx),
            delta_hc0=sph.delta * self.h * sph.sound_speed, wall_nu=terms.wall_friction,
            p_background=sph.background_pressure, **SOLVERS[sph.solver].params(scene, self.kernel, self.H, dx),
        )
        self.use_xsph = terms.xsph > 0.0
        self.use_shifting = terms.shifting > 0.0
        self.use_drift = self.use_xsph or self.use_shifting  # the drift uses v + dv
        self.force_terms = tuple((term, scene_value(scene, term.key)) for term in st.FORCE_TERMS
                                 if scene_value(scene, term.key) > 0.0)
        self.use_vorticity = terms.vorticity_confinement > 0.0
        self.use_balsara = sph.viscosity_switch == "balsara"  # the balsara stage and its factor in the forces
        self.use_damping = bool(scene.damping_zones)
        self.continuity = sph.density == "continuity"
        self.use_diffusion = self.continuity and sph.delta > 0.0
        # per-particle arrays that follow their particle (ParticleState.extra): the solver's (DFSPH's
        # kappa = p / rho^2, the next step's warm start); the carried density (physics/continuity.py).
        # 0 means a cold start: kappa = 0, density = rho0.
        self.extra_names = (SOLVERS[sph.solver].carried + (("density",) if self.continuity else ())
                            + (("x_ref",) if list_skin(scene, backend) else ()))
        # the compile-time choices of this model's stages (stages.CHOICES); ``divergence`` is per call
        self.choices = {"kernel": int(self.kernel), "eos": int(self.eos), "viscosity": int(self.viscosity),
                        "viscosity_switch": int(self.use_balsara),
                        "pressure_gradient": int(self.pressure_gradient),
                        "integrator": int(self.integrator), "periodic": self.periodic,
                        "neighbours": NEIGHBOURS[self.neighbours],
                        "pair_gradients": int(self.pair_gradients),
                        "continuity": int(self.continuity), "use_drift": int(self.use_drift),
                        "add": int(self.use_xsph)}

    @staticmethod
    def grid_for(scene: Scene, backend: str = "cpu"):
        """The global grid of ``scene`` on ``backend`` without a model (to check a decomposition)."""
        kernel = KERNELS[scene.sph.kernel]
        H = scene.sph.support * scene.particles.spacing
        return make_grid(scene, build_walls(scene, kernel, H, np.float64), H, np.float64, backend)

    @staticmethod
    def fluid_gravity(scene: Scene) -> tuple:
        """The gravity the fluid feels: the scene's, or none with forces.hydrostatic = "removed" (the
        fluid under its modified pressure p - rho0 g . x; the floating bodies get their weight less
        their buoyancy instead, ``body_acceleration``)."""
        return (0.0, 0.0, 0.0) if scene.forces.hydrostatic == "removed" else scene.forces.gravity

    def body_acceleration(self, prm, t: float, body) -> tuple:
        """The body force on floating body ``body`` at time t (m/s^2): the fluid's (gravity and
        forces.external in ``prm``, ramped alike); with forces.hydrostatic = "removed", where the fluid
        feels no gravity and its pressure no hydrostatic part, the body's gravity less its buoyancy,
        (1 - rho0 / rho_body) zeta(t) g, added in float64."""
        b = [float(prm.gravity_x + prm.external_x), float(prm.gravity_y + prm.external_y),
             float(prm.gravity_z + prm.external_z)]
        if self.scene.forces.hydrostatic == "removed":
            share = (1.0 - self.scene.fluid.rest_density / body.density) * ramp_factor(t, self.scene.forces.ramp_time)
            b = [b[k] + share * float(self.scene.forces.gravity[k]) for k in range(3)]
        return tuple(b)

    def ramped_params(self, t: float):
        """Params at time t: the body forces scaled by the ramp factor zeta(t) (physics/external.py)."""
        zeta = ramp_factor(t, self.scene.forces.ramp_time)
        if zeta == 1.0:
            return self.prm
        f = self.dtype.type(zeta)
        p = self.prm
        return p._replace(gravity_x=p.gravity_x * f, gravity_y=p.gravity_y * f, gravity_z=p.gravity_z * f,
                          external_x=p.external_x * f, external_y=p.external_y * f, external_z=p.external_z * f,
                          central_omega2=p.central_omega2 * f)
