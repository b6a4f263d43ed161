"""Heavier checks at the shipped resolutions (pytest -m slow; minutes on 2 cores)."""
import numpy as np
import pytest

from sphcore.solver import Simulation

from conftest import scene, settled_pressure_profile

pytestmark = pytest.mark.slow


def test_hydrostatic_at_shipped_resolution():
    sim = Simulation(scene("hydrostatic_2d"), "f64")
    slope, surface = settled_pressure_profile(sim, 1.2, (0.05, 0.45), (0.03, 0.47))
    # measured 2026-11-22: slope -2.8 %, surface +2 mm; what remains is the SPH gradient error of the
    # settled (no longer cubic) particle arrangement at ~17 neighbours
    assert -slope == pytest.approx(1000.0 * 9.81, rel=0.04)
    assert surface == pytest.approx(0.5, abs=0.01)
    assert sim.leaks == 0


@pytest.mark.parametrize("precision", ["f32", "f64"])
def test_full_dam_break_to_0_6_s(precision):
    # The 49,152-particle dam break until the water has run up the far wall
    sim = Simulation(scene("dam_break"), precision)
    while sim.t < 0.6:
        sim.step()
    s = sim.state
    assert np.isfinite(s.x).all() and np.isfinite(s.v).all()
    assert sim.leaks == 0
    assert s.x[:, 0].max() > 1.5  # the front reached the far wall
    assert sim.max_compression < 0.2


def test_every_scene_runs_its_default_length():
    for name in ("dam_break_2d", "taylor_green_2d", "obstacle", "tiny"):
        sc = scene(name)
        sim = Simulation(sc, "f64")
        for _ in range(sc.time.steps):
            sim.step()
        assert sim.leaks == 0, name
        assert np.isfinite(sim.state.v).all(), name
