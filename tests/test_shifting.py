"""Particle shifting (physics/shifting.py): no shift on an ordered lattice, less disorder on a
disordered one, nothing along a wall's normal or in the free-surface layer, and nothing at all when
it is off."""
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


def test_no_shift_along_a_wall_normal_or_in_the_surface_layer():
    sc = load_scene("configs/hydrostatic_2d.toml", ["particles.spacing=0.05", "terms.shifting=2.0"])
    sim = Simulation(sc, "f64")
    rng = np.random.default_rng(3)
    s = sim.state
    x = s.x + rng.uniform(-0.1, 0.1, s.x.shape) * 0.05 * np.array([1, 1, 0])
    sim.state = ParticleState.create(s.id, x, s.v, s.m, sim.dtype, extra=s.extra)
    dv = _drift(sim, np.tile([1.0, 1.0, 0.0], (sim.n_particles, 1)))
    s = sim.state
    n = s.n_owned
    H = sim.H
    lo, hi = sim.walls.lo, sim.walls.hi
    near_floor = s.x[:n, 1] - lo[1] < H
    near_side = (s.x[:n, 0] - lo[0] < H) | (hi[0] - s.x[:n, 0] < H)
    assert np.count_nonzero(near_floor) > 5 and np.count_nonzero(near_side) > 5
    assert np.all(dv[near_floor, 1] == 0.0) and np.all(dv[near_side, 0] == 0.0)
    top = s.x[:n, 1] > np.max(s.x[:n, 1]) - 0.5 * 0.05
    assert np.all(dv[top] == 0.0)  # the top layer is in the free-surface layer
    assert np.count_nonzero(dv) > 0  # the rest of the disordered tank is shifted


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
