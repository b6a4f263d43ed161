"""sph.background_pressure (physics/eos.py): a constant p_b added to the EOS pressure of a closed
WCSPH flow, refused where a free surface or a solved pressure has no use for it."""
import numpy as np
import pytest

from sphcore.scene import SceneError
from sphcore.solver import Simulation

from conftest import scene

pytestmark = pytest.mark.fast

CAVITY = ("particles.spacing=0.05",)  # 20 across: 400 particles


def test_the_pressure_is_the_eos_pressure_plus_p_b():
    # Given the lid-driven cavity (linear EOS, negative pressures kept) with and without p_b = 2 kPa
    plain = Simulation(scene("cavity_2d", *CAVITY), "f64")
    raised = Simulation(scene("cavity_2d", *CAVITY, "sph.background_pressure=2000"), "f64")
    assert raised.prm.p_background == 2000.0 and plain.prm.p_background == 0.0
    # When both compute their fields at the same positions
    plain.refresh()
    raised.refresh()
    # Then the densities are the same and every pressure is higher by p_b
    n = plain.state.n_owned
    assert np.array_equal(plain.state.id[:n], raised.state.id[:n])
    assert np.array_equal(plain.state.rho[:n], raised.state.rho[:n])
    assert np.allclose(raised.state.p[:n] - plain.state.p[:n], 2000.0, rtol=0.0, atol=1e-9)
    # and on the cavity's lattice at rest (a uniform density) p_b pushes nobody: the accelerations of
    # the particles farther than H from every wall are the same with and without it
    x = plain.state.x[:n]
    H = plain.model.H
    inner = np.all((x[:, :2] > H) & (x[:, :2] < 1.0 - H), axis=1)
    assert inner.sum() > 50
    one_neighbour = 2000.0 / 1000.0 / 0.05  # p_b / (rho0 dx): one neighbour's share, ~40 m/s^2
    assert np.max(np.abs(raised.state.a[:n][inner] - plain.state.a[:n][inner])) < 1e-8 * one_neighbour


@pytest.mark.parametrize("name,overrides,fragment", [
    ("cavity_2d", CAVITY + ("sph.clamp_negative_pressure=true",), "sph.clamp_negative_pressure = true (a free surface)"),
    ("hydrostatic_2d", ("sph.clamp_negative_pressure=false", "sph.solver='dfsph'", "sph.density='summation'",
                        "time.integrator='symplectic_euler'"), "sph.solver = 'dfsph'"),
])
def test_a_background_pressure_is_refused_where_it_has_no_use(name, overrides, fragment):
    with pytest.raises(SceneError) as err:
        scene(name, "sph.background_pressure=2000", *overrides)
    assert "sph.background_pressure = 2000" in str(err.value) and fragment in str(err.value)


def test_a_free_surface_scene_refuses_it():
    with pytest.raises(SceneError, match="sph.background_pressure = 100.0: only for a closed WCSPH flow"):
        scene("dam_break_2d", "sph.background_pressure=100")
