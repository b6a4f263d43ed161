"""The difference form of the pressure gradient (sph.pressure_gradient = "difference",
physics/pressure.py): a uniform pressure does not enter it in the bulk however disordered the
particles, the free surface's layer keeps the symmetric form, the tank stays at rest, N peers and a
resumed run give one process's bits, and the scene refuses what it cannot run."""
import numpy as np
import pytest

from sphcore import stages
from sphcore.physics.pressure import SURFACE_LAYER
from sphcore.scene import SceneError, load_scene
from sphcore.solver import Simulation
from sphcore.state import ParticleState

from conftest import CONFIGS
from test_floating import _one_two_peers_and_resumed

TG = CONFIGS / "taylor_green_2d.toml"
DIFFERENCE = ["sph.pressure_gradient='difference'", "terms.shifting=2.0"]


def _accelerations(sim, x, p):
    """The forces pass's a for positions x and a pressure p set on every row (after one refresh)."""
    s = sim.state
    sim.state = ParticleState.create(s.id, x, s.v, s.m, sim.dtype, extra=s.extra)
    sim.refresh()
    n = sim.state.n_owned
    sim.state.p[:] = p(sim.state.x)
    sim.engine.run(stages.FORCES, prm=sim.prm)
    order = np.argsort(sim.state.id[:n])
    return sim.state.a[:n][order].copy(), sim.state.x[:n][order].copy()


def _periodic_box(form):
    overrides = ["particles.spacing=0.05", "fluid.initial_flow='none'", "sph.viscosity='none'", "time.mode='fixed'",
                 "time.dt=1e-3", "terms.shifting=2.0", f"sph.pressure_gradient='{form}'"]
    return Simulation(load_scene(TG, overrides), "f64")


@pytest.mark.fast
def test_a_uniform_pressure_pushes_disordered_particles_only_in_the_symmetric_form():
    """A periodic box (no surface, no wall), its lattice jittered by 5 % of a spacing, every particle
    at 10 kPa: the symmetric form pushes them back towards the lattice with ~ p / (rho h) times the
    disorder; the difference form gives no acceleration at all."""
    sims = {form: _periodic_box(form) for form in ("symmetric", "difference")}
    x = sims["symmetric"].state.x[: sims["symmetric"].state.n_owned].copy()
    x[:, :2] += np.random.default_rng(7).uniform(-0.05, 0.05, (len(x), 2)) * 0.05
    largest = {form: np.max(np.abs(_accelerations(sim, x, lambda xs: np.full(len(xs), 1.0e4))[0]))
               for form, sim in sims.items()}
    assert largest["symmetric"] > 1.0  # m/s^2: p / (rho h) = 130 m/s^2 times the disorder (5.3 measured)
    assert largest["difference"] == 0.0


def _tank(form, spacing=0.05):
    overrides = [f"particles.spacing={spacing}", "terms.shifting=2.0", f"sph.pressure_gradient='{form}'"]
    return Simulation(load_scene(CONFIGS / "hydrostatic_2d.toml", overrides), "f64")


@pytest.mark.fast
def test_the_free_surface_layer_keeps_the_symmetric_form_and_the_bulk_the_difference_form():
    """The hydrostatic tank's lattice under rho0 g (H - y): the top row (concentration ~0.6, below
    SURFACE_LAYER) gets the symmetric form's acceleration to round-off; a row in the bulk away
    from the walls gets the difference form's, which differs from the symmetric one only where the
    symmetric form's zeroth-order part is not zero (on the lattice: nowhere in the bulk)."""
    assert SURFACE_LAYER[0] < SURFACE_LAYER[1] < 1.0
    out = {}
    for form in ("symmetric", "difference"):
        sim = _tank(form)
        x0 = sim.state.x[: sim.state.n_owned].copy()
        top = x0[:, 1].max()
        out[form], x = _accelerations(sim, x0, lambda xs: 1000.0 * 9.81 * np.maximum(top - xs[:, 1], 0.0))
    top_row = x[:, 1] > top - 1e-9
    assert np.count_nonzero(top_row) >= 8
    assert np.allclose(out["difference"][top_row], out["symmetric"][top_row], rtol=1e-12, atol=1e-12)
    # below the surface layer the two forms differ only by the lattice's round-off, not by the surface's term
    bulk = (x[:, 1] < top - 4 * 0.05) & (x[:, 1] > 4 * 0.05) & (np.abs(x[:, 0] - 0.25) < 0.1)
    assert np.count_nonzero(bulk) >= 4
    assert np.allclose(out["difference"][bulk], out["symmetric"][bulk], atol=1e-9)
    # and in the layer the zeroth-order term is what holds the top row up (it is not zero there)
    assert np.max(np.abs(out["symmetric"][top_row, 1] - out["symmetric"][bulk, 1].mean())) > 1.0


@pytest.mark.fast
def test_the_corrected_difference_form_balances_a_hydrostatic_pressure_exactly_however_disordered():
    """The hydrostatic tank's particles moved by up to 10 % of a spacing, at rest density, under
    rho0 g (H0 - y): below the free surface's layer every particle, by the floor and the side walls
    too (their virtual lattice is in the correction's moment), feels the pressure's push balance
    gravity to round-off (B^-1 makes the difference sum exact for a linear field); the symmetric form
    on the same particles misses it by a tenth of a metre per second squared or more."""
    out = {}
    for form in ("symmetric", "difference"):
        sim = _tank(form)
        x0 = sim.state.x[: sim.state.n_owned].copy()
        top = x0[:, 1].max()
        # (10 %: with 20 % a few bulk particles' concentration falls below SURFACE_LAYER[1], and they
        # take a share of the symmetric form, as a particle of the surface's layer does)
        x0[:, :2] += np.random.default_rng(11).uniform(-0.1, 0.1, (len(x0), 2)) * 0.05
        s = sim.state
        sim.state = ParticleState.create(s.id, x0, s.v, s.m, sim.dtype, extra=s.extra)
        sim.refresh()
        n = sim.state.n_owned
        sim.state.rho[:n] = 1000.0
        sim.state.p[:n] = 1000.0 * 9.81 * (top + 0.025 - sim.state.x[:n, 1])
        sim.engine.run(stages.FORCES, prm=sim.prm)
        order = np.argsort(sim.state.id[:n])
        out[form], x = sim.state.a[:n][order].copy(), sim.state.x[:n][order].copy()
    below = x[:, 1] < top - 4 * 0.05  # well below the surface layer (C >= 0.95 there)
    assert np.count_nonzero(below) > 40 and np.count_nonzero(below & (x[:, 1] < 0.05)) >= 8  # the floor's row
    assert np.abs(out["difference"][below]).max() < 1e-9
    assert np.abs(out["symmetric"][below]).max() > 0.1


def test_the_tank_stays_at_rest_in_the_difference_form():
    """Still water under gravity, 0.5 s (the gravity ramps in over 0.4 s): no flow beyond the
    start-up's settling, no particle above the surface (the layer's symmetric form holds it)."""
    sim = _tank("difference", spacing=0.025)
    top = sim.state.x[: sim.state.n_owned, 1].max()
    while sim.t < 0.5:
        sim.step()
    n = sim.state.n_owned
    assert np.max(np.linalg.norm(sim.state.v[:n], axis=1)) < 0.02  # m/s; sqrt(g H) = 2.2
    assert sim.state.x[:n, 1].max() < top + 0.25 * 0.025


def test_two_peers_and_a_resumed_run_reproduce_one_process_bitwise(tmp_path):
    """The difference form's extra sums (C_i, the zeroth-order part) walk the same fixed order of
    neighbours on every peer: the settling cylinder (its force the traction's, which the difference
    form needs) on one process, two peers and resumed."""
    scene = load_scene(CONFIGS / "settling_cylinder_2d.toml",
                       ["particles.spacing=1e-3", *DIFFERENCE, "sph.body_force='traction'"])
    one, cluster, resumed, _ = _one_two_peers_and_resumed(tmp_path, scene, steps=30)
    reference = one.final_arrays()
    for got in (cluster.final_arrays(), resumed.final_arrays()):
        for key in ("id", "x", "v", "rho"):
            assert np.array_equal(reference[key], got[key]), key
    body = one.model.walls.bodies[0]
    assert all(np.array_equal(sim.model.walls.bodies[0].x, body.x) for sim in (*cluster.peers, resumed))
    assert body.v[1] < 0.0  # it settles


@pytest.mark.fast
@pytest.mark.parametrize("overrides, match", [
    (["sph.solver='dfsph'", "sph.density='summation'", "terms.shifting=1.0"], "sph.solver = 'dfsph'"),
    (["terms.shifting=0.0"], "needs terms.shifting > 0"),
    (["sph.pressure_gradient='antisymmetric'"], "pressure_gradient"),
])
def test_the_scene_refuses_what_the_difference_form_cannot_run(overrides, match):
    with pytest.raises(SceneError, match=match):
        load_scene(CONFIGS / "hydrostatic_2d.toml", ["sph.pressure_gradient='difference'", *overrides])
