"""Density by the continuity equation with delta-SPH diffusion (sph.density = "continuity",
sphcore/physics/continuity.py): the rate is the time derivative of the summation density, the
diffusion leaves a hydrostatic column alone, a tank settles to a smooth pressure field, two peers
give the same bits as one process, the density survives a checkpoint, and DFSPH refuses it."""
import numpy as np
import pytest

from sphcore import checkpoint, stages
from sphcore.scene import SceneError
from sphcore.solver import Simulation

from conftest import one_process_and_two_peers, scene

CONTINUITY = ("sph.density='continuity'",)


def _by_id(sim, field):
    s = sim.state
    n = s.n_owned
    order = np.argsort(s.id[:n])
    return field[:n][order]


def test_rate_is_the_time_derivative_of_the_summation_density():
    # Given a tank whose particles sit off their lattice and move with a smooth velocity field
    summ = Simulation(scene("hydrostatic_2d", "particles.spacing=0.05", "sph.density='summation'"), "f64")
    cont = Simulation(scene("hydrostatic_2d", "particles.spacing=0.05", "sph.delta=0", *CONTINUITY), "f64")
    n = summ.state.n_owned
    so, co = np.argsort(summ.state.id[:n]), np.argsort(cont.state.id[:n])  # rows of the same ids
    rng = np.random.default_rng(1)
    x0 = summ.state.x[so].copy()
    x0[:, :2] += rng.uniform(-0.01, 0.01, (n, 2))
    vel = np.zeros((n, 3))
    vel[:, 0] = np.sin(3.0 * x0[:, 1]) + 0.3
    vel[:, 1] = np.cos(2.0 * x0[:, 0]) - 0.2
    cont.state.x[co] = x0
    cont.state.v[co] = vel
    # When D rho/Dt comes from the continuity equation (walls included): the density stage advances
    # the carried density by dt_prev D rho/Dt (without storing it: commit=False)
    cont._neighbours()
    cont.engine.run(stages.DENSITY, prm=cont.prm, dt_prev=cont.dtype.type(cont.dt_prev), commit=True)  # a fresh run: the carried density starts from the sum
    carried = cont.state.extra["density"][:n].copy()
    cont.dt_prev = 1e-3
    cont.engine.run(stages.DENSITY, prm=cont.prm, dt_prev=cont.dtype.type(cont.dt_prev), commit=False)
    assert np.array_equal(cont.state.extra["density"][:n], carried)
    rate = _by_id(cont, (cont.state.rho[:n] - carried) / cont.dt_prev)

    # ... and from central differences of the summation density along the same velocities
    def summed(eps):
        s = summ.state
        s.x[np.argsort(s.id[:n])] = x0 + eps * vel
        summ._neighbours()
        summ.engine.run(stages.DENSITY, prm=summ.prm, dt_prev=summ.dtype.type(summ.dt_prev), commit=True)
        return _by_id(summ, summ.state.rho), _by_id(summ, summ.engine.scratch.fill)
    eps = 1e-6
    (rho_plus, fill_plus), (rho_minus, fill_minus) = summed(eps), summed(-eps)
    fd = (rho_plus - rho_minus) / (2 * eps)
    # Then they agree up to the gradient's calibration (sum_j V_j x_ji grad W_ij = -I on the lattice,
    # boundaries.lattice_gradient_moment), next to the walls (their share rho0 Phi(d)) as well as
    # inside, wherever the wall fill fraction theta is 1 (the rate holds theta fixed within a step)
    from sphcore.boundaries import lattice_gradient_moment
    moment = lattice_gradient_moment(cont.kernel, 2, cont.H, 0.05)
    full = (fill_plus == 1.0) & (fill_minus == 1.0)
    near_wall = np.minimum(np.minimum(x0[:, 0], 0.5 - x0[:, 0]), x0[:, 1]) < 0.5 * cont.H
    assert full.sum() > 0.6 * n and (full & near_wall).sum() >= 10
    assert np.max(np.abs(rate - fd / moment)[full]) < 0.02 * np.max(np.abs(fd))
    assert np.max(np.abs(fd)[full & near_wall]) > 1e3  # the walls' share dominates there


def test_the_carried_density_never_falls_below_the_particles_own_kernel_share():
    # Given a tank run with continuity density, one particle's carried density near zero (spray
    # integrates its density down: docs/VALIDATION.md, the MARIN section) and every particle moving
    # away from it (a divergent flow: D rho / Dt < 0 there)
    sim = Simulation(scene("hydrostatic_2d", "particles.spacing=0.05", "sph.delta=0", *CONTINUITY), "f64")
    sim._neighbours()
    sim.engine.run(stages.DENSITY, prm=sim.prm, dt_prev=sim.dtype.type(0.0), commit=True)  # starts at rho0
    s = sim.state
    n = s.n_owned
    i = int(np.argmin(np.linalg.norm(s.x[:n, :2] - [0.25, 0.2], axis=1)))  # inside the tank
    s.extra["density"][i] = 1.0  # kg/m^3
    s.v[:n] = 50.0 * (s.x[:n] - s.x[i])
    # When the density stage advances the carried density over a step
    sim.engine.run(stages.DENSITY, prm=sim.prm, dt_prev=sim.dtype.type(1e-3), commit=True)
    # Then it stops at the particle's own kernel share m_i W(0), the least density a kernel sum gives
    # (without the floor: 1 + 1e-3 D rho / Dt, below zero), and no particle is below its own
    floor = s.m[:n] * sim.prm.w0
    assert s.extra["density"][i] == floor[i] and s.rho[i] == floor[i]
    assert 20.0 < floor[i] < 500.0
    assert np.all(s.extra["density"][:n] >= floor)


def _column(correction):
    """max |delta-SPH drho| of a tank at rest whose carried density follows the hydrostatic profile
    of the linear EOS (dp/dy = -rho g, p = c0^2 (rho - rho0): rho0 exp(g (H - y) / c0^2)), with or
    without the hydrostatic correction."""
    sim = Simulation(scene("hydrostatic_2d", "particles.spacing=0.025", "sph.eos='linear'", "forces.ramp_time=0",
                           *CONTINUITY), "f64")
    sim.step()
    s = sim.state
    n = s.n_owned
    s.v[:n] = 0.0
    c0, g, H = sim.scene.sph.sound_speed, 9.81, 0.5
    s.extra["density"][:n] = 1000.0 * np.exp(g * (H - s.x[:n, 1]) / c0**2)
    sim._neighbours()
    prm = sim.prm if correction else sim.prm._replace(gravity_y=np.float64(0.0))  # rho^H uses gravity
    sim.engine.run(stages.DENSITY, prm=prm, dt_prev=sim.dtype.type(sim.dt_prev), commit=True)
    sim.engine.run(stages.DIFFUSION, prm=prm)
    return float(np.abs(sim.engine.scratch.drho[:n]).max())


def test_diffusion_leaves_a_hydrostatic_column_alone():
    # Given a column at rest with the hydrostatic density profile
    corrected, plain = _column(correction=True), _column(correction=False)
    # Then the plain Molteni-Colagrossi term moves density where the kernel is cut (free surface, floor):
    # (36 kg/m^3/s measured; about delta h c0 * 2 rho0 g dx / c0^2 / h^2)
    assert plain > 5.0
    # While with the hydrostatic correction nothing diffuses anywhere, surface and floor included
    # (what is left is the pair-mean linearisation, second order in g dx / c0^2 ~ 2.5e-4)
    assert corrected < 1e-4 * plain


@pytest.fixture(scope="module")
def settled_tank():
    sim = Simulation(scene("hydrostatic_2d", "particles.spacing=0.025", *CONTINUITY), "f64")
    while sim.t < 1.5:
        sim.step(dt_cap=1.5 - sim.t)
    sim.refresh()
    return sim


def test_tank_settles_to_a_smooth_hydrostatic_pressure(settled_tank):
    sim = settled_tank
    s = sim.state
    n = s.n_owned
    y, p = s.x[:n, 1], s.p[:n]
    H = float(np.max(y)) + 0.5 * 0.025
    below = y < H - 3 * 0.025
    err = np.abs(p - 1000.0 * 9.81 * (H - y))[below] / (1000.0 * 9.81 * H)
    assert err.max() < 0.05  # summation density: 13-19 % (docs/VALIDATION.md)


def test_two_peers_give_the_same_bits_as_one_process():
    # the carried density migrates with its particle; ghosts' densities feed the diffusion
    one_process_and_two_peers(scene("dam_break", "particles.spacing=0.04", "time.dt=0.0005", *CONTINUITY))


def test_density_survives_a_checkpoint(tmp_path):
    sc = scene("hydrostatic_2d", "particles.spacing=0.05", *CONTINUITY)
    sim = Simulation(sc, "f64")
    for _ in range(30):
        sim.step()
    parts = [checkpoint.write_part(tmp_path, sim.step_index, 0, sim)]
    checkpoint.commit(tmp_path, sim.step_index, checkpoint.sim_info(sim), {}, parts)
    fresh = Simulation(sc, "f64")
    checkpoint.restore(fresh, checkpoint.load(tmp_path))
    for _ in range(10):
        sim.step()
        fresh.step()
    assert np.array_equal(_by_id(sim, sim.state.extra["density"]), _by_id(fresh, fresh.state.extra["density"]))
    assert np.array_equal(_by_id(sim, sim.state.x), _by_id(fresh, fresh.state.x))


def test_dfsph_refuses_continuity_density():
    with pytest.raises(SceneError, match="sph.density = 'continuity'"):
        scene("hydrostatic_2d", "sph.solver='dfsph'", *CONTINUITY)
