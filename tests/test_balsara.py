"""Balsara's switch on the artificial viscosity (sph.viscosity_switch, physics/balsara.py)."""
import numpy as np
import pytest

from sphcore.scene import SceneError, scene_from_dict
from sphcore.solver import Simulation

pytestmark = pytest.mark.fast

SPACING = 0.02
SIDE = 0.4  # a 20 x 20 block: its middle is more than a support radius from the free edge


def block_scene(switch="balsara", **sph):
    return scene_from_dict({
        "scene": {"name": "block", "dim": 2},
        "particles": {"spacing": SPACING},
        "fluid": {"blocks": [{"min": [0.0, 0.0], "max": [SIDE, SIDE]}]},
        "sph": {"sound_speed": 10.0, "clamp_negative_pressure": False, "viscosity": "artificial", "alpha": 0.1,
                "viscosity_switch": switch, **sph},
        "forces": {"gravity": [0.0, 0.0]},
        "time": {"mode": "fixed", "dt": 1e-4},
        "domain": {"container": "none", "bounds_min": [-0.5, -0.5], "bounds_max": [0.9, 0.9]},
    })


def with_velocity(sim, field):
    """Set v = field(x, y) and recompute the step's fields and accelerations at rest positions."""
    s = sim.state
    s.v[:, :2] = field(s.x[:, 0], s.x[:, 1])
    sim.refresh()
    return s


def middle(s, margin=0.1):
    """The owned rows farther than ``margin`` (> H = 0.046 m) from the block's free edge."""
    x, y = s.x[:s.n_owned, 0], s.x[:s.n_owned, 1]
    return (x > margin) & (x < SIDE - margin) & (y > margin) & (y < SIDE - margin)


SHEAR = lambda x, y: np.stack([5.0 * (y - SIDE / 2), 0.0 * x], axis=1)          # curl only: du/dy = 5 1/s
EXPANSION = lambda x, y: np.stack([5.0 * (x - SIDE / 2), 5.0 * (y - SIDE / 2)], axis=1)  # divergence only
# a shear whose profile curves (a linear one has no viscous force: its Laplacian is 0)
WAVY_SHEAR = lambda x, y: np.stack([0.5 * np.sin(2.0 * np.pi * y / SIDE), 0.0 * x], axis=1)


def test_the_switch_is_near_one_in_compression_and_near_zero_in_shear():
    # Given a block of fluid in a uniform shear, and the same block expanding uniformly
    sim = Simulation(block_scene(), "f64")
    s = with_velocity(sim, SHEAR)
    f_shear = sim.engine.scratch.balsara[:s.n_owned][middle(s)].copy()
    s = with_velocity(sim, EXPANSION)
    f_expansion = sim.engine.scratch.balsara[:s.n_owned][middle(s)].copy()
    # Then f reads the shear as no compression and the expansion as all of it (the floor
    # 1e-4 c0 / h = 0.043 1/s against a divergence of 10 1/s keeps it a little under 1)
    assert f_shear.size > 50 and f_expansion.size == f_shear.size
    assert f_shear.max() < 1e-6, f_shear.max()
    assert f_expansion.min() > 0.99, f_expansion.min()
    # and at rest f is 0 (nothing to damp), not a division by zero
    s = with_velocity(sim, lambda x, y: np.zeros((x.size, 2)))
    assert np.all(sim.engine.scratch.balsara[:s.n_owned] == 0.0)


def viscous_part(switch, field):
    """The artificial viscosity's share of a in the block's middle: a(alpha) - a(alpha = 0)."""
    def a(alpha):
        sim = Simulation(block_scene(switch, alpha=alpha), "f64")
        s = with_velocity(sim, field)
        order = np.argsort(s.id[:s.n_owned])
        return s.a[:s.n_owned][order], middle(s)[order]
    with_alpha, rows = a(0.1)
    without, _ = a(0.0)
    return np.abs(with_alpha - without)[rows].max()


def test_the_switch_takes_the_viscosity_out_of_a_shear_and_keeps_it_in_compression():
    # Given the sheared and the expanding block, their viscous accelerations with and without the switch
    shear_on, shear_off = viscous_part("balsara", WAVY_SHEAR), viscous_part("none", WAVY_SHEAR)
    expansion_on, expansion_off = viscous_part("balsara", EXPANSION), viscous_part("none", EXPANSION)
    # Then without it the shear feels the artificial viscosity; with it, not
    assert shear_off > 1e-3, shear_off
    assert shear_on < 1e-6 * shear_off, (shear_on, shear_off)
    # (a uniform compression or expansion has v_ij . x_ij of one sign for every pair, so the
    # viscosity acts on none of its pairs or on all: this one expands, and none approaches)
    assert expansion_off == 0.0 and expansion_on == 0.0


def test_the_switch_keeps_the_viscosity_in_a_converging_flow():
    # Given the block's middle compressed along x at a rate that varies (2.8-3.9 1/s: a uniform one
    # has no viscous force), with no rotation
    converging = lambda x, y: np.stack([-0.5 * np.sin(np.pi * (x - SIDE / 2) / SIDE), 0.0 * y], axis=1)
    on, off = viscous_part("balsara", converging), viscous_part("none", converging)
    # Then the switch leaves nearly all of it (f > 0.97 on every pair of the middle's rows)
    assert off > 1e-3 and abs(on / off - 1.0) < 0.03, (on, off)


def test_no_switch_leaves_the_step_as_it_was():
    # Given one step with sph.viscosity_switch = "none" (the default)
    sim = Simulation(block_scene("none"), "f64")
    sim.step()
    # Then no balsara stage ran and its scratch is one row
    assert "balsara" not in sim.timers.samples
    assert sim.engine.scratch.balsara.shape == (1,)
    on = Simulation(block_scene(), "f64")
    on.step()
    assert "balsara" in on.timers.samples


@pytest.mark.parametrize("viscosity", ["none", "morris", "muller"])
def test_the_switch_needs_the_artificial_viscosity(viscosity):
    with pytest.raises(SceneError) as err:
        block_scene(viscosity=viscosity)
    message = str(err.value)
    assert "sph.viscosity_switch = 'balsara'" in message and f"sph.viscosity = {viscosity!r}" in message
    # and an unknown switch names the key and what is allowed
    with pytest.raises(SceneError) as err:
        block_scene(switch="monaghan")
    assert "viscosity_switch" in str(err.value) and "balsara" in str(err.value)


def test_peers_drop_a_ghost_f_outside_zero_to_one_and_stay_bitwise_equal():
    from conftest import scene
    from nodes.cluster import InProcessCluster
    # Given two in-process clusters with the switch, in one of which every peer sends, in steps 3 to
    # 5, a forged exchange 2 ahead of its genuine one: the right arrays and rows, finite, but an f
    # outside [0, 1] (a negative f would make the artificial viscosity push energy in)
    sc = scene("dam_break_2d", "particles.spacing=0.01", "sph.viscosity_switch='balsara'")
    calm = InProcessCluster(sc, 2, "f64", dims=(2, 1, 1))
    hit = InProcessCluster(sc, 2, "f64", dims=(2, 1, 1))

    def forging(rank, send, f):
        def send_first_a_forgery(dest, tag, arrays):
            step, phase = tag
            if phase == "fields" and 3 <= step <= 5:
                hit.network.deliver(dest, rank, tag, dict(arrays, balsara=np.full_like(arrays["balsara"], f)))
            send(dest, tag, arrays)
        return send_first_a_forgery

    for rank, (halo, f) in enumerate(zip(hit.halos, (-0.5, 2.0))):
        halo.transport.send = forging(rank, halo.transport.send, f)
    for _ in range(8):
        calm.step()
        hit.step()
    # Then each forgery was dropped for its range, and the result did not change
    for rank, halo in enumerate(hit.halos):
        assert halo.transport.drops == {str(1 - rank): {"range": 3}}, (rank, halo.transport.drops)
    assert all(h.transport.dropped == 0 for h in calm.halos)
    a, b = calm.final_arrays(), hit.final_arrays()
    for key in ("id", "x", "v", "rho"):
        assert np.array_equal(a[key], b[key]), key


def test_the_viewer_says_the_switch_is_on():
    from nodes.viewer import info_text
    assert "artificial, alpha = 0.1, Balsara's switch" in info_text(block_scene(), 400, 1)
    assert "Balsara" not in info_text(block_scene("none"), 400, 1)
