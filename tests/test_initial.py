"""Particles from a scene's blocks. A large block is filled in slabs of whole lattice layers on every
core (initial.fill_blocks, for the set-up of hundreds of millions of particles); the slabs must give
the very particles of one pass, in the same order (the ids follow the order, and every peer of a run
generates the scene itself)."""
import numpy as np
import pytest

from conftest import scene, scene_dict
from sphcore.boundaries import build_walls
from sphcore.choices import KERNELS
from sphcore.initial import _slabs, generate_particles

ONE_PASS = 10**12  # slab_points: no block is split


def _rotated_container(dim):
    return scene_dict(
        scene={"name": "rotated", "dim": dim}, particles={"spacing": 0.02},
        fluid={"blocks": [{"min": [-0.15, -0.1, -0.15][:dim], "max": [0.15, 0.05, 0.15][:dim], "frame": "container",
                           "clip": True, "velocity": [0.3, 0.0, -0.2][:dim]}]},
        domain={"container": "box", "center": [0.0, 0.0, 0.0][:dim], "size": [0.4, 0.3, 0.4][:dim],
                "rotation": [10.0, 25.0, -15.0] if dim == 3 else [0.0, 0.0, 20.0], "scale": 1.2},
        forces={"gravity": [0.0, -9.81, 0.0][:dim]})


CASES = {
    "3D box against walls": lambda: scene("dam_break"),
    "2D (slabs of y layers)": lambda: scene("dam_break_2d"),
    "an obstacle carved": lambda: scene("obstacle"),
    "a mesh obstacle carved": lambda: scene("mesh_obstacle"),
    "a sphere overlapping an earlier box": lambda: scene("tiny", "fluid.blocks[1].center=[0.075, 0.03, 0.075]"),
    "a rotated, scaled container, clipped": lambda: _rotated_container(3),
    "the same in 2D": lambda: _rotated_container(2),
}


@pytest.mark.fast
@pytest.mark.parametrize("case", CASES)
def test_slabs_give_the_particles_of_one_pass(case):
    # Given a scene whose blocks span many lattice layers
    sc = CASES[case]()
    dx = sc.particles.spacing
    walls = build_walls(sc, KERNELS[sc.sph.kernel], sc.sph.support * dx, np.float64)
    slab_points = 20
    assert max(len(_slabs(b, sc.dim, dx, slab_points)) for b in sc.fluid.blocks) >= 4
    # When its blocks are filled in one pass and in slabs of about 20 points
    one = generate_particles(sc, walls, ONE_PASS)
    slabs = generate_particles(sc, walls, slab_points)
    # Then the ids, positions and velocities are the same, bit for bit
    for name, a, b in zip(("id", "x", "v"), one, slabs):
        assert a.shape == b.shape and np.array_equal(a, b), name


@pytest.mark.fast
def test_slabs_cover_every_layer_once():
    sc = scene("dam_break")
    block = sc.fluid.blocks[0]
    layers = round((block.max[2] - block.min[2]) / sc.particles.spacing)
    for points in (1, 100, 5000, ONE_PASS):
        slabs = _slabs(block, 3, sc.particles.spacing, points)
        if slabs == [None]:
            continue
        assert slabs[0][0] == 0 and slabs[-1][1] == layers
        assert all(a[1] == b[0] and a[1] > a[0] for a, b in zip(slabs, slabs[1:]))
