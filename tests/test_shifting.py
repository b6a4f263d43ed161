"""Particle shifting (physics/shifting.py): no shift on an ordered lattice, walls included, less
disorder on a disordered one, nothing in a free surface's layer, a void filled in a closed flow, and
nothing at all when it is off."""
import numpy as np

from sphcore import stages
from sphcore.scene import load_scene
from sphcore.solver import Simulation
from sphcore.state import ParticleState

TG = "configs/taylor_green_2d.toml"


def _periodic_box(overrides=()):
    return load_scene(TG, ["particles.spacing=0.05", "fluid.initial_flow='none'", "sph.viscosity='none'",
                           "time.mode='fixed'", "time.dt=1e-3", *overrides])


def _drift(sim, v):
    """The shifting drift of every particle for velocities v (one refresh, then the shifting stage)."""
    s = sim.state
    sim.state = ParticleState.create(s.id, s.x, v, s.m, sim.dtype, extra=s.extra)
    sim.refresh()
    sim.engine.run(stages.SHIFTING, prm=sim.prm)
    return sim.engine.scratch.dv[: sim.state.n_owned].copy()


def test_an_ordered_lattice_is_not_shifted():
    sim = Simulation(_periodic_box(["terms.shifting=2.0"]), "f64")
    v = np.tile([1.0, 0.5, 0.0], (sim.n_particles, 1))
    assert np.max(np.abs(_drift(sim, v))) < 1e-12


def test_shifting_moves_particles_out_of_a_cluster():
    """Squeeze one particle towards its right neighbour: the shift pushes it back (against the
    concentration gradient), scaled by A h |v|."""
    sim = Simulation(_periodic_box(["terms.shifting=2.0"]), "f64")
    s = sim.state
    x = s.x.copy()
    i = int(np.argmin(np.hypot(x[:, 0] - 0.5, x[:, 1] - 0.5)))
    x[i, 0] += 0.3 * 0.05
    sim.state = ParticleState.create(s.id, x, s.v, s.m, sim.dtype, extra=s.extra)
    dv = _drift(sim, np.tile([2.0, 0.0, 0.0], (sim.n_particles, 1)))
    row = int(np.nonzero(sim.state.id[: sim.state.n_owned] == s.id[i])[0][0])
    assert dv[row, 0] < 0.0  # back towards its lattice site
    dv2 = _drift(sim, np.tile([4.0, 0.0, 0.0], (sim.n_particles, 1)))
    assert np.isclose(dv2[row, 0], 2.0 * dv[row, 0], rtol=1e-12)  # D = A h |v| dt: linear in |v|


def _tank(overrides=()):
    return Simulation(load_scene("configs/hydrostatic_2d.toml", ["particles.spacing=0.05", "terms.shifting=2.0",
                                                                 *overrides]), "f64")


def test_an_ordered_lattice_by_the_walls_is_not_shifted():
    """The walls' share of C (their virtual lattice) balances the fluid's: a lattice particle by a
    wall or in a corner sees a full neighbourhood, so its C has no gradient."""
    sim = _tank()
    dv = _drift(sim, np.tile([1.0, 1.0, 0.0], (sim.n_particles, 1)))
    s = sim.state
    n = s.n_owned
    below_surface = s.x[:n, 1] < np.max(s.x[:n, 1]) - sim.H
    near_wall = (s.x[:n, 1] - sim.walls.lo[1] < sim.H) | (s.x[:n, 0] - sim.walls.lo[0] < sim.H)
    assert np.count_nonzero(near_wall & below_surface) > 10
    assert np.max(np.abs(dv[below_surface])) < 1e-9


def test_by_a_wall_a_displaced_particle_is_shifted_back_either_way():
    """A particle of the lattice's first row above the floor, pushed towards the floor or away from
    it, is shifted back towards its site: the floor's share of C counts as fluid would."""
    for offset, sign in ((-0.2, 1.0), (0.2, -1.0)):
        sim = _tank()
        s = sim.state
        x = s.x.copy()
        first_row = x[:, 1] < x[:, 1].min() + 1e-9
        i = int(np.argmin(np.where(first_row, np.abs(x[:, 0] - np.median(x[:, 0])), np.inf)))
        x[i, 1] += offset * 0.05
        sim.state = ParticleState.create(s.id, x, s.v, s.m, sim.dtype, extra=s.extra)
        dv = _drift(sim, np.tile([1.0, 0.0, 0.0], (sim.n_particles, 1)))
        row = int(np.nonzero(sim.state.id[: sim.state.n_owned] == s.id[i])[0][0])
        assert sign * dv[row, 1] > 0.0, (offset, dv[row])


def test_the_free_surface_layer_is_not_shifted():
    sim = _tank()
    rng = np.random.default_rng(3)
    s = sim.state
    x = s.x + rng.uniform(-0.1, 0.1, s.x.shape) * 0.05 * np.array([1, 1, 0])
    sim.state = ParticleState.create(s.id, x, s.v, s.m, sim.dtype, extra=s.extra)
    dv = _drift(sim, np.tile([1.0, 1.0, 0.0], (sim.n_particles, 1)))
    s = sim.state
    n = s.n_owned
    top = s.x[:n, 1] > np.max(s.x[:n, 1]) - 0.5 * 0.05
    assert np.all(dv[top] == 0.0)  # the top layer is in the free-surface layer
    assert np.count_nonzero(dv) > n // 2  # the rest of the disordered tank is shifted, by the walls too


def test_in_a_closed_flow_a_void_draws_its_neighbours_in():
    """Without a free surface (clamp_negative_pressure = false) a low C marks a void, not a surface:
    the particles around a hole are shifted into it; with a free surface they would be left alone."""
    def around_a_hole(overrides):
        sim = Simulation(_periodic_box(["terms.shifting=2.0", *overrides]), "f64")
        s = sim.state
        centre = np.array([0.5, 0.5, 0.0])
        r = np.hypot(s.x[:, 0] - 0.5, s.x[:, 1] - 0.5)
        keep = r > 0.06  # a hole of about two spacings
        sim.state = ParticleState.create(s.id[keep], s.x[keep], s.v[keep], s.m[keep], sim.dtype,
                                         extra={k: a[keep] for k, a in s.extra.items()})
        dv = _drift(sim, np.tile([1.0, 0.0, 0.0], (keep.sum(), 1)))
        s = sim.state
        n = s.n_owned
        rim = np.hypot(s.x[:n, 0] - 0.5, s.x[:n, 1] - 0.5) < 0.09
        inward = np.einsum("ij,ij->i", dv[rim], centre - s.x[:n][rim])
        return rim, inward

    rim, inward = around_a_hole(["sph.clamp_negative_pressure=false"])
    assert np.count_nonzero(rim) >= 8 and np.all(inward > 0.0)
    _, inward = around_a_hole(["sph.clamp_negative_pressure=true"])
    assert np.all(inward == 0.0)


def test_off_means_not_in_the_step():
    sim = Simulation(_periodic_box(["terms.shifting=0.0"]), "f64")
    sim.step()
    assert "shifting" not in sim.timers.summary()
    on = Simulation(_periodic_box(["terms.shifting=1.0"]), "f64")
    on.step()
    assert "shifting" in on.timers.summary()


def test_shifting_limits_the_time_step_like_a_diffusion():
    from sphcore.timestep import choose_dt
    h, cfl = 0.02, 0.25
    # Without a speed of sound (DFSPH) the flow-speed step is cfl h / |v| ...
    assert choose_dt("adaptive", 1.0, cfl, h, 0.0, 1.0, 0.0, 0.0) == (cfl * h / 1.0, "acoustic")
    # ... and shifting with A = 8 (drift -A h |v| grad C, diffusivity ~A h |v|) cuts it 8-fold
    assert choose_dt("adaptive", 1.0, cfl, h, 0.0, 1.0, 0.0, 0.0, 8.0) == (cfl * h / 8.0, "shifting")
    # With WCSPH's speed of sound (c0 = 10 U) the acoustic limit stays the smaller one at A = 8
    assert choose_dt("adaptive", 1.0, cfl, h, 10.0, 1.0, 0.0, 0.0, 8.0)[1] == "acoustic"
    # A fluid at rest has no shifting limit
    assert choose_dt("adaptive", 1.0, cfl, h, 0.0, 0.0, 0.0, 0.0, 8.0) == (1.0, "max")
