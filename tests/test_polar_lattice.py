"""A sphere block filled on a polar lattice (fluid.blocks[].lattice = "polar"): rings in 2D, shells in
3D, one spacing apart, each point holding about one spacing^dim of volume; circular walls about the
same centre then sit half a spacing from the nearest ring, as a flat wall does from a cartesian
lattice (a cartesian lattice clipped by a circle leaves gaps of 0.5-1.5 spacings along it, which made
the circular Couette flow slip: docs/VALIDATION.md)."""
import math

import numpy as np
import pytest

from conftest import one_process_and_two_peers, scene
from sphcore.initial import _polar_points
from sphcore.scene import SceneError
from sphcore.solver import Simulation


@pytest.mark.fast
def test_rings_hold_the_disc_area_one_spacing_apart():
    dx, R = 0.01, 0.2
    pts = _polar_points((0.0, 0.0, 0.0), R, 2, dx)
    assert len(pts) == pytest.approx(math.pi * R * R / dx**2, rel=0.01)
    r = np.hypot(pts[:, 0], pts[:, 1])
    radii = np.unique(np.round(r / dx - 0.5, 9))
    assert np.array_equal(radii, np.arange(20))  # r_k = (k + 1/2) dx, k = 0 .. R / dx - 1
    assert r.max() == pytest.approx(R - 0.5 * dx)  # half a spacing inside the block's circle
    for k in range(1, 20):  # along each ring the points are a spacing apart
        ring = pts[np.isclose(r, (k + 0.5) * dx)]
        theta = np.sort(np.arctan2(ring[:, 1], ring[:, 0]))
        step = np.diff(np.append(theta, theta[0] + 2 * math.pi)) * (k + 0.5) * dx
        assert np.allclose(step, step[0]) and step[0] == pytest.approx(dx, rel=0.05)


@pytest.mark.fast
def test_shells_hold_the_ball_volume_with_a_spacing_between_neighbours():
    dx, R = 0.02, 0.2
    pts = _polar_points((1.0, 2.0, 3.0), R, 3, dx)
    assert len(pts) == pytest.approx(4.0 / 3.0 * math.pi * R**3 / dx**3, rel=0.02)
    rel = pts - np.array([1.0, 2.0, 3.0])
    assert np.linalg.norm(rel, axis=1).max() == pytest.approx(R - 0.5 * dx)
    outer = rel[np.isclose(np.linalg.norm(rel, axis=1), R - 0.5 * dx)]
    d = np.linalg.norm(outer[:, None] - outer[None], axis=2) + np.eye(len(outer)) * 1e9
    assert 0.8 * dx < np.median(d.min(axis=1)) < 1.2 * dx  # the Fibonacci spiral's nearest neighbour


@pytest.mark.fast
def test_a_polar_box_is_refused_with_the_key():
    with pytest.raises(SceneError, match=r"fluid.blocks\[0\].lattice = 'polar': fills a sphere block"):
        scene("dam_break_2d", "fluid.blocks[0].lattice='polar'")


def test_the_annulus_starts_half_a_spacing_from_both_walls_and_peers_keep_the_bits():
    sc = scene("circular_couette_2d", "particles.spacing=1e-4")
    sim = Simulation(sc, "f64")
    r = np.hypot(sim.state.x[:, 0], sim.state.x[:, 1])
    dx = 1e-4
    assert (r.min() - 1e-3) / dx == pytest.approx(0.5) and (2e-3 - r.max()) / dx == pytest.approx(0.5)
    assert sim.n_particles == pytest.approx(math.pi * (2e-3**2 - 1e-3**2) / dx**2, rel=0.01)
    one_process_and_two_peers(sc, steps=20)
