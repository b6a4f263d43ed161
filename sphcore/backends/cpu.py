"""CPU drivers: one ``@njit(parallel=True)`` function per stage, a ``prange`` over the rows of
``backends/rows.py``.

Every driver loops over owned particles i (``prange``) and calls the stage's row function, which
visits i's neighbours j in list order and writes only row i (gather, never scatter: no atomics, no
races, reproducible sums). Integer choices (kernel, EOS, viscosity model, integrator, whether any
axis is periodic) are compile-time literals (``numba.literally``): each scene compiles, and caches,
a driver containing only the branches it uses.
"""
from numba import literally, njit, prange

from sphcore.backends.literal import literal_dispatch
from sphcore.backends.rows import (acceleration_row, boundaries_row, confinement_row, density_row, density_update_row,
                                   dfsph_factor_row, dfsph_finish_row, dfsph_kick_row, dfsph_source_row,
                                   dfsph_update_row, diffusion_row, integrate_row, shifting_row, statistics_row,
                                   surface_tension_row, vorticity_row, xsph_row)
from sphcore.physics.dfsph import quantized_error, quantized_offset

# Floating-point licences for the neighbour passes: reassociation (the sums over neighbours become
# partial sums LLVM can schedule; 25-30 % faster forces), contraction into FMA, reciprocals and
# ignoring the sign of zero. Not 'nnan'/'ninf' (NaN must propagate to the health check) nor 'afn'
# (sqrt stays exact). Results stay deterministic: the same compiled driver on the same neighbour
# order gives the same bits, on one process or many.
FASTMATH = {"reassoc", "contract", "arcp", "nsz"}


@literal_dispatch(4)
@njit(cache=True, parallel=True, fastmath=FASTMATH)
def compute_density(kernel, eos, periodic, continuity, prm, n, x, v, m, nbr, counts, wall_kind, wall_data,
                    wall_tables, dt_prev, commit, rho_c, rho, p, fill):
    """rho, p and the wall fill fraction of rows 0..n-1 (rows.density_row)."""
    literally(kernel)
    literally(eos)
    literally(periodic)
    literally(continuity)
    for i in prange(n):
        density_row(kernel, eos, periodic, continuity, prm, i, x, v, m, nbr, counts, wall_kind, wall_data,
                    wall_tables, dt_prev, commit, rho_c, rho, p, fill)


@literal_dispatch(3)
@njit(cache=True, parallel=True, fastmath=FASTMATH)
def density_diffusion(kernel, eos, periodic, prm, n, x, m, rho, nbr, counts, drho):
    """delta-SPH density diffusion of rows 0..n-1 (rows.diffusion_row)."""
    literally(kernel)
    literally(eos)
    literally(periodic)
    for i in prange(n):
        diffusion_row(kernel, eos, periodic, prm, i, x, m, rho, nbr, counts, drho)


@njit(cache=True, parallel=True)
def density_update(n, rho_c, drho, dt):
    """The carried density of rows 0..n-1 advanced by dt (rows.density_update_row)."""
    for i in prange(n):
        density_update_row(i, rho_c, drho, dt)


@literal_dispatch(3)
@njit(cache=True, parallel=True, fastmath=FASTMATH)
def compute_acceleration(kernel, viscosity, periodic, prm, n, x, v, m, rho, p, nbr, counts, wall_kind, wall_data,
                         wall_tables, fill, a):
    """a of rows 0..n-1: pressure, viscosity, body force, wall pressure (rows.acceleration_row)."""
    literally(kernel)
    literally(viscosity)
    literally(periodic)
    for i in prange(n):
        acceleration_row(kernel, viscosity, periodic, prm, i, x, v, m, rho, p, nbr, counts, wall_kind, wall_data,
                         wall_tables, fill, a)


@literal_dispatch(2)
@njit(cache=True, parallel=True, fastmath=FASTMATH)
def dfsph_factor(kernel, periodic, prm, n, x, m, rho, nbr, counts, wall_kind, wall_data, wall_tables, fill, p, wgrad,
                 inv_d, lam_sum):
    """DFSPH wall gradient, 1 / D, p = 0 and lam_sum = 0 of rows 0..n-1 (rows.dfsph_factor_row); returns
    the sum of rho_i / rho0 - 1 in units of 2^-32 (dfsph.quantized_offset: the mean density)."""
    literally(kernel)
    literally(periodic)
    total = 0
    for i in prange(n):
        dfsph_factor_row(kernel, periodic, prm, i, x, m, rho, nbr, counts, wall_kind, wall_data, wall_tables, fill,
                         p, wgrad, inv_d, lam_sum)
        total += quantized_offset(rho[i], prm.rho0)
    return total


@literal_dispatch(3)
@njit(cache=True, parallel=True, fastmath=FASTMATH)
def dfsph_source(kernel, periodic, divergence, prm, n, x, v, m, rho, nbr, counts, wgrad, inv_d, dt, share, rho_ref,
                 lam_sum, lam):
    """lambda of rows 0..n-1 (rows.dfsph_source_row); returns the sum of |s_i| / rho0 in units of
    2^-32 (an integer: the same sum in any order, dfsph.quantized_error)."""
    literally(kernel)
    literally(periodic)
    literally(divergence)
    total = 0
    for i in prange(n):
        total += quantized_error(dfsph_source_row(kernel, periodic, divergence, prm, i, x, v, m, rho, nbr, counts,
                                                  wgrad, inv_d, dt, share, rho_ref, lam_sum, lam))
    return total


@literal_dispatch(2)
@njit(cache=True, parallel=True, fastmath=FASTMATH)
def dfsph_update(kernel, periodic, prm, n, x, m, lam, nbr, counts, wgrad, inv_dt, v, lam_sum):
    """Pressure velocity update of rows 0..n-1 (rows.dfsph_update_row)."""
    literally(kernel)
    literally(periodic)
    for i in prange(n):
        dfsph_update_row(kernel, periodic, prm, i, x, m, lam, nbr, counts, wgrad, inv_dt, v, lam_sum)


@njit(cache=True, parallel=True)
def dfsph_kick(n, v, a, dt, kappa, v_star, lam, lam_sum):
    """v* = v + dt a and the warm-start lambda of rows 0..n-1 (rows.dfsph_kick_row)."""
    for i in prange(n):
        dfsph_kick_row(i, v, a, dt, kappa, v_star, lam, lam_sum)


@njit(cache=True, parallel=True)
def dfsph_finish(n, v, v_star, rho, lam_sum, inv_dt, store, a, p, kappa):
    """a = (v* - v) / dt and (if store) the solved kappa, p of rows 0..n-1 (rows.dfsph_finish_row)."""
    for i in prange(n):
        dfsph_finish_row(i, v, v_star, rho, lam_sum, inv_dt, store, a, p, kappa)


@literal_dispatch(2)
@njit(cache=True, parallel=True, fastmath=FASTMATH)
def add_surface_tension(kernel, periodic, prm, n, x, m, rho, nbr, counts, a):
    """a += colour-field surface tension (rows.surface_tension_row)."""
    literally(kernel)
    literally(periodic)
    for i in prange(n):
        surface_tension_row(kernel, periodic, prm, i, x, m, rho, nbr, counts, a)


@literal_dispatch(2)
@njit(cache=True, parallel=True, fastmath=FASTMATH)
def compute_vorticity(kernel, periodic, prm, n, x, v, m, rho, nbr, counts, omega):
    """omega of rows 0..n-1 (rows.vorticity_row)."""
    literally(kernel)
    literally(periodic)
    for i in prange(n):
        vorticity_row(kernel, periodic, prm, i, x, v, m, rho, nbr, counts, omega)


@literal_dispatch(2)
@njit(cache=True, parallel=True, fastmath=FASTMATH)
def add_vorticity_confinement(kernel, periodic, prm, n, x, m, rho, omega, nbr, counts, a):
    """a += vorticity confinement (rows.confinement_row)."""
    literally(kernel)
    literally(periodic)
    for i in prange(n):
        confinement_row(kernel, periodic, prm, i, x, m, rho, omega, nbr, counts, a)


@literal_dispatch(2)
@njit(cache=True, parallel=True, fastmath=FASTMATH)
def compute_xsph(kernel, periodic, prm, n, x, v, m, rho, nbr, counts, dv):
    """XSPH velocity correction dv of rows 0..n-1 (rows.xsph_row)."""
    literally(kernel)
    literally(periodic)
    for i in prange(n):
        xsph_row(kernel, periodic, prm, i, x, v, m, rho, nbr, counts, dv)


@literal_dispatch(3)
@njit(cache=True, parallel=True, fastmath=FASTMATH)
def compute_shifting(kernel, periodic, add, prm, n, x, v, m, rho, nbr, counts, wall_kind, wall_data, dv):
    """Particle-shifting drift of rows 0..n-1, written to dv or added to it (rows.shifting_row)."""
    literally(kernel)
    literally(periodic)
    literally(add)
    for i in prange(n):
        shifting_row(kernel, periodic, prm, i, x, v, m, rho, nbr, counts, wall_kind, wall_data, add, dv)


@literal_dispatch(2)
@njit(cache=True, parallel=True)
def integrate(integrator, use_drift, n, x, v, a, dv, dt, dt_prev):
    """v, x of rows 0..n-1 advanced by dt (rows.integrate_row)."""
    literally(integrator)
    literally(use_drift)
    for i in prange(n):
        integrate_row(integrator, use_drift, i, x, v, a, dv, dt, dt_prev)


@literal_dispatch(1)
@njit(cache=True, parallel=True)
def enforce_boundaries(periodic, prm, n, x, v, lo, wall_kind, wall_data, leaked):
    """Periodic wrap, wall collision guard and leak marks of rows 0..n-1 (rows.boundaries_row)."""
    literally(periodic)
    for i in prange(n):
        boundaries_row(periodic, prm, i, x, v, lo, wall_kind, wall_data, leaked)


@njit(cache=True, parallel=True)
def step_statistics(n, x, v, a, rho, rho0):
    """(max |v|^2, max |a|^2, max (rho/rho0 - 1, 0), count of rows holding NaN/Inf) over owned rows.

    The density error counts compression only: free-surface particles have a partial neighbourhood
    and a legitimately low summed density."""
    vmax2 = 0.0
    amax2 = 0.0
    dev = 0.0
    bad = 0
    for i in prange(n):
        v2, a2, r, finite = statistics_row(i, x, v, a, rho, rho0)
        if not finite:
            bad += 1
        else:
            vmax2 = max(vmax2, v2)
            amax2 = max(amax2, a2)
            dev = max(dev, r)
    return vmax2, amax2, dev, bad


class CpuStages:
    """The stages of ``Simulation.stages`` on the CPU: the drivers above over the simulation's host
    state (which is the only copy, so the host <-> device hooks do nothing)."""

    def __init__(self, sim):
        self.sim = sim

    def pull(self, state):
        pass

    def to_device(self, names):
        pass

    def fetch(self, name):
        if name == "v":
            return self.sim.state.v
        return getattr(self.sim, "_" + name)

    def store(self, name, host):
        pass

    def bin(self):
        return self.sim.grid.bin(self.sim.state)  # x -> (cell, id) order, neighbour lists

    def density(self, prm, commit=True):
        sim = self.sim
        s, w_, g = sim.state, sim.walls, sim.grid
        rho_c = s.extra["density"] if sim.continuity else sim._drho
        compute_density(int(sim.kernel), int(sim.eos), sim.periodic, int(sim.continuity), prm, s.n_owned, s.x, s.v,
                        s.m, g.nbr, g.counts, w_.kind, w_.data, w_.tables, sim.dtype.type(sim.dt_prev), bool(commit),
                        rho_c, s.rho, s.p, sim._fill)

    def diffusion(self, prm):
        sim = self.sim
        s, g = sim.state, sim.grid
        density_diffusion(int(sim.kernel), int(sim.eos), sim.periodic, prm, s.n_owned, s.x, s.m, s.rho, g.nbr,
                          g.counts, sim._drho)

    def density_update(self, dt):
        sim = self.sim
        density_update(sim.state.n_owned, sim.state.extra["density"], sim._drho, dt)

    def forces(self, prm):
        sim = self.sim
        s, w_, g = sim.state, sim.walls, sim.grid
        compute_acceleration(int(sim.kernel), int(sim.viscosity), sim.periodic, prm, s.n_owned, s.x, s.v, s.m,
                             s.rho, s.p, g.nbr, g.counts, w_.kind, w_.data, w_.tables, sim._fill, s.a)

    def dfsph_factor(self, prm):
        sim = self.sim
        s, w_, g = sim.state, sim.walls, sim.grid
        return int(dfsph_factor(int(sim.kernel), sim.periodic, prm, s.n_owned, s.x, s.m, s.rho, g.nbr, g.counts,
                                w_.kind, w_.data, w_.tables, sim._fill, s.p, sim._wgrad, sim._inv_d, sim._lam_sum))

    def dfsph_source(self, prm, divergence, dt, share, rho_ref):
        sim = self.sim
        s, g = sim.state, sim.grid
        v = s.v if divergence else sim._v_star
        return int(dfsph_source(int(sim.kernel), sim.periodic, int(divergence), prm, s.n_owned, s.x, v, s.m, s.rho,
                                g.nbr, g.counts, sim._wgrad, sim._inv_d, dt, share, rho_ref, sim._lam_sum, sim._lam))

    def dfsph_update(self, prm, divergence, inv_dt):
        sim = self.sim
        s, g = sim.state, sim.grid
        v = s.v if divergence else sim._v_star
        dfsph_update(int(sim.kernel), sim.periodic, prm, s.n_owned, s.x, s.m, sim._lam, g.nbr, g.counts, sim._wgrad,
                     inv_dt, v, sim._lam_sum)

    def dfsph_kick(self, dt):
        sim = self.sim
        s = sim.state
        dfsph_kick(s.n_owned, s.v, s.a, dt, s.extra["kappa"], sim._v_star, sim._lam, sim._lam_sum)

    def dfsph_finish(self, inv_dt, store):
        sim = self.sim
        s = sim.state
        dfsph_finish(s.n_owned, s.v, sim._v_star, s.rho, sim._lam_sum, inv_dt, bool(store), s.a, s.p, s.extra["kappa"])

    def surface_tension(self, prm):
        sim = self.sim
        s, g = sim.state, sim.grid
        add_surface_tension(int(sim.kernel), sim.periodic, prm, s.n_owned, s.x, s.m, s.rho, g.nbr, g.counts, s.a)

    def vorticity(self, prm):
        sim = self.sim
        s, g = sim.state, sim.grid
        compute_vorticity(int(sim.kernel), sim.periodic, prm, s.n_owned, s.x, s.v, s.m, s.rho, g.nbr, g.counts,
                          sim._omega)

    def confinement(self, prm):
        sim = self.sim
        s, g = sim.state, sim.grid
        add_vorticity_confinement(int(sim.kernel), sim.periodic, prm, s.n_owned, s.x, s.m, s.rho, sim._omega,
                                  g.nbr, g.counts, s.a)

    def xsph(self, prm):
        sim = self.sim
        s, g = sim.state, sim.grid
        compute_xsph(int(sim.kernel), sim.periodic, prm, s.n_owned, s.x, s.v, s.m, s.rho, g.nbr, g.counts,
                     sim._xsph_dv)

    def shifting(self, prm):
        sim = self.sim
        s, g, w_ = sim.state, sim.grid, sim.walls
        compute_shifting(int(sim.kernel), sim.periodic, int(sim.use_xsph), prm, s.n_owned, s.x, s.v, s.m, s.rho,
                         g.nbr, g.counts, w_.kind, w_.data, sim._xsph_dv)

    def statistics(self):
        sim = self.sim
        s = sim.state
        return step_statistics(s.n_owned, s.x, s.v, s.a, s.rho, sim.prm.rho0)

    def integrate(self, prm, dt, dt_prev):
        sim = self.sim
        s = sim.state
        integrate(int(sim.integrator), int(sim.use_drift), s.n_owned, s.x, s.v, s.a, sim._xsph_dv, dt, dt_prev)
        enforce_boundaries(sim.periodic, prm, s.n_owned, s.x, s.v, sim._lo, sim.walls.kind, sim.walls.data,
                           sim._leaked)
        return int(sim._leaked[: s.n_owned].sum())
