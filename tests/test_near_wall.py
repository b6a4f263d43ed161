"""The near-wall cell flags (boundaries.near_wall_cells): the density and force passes (the walls'
density share and push, the carried density's wall rate, the Morris no-slip wall) and shifting
evaluate the walls' terms only for particles in a flagged cell, since elsewhere they are zero. A missing flag would
silently drop a wall's push, so the flags are checked against the walls themselves, and a run with
them against a run with every cell flagged, bit for bit."""
import numpy as np
import pytest
from numba import njit

from sphcore.boundaries import near_wall_cells
from sphcore.physics.walls import signed_distance
from sphcore.solver import Simulation

from conftest import scene

pytestmark = pytest.mark.fast

SCENES = {  # the wall primitives: planes, obstacles, a mesh, turning cylinders (moving: every cell flagged)
    "dam_break": ("particles.spacing=0.05",),
    "obstacle": (),
    "mesh_obstacle": (),
    "circular_couette_2d": (),
    "hydrostatic_2d": (),
}


@njit
def distances(kinds, data, points, H, reached):
    """reached[k]: point k lies within H of a wall (its signed distance under H, as the passes test it)."""
    for k in range(points.shape[0]):
        for q in range(kinds.shape[0]):
            if signed_distance(kinds[q], data[q], points[k, 0], points[k, 1], points[k, 2])[0] < H:
                reached[k] = True
                break


@pytest.mark.parametrize("name", sorted(SCENES))
def test_every_point_a_wall_reaches_lies_in_a_flagged_cell(name):
    sim = Simulation(scene(name, *SCENES[name]), "f32")  # the precision the run-equality test compiles
    walls, grid = sim.model.walls, sim.grid
    H = float(np.sqrt(grid.H2))
    # points all over the grid's box, and the particles themselves
    rng = np.random.default_rng(3)
    lo = grid.origin.astype(np.float64)
    hi = lo + grid.ncell * grid.cell.astype(np.float64)
    dim = 2 if grid.ncell[2] == 1 else 3
    points = rng.uniform(lo, hi, size=(200_000, 3))
    if dim == 2:
        points[:, 2] = 0.0
    points = np.concatenate([points, sim.state.x[:sim.state.n_owned].astype(np.float64)])
    reached = np.zeros(len(points), dtype=bool)
    distances(walls.kind, walls.data.astype(np.float64), points, H, reached)
    cells = grid.cells_of(points)
    index = (cells[:, 2] * grid.ncell[1] + cells[:, 1]) * grid.ncell[0] + cells[:, 0]
    flagged = walls.near[index] != 0
    assert reached.any() and not reached.all(), name
    missed = reached & ~flagged
    assert not missed.any(), f"{name}: {int(missed.sum())} points within H of a wall in unflagged cells"
    # and, where no wall moves, the flags do skip most of the far cells (else they would be worth nothing)
    if not walls.moves:
        assert flagged[~reached].mean() < 0.9, name


# every term the flags gate: the walls' density share and push (all), the carried density's wall rate
# (continuity), the DFSPH factor's wall gradient, the Morris no-slip wall, shifting's wall share
RUNS = {
    "dam_break": ("dam_break", *SCENES["dam_break"]),
    "obstacle": ("obstacle",),
    "mesh_obstacle": ("mesh_obstacle",),
    "continuity": ("dam_break_pressure_2d", "particles.spacing=0.03"),
    "dfsph": ("dam_break_2d", "particles.spacing=0.02", "sph.solver='dfsph'"),
    "morris": ("poiseuille_2d",),
    "shifting": ("dam_break_2d", "particles.spacing=0.02", "terms.shifting=1.0"),
}


@pytest.mark.parametrize("name", sorted(RUNS))
def test_a_run_with_the_flags_equals_one_that_evaluates_every_wall(name):
    a = Simulation(scene(*RUNS[name]), "f32")
    b = Simulation(scene(*RUNS[name]), "f32")
    b.model.walls.near = np.ones_like(b.model.walls.near)
    cells = a.grid.cells_of(a.state.x[:a.state.n_owned])
    index = (cells[:, 2] * a.grid.ncell[1] + cells[:, 1]) * a.grid.ncell[0] + cells[:, 0]
    assert (a.model.walls.near[index] == 0).sum() > 0.1 * len(index)  # a tenth of the particles or more skip
    for _ in range(20):
        a.step()
        b.step()
    for f in ("x", "v", "rho", "p", "a"):
        assert np.array_equal(getattr(a.state, f), getattr(b.state, f)), f


def test_moving_walls_flag_every_cell():
    sim = Simulation(scene("wave_maker_2d", "particles.spacing=0.01"), "f64")
    assert sim.model.walls.moves and sim.model.walls.near.all()


def test_particles_outside_the_grid_are_binned_in_flagged_cells():
    sim = Simulation(scene("dam_break", *SCENES["dam_break"]), "f64")
    grid = sim.grid
    near = sim.model.walls.near.reshape(grid.ncell[::-1])  # (z, y, x)
    assert near[0].all() and near[-1].all() and near[:, 0].all() and near[:, -1].all()
    assert near[:, :, 0].all() and near[:, :, -1].all()
