"""The cell walk (run.neighbours = "walk"): every neighbour pass walks the 27 cells around its row
instead of reading a neighbour list. It must visit exactly the list's neighbours in the list's order,
and a run with it must keep the guarantees of a run with lists (N peers == one process, bitwise)."""
from typing import NamedTuple

import numpy as np
import pytest
from numba import njit

from nodes.cluster import InProcessCluster
from sphcore.grid import CELL_WALK, Grid
from sphcore.physics.pairs import candidate, span_rows, spans, walk_start
from sphcore.solver import Simulation
from sphcore.state import ParticleState

from conftest import scene

pytestmark = pytest.mark.fast


class Periods(NamedTuple):
    """The fields of Params that pairs.candidate reads."""
    period_x: float
    period_y: float
    period_z: float


@njit
def walked(x, n_query, cells, cell_begin, cell_end, prm, out, found):
    """The rows the walk accepts for rows 0..n_query-1, in the order it visits them (the same loop
    every neighbour pass runs, pairs.py)."""
    for i in range(n_query):
        c = 0
        home = walk_start(CELL_WALK, x, i, cells)
        for span in range(spans(CELL_WALK, cells)):
            k_lo, k_hi = span_rows(CELL_WALK, span, home, i, found, cells, cell_begin, cell_end)
            for k in range(k_lo, k_hi):
                j, dx, dy, dz, r2, inside = candidate(CELL_WALK, 1, x, out, i, k, prm, cells)
                if inside:
                    out[i, c] = j
                    c += 1
        found[i] = c


def check_walk_equals_lists(grid, state):
    """Bin the state (sort + lists), walk it, and compare every owned row's neighbours in order."""
    grid.bin(state)
    n = state.n_owned
    out = np.full((n, max(grid.capacity, 1)), -1, dtype=np.int64)
    found = np.zeros(n, dtype=np.int64)
    walked(state.x, n, grid.cells, grid.cell_begin, grid.cell_end, Periods(*grid.period), out, found)
    assert np.array_equal(found, grid.counts[:n])
    for i in range(n):
        assert np.array_equal(out[i, :found[i]], grid.nbr[i, :found[i]]), f"row {i}"
    return int(found.sum())


def random_state(x, rng, n_owned=None):
    n = len(x)
    s = ParticleState.create(rng.permutation(n).astype(np.int64), x, np.zeros((n, 3)), np.ones(n), np.float64)
    if n_owned is not None:
        s.n_owned = n_owned
    return s


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("reach", [1, 2])
def test_walk_visits_the_list_in_order_random_box(dim, reach):
    rng = np.random.default_rng(11)
    lo, hi = np.zeros(3), np.array([1.3, 0.7, 0.45 if dim == 3 else 0.0])
    H = 0.13
    grid = Grid(lo - H, hi + H, H, (False, False, False), np.float64, reach=reach)
    assert check_walk_equals_lists(grid, random_state(rng.uniform(lo, hi, size=(700, 3)), rng)) > 0


@pytest.mark.parametrize("reach", [1, 2])
def test_walk_visits_the_list_in_order_on_cell_faces_and_corners(reach):
    rng = np.random.default_rng(12)
    H = 0.1
    g = np.arange(0, 6) * H
    x = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    x = np.concatenate([x, x[:50] + np.array([0.5 * H, 0.0, 0.0])])
    grid = Grid(np.zeros(3), np.full(3, 5 * H), H, (False, False, False), np.float64, reach=reach)
    check_walk_equals_lists(grid, random_state(x, rng))


@pytest.mark.parametrize("periodic", [(True, False, False), (True, True, True)])
@pytest.mark.parametrize("reach", [1, 2])
def test_walk_visits_the_list_in_order_on_periodic_axes(periodic, reach):
    rng = np.random.default_rng(13)
    L = np.array([1.0, 0.8, 0.6])
    H = 0.15
    lo, hi = np.zeros(3), L.copy()
    for d in range(3):
        if not periodic[d]:
            lo[d] -= H
            hi[d] += H
    grid = Grid(lo, hi, H, periodic, np.float64, reach=reach)
    check_walk_equals_lists(grid, random_state(rng.uniform(0, L, size=(500, 3)), rng))


@pytest.mark.parametrize("reach", [1, 2])
def test_walk_visits_the_list_in_order_with_ghost_rows(reach):
    # Given a peer's rows: owned particles in the left half, ghosts (a slab beyond the cut) after them,
    # so the owned and ghost cells are not contiguous in memory (the list builder's other path)
    rng = np.random.default_rng(14)
    H = 0.15
    own = rng.uniform([0, 0, 0], [0.6, 0.9, 0.6], size=(500, 3))
    ghosts = rng.uniform([0.6, 0, 0], [0.6 + H, 0.9, 0.6], size=(120, 3))
    grid = Grid(np.zeros(3) - H, np.array([1.2, 0.9, 0.6]) + H, H, (False, False, False), np.float64, reach=reach)
    # the cut lies on a cell face: 0.6 - (-0.15) = 0.75 = 5 cells
    state = random_state(np.concatenate([own, ghosts]), rng, n_owned=500)
    check_walk_equals_lists(grid, state)


def test_a_walking_run_counts_the_neighbours_the_lists_hold():
    # Given the dam break advanced a few steps with lists, and the same particles in a walking run on
    # the same grid (by default the walk has cells of H and lists cells of H / 2: scene.grid_reach)
    lists = Simulation(scene("dam_break", "particles.spacing=0.05", "run.cells_per_support=2",
                                 "run.neighbour_skin=0"), "f64")  # a list a step, as the walk's
    for _ in range(5):
        lists.step()
    walk = Simulation(scene("dam_break", "particles.spacing=0.05", "run.neighbours='walk'",
                            "run.cells_per_support=2"), "f64")
    walk.state = ParticleState.create(*(getattr(lists.state, f)[:lists.state.n_owned].copy()
                                        for f in ("id", "x", "v", "m")), np.float64)
    lists.refresh()
    walk.refresh()
    n = lists.state.n_owned
    # Then the density pass of the walk counts exactly the list's neighbours, and no list was built
    assert walk.neighbours_sum == int(lists.grid.counts[:n].sum()) == lists.neighbours_sum > 0
    assert walk.neighbours_max == int(lists.grid.counts[:n].max()) == lists.neighbours_max
    assert walk.grid.nbr.shape[0] == 0
    # and the fields agree to round-off (the reassociation licence rounds the two loop shapes differently)
    for f in ("rho", "p", "a"):
        a, b = getattr(lists.state, f)[:n], getattr(walk.state, f)[:n]
        assert np.array_equal(lists.state.id[:n], walk.state.id[:n])
        assert np.max(np.abs(a - b)) <= 1e-11 * max(np.max(np.abs(a)), 1.0), f


@pytest.mark.parametrize("solver", ["wcsph", "dfsph"])
def test_walking_peers_equal_one_walking_process_bitwise(solver):
    # Given the dam break with the cell walk, XSPH, vorticity confinement, surface tension and Balsara's
    # switch (WCSPH) or the DFSPH solver (its factor, source and update passes walk too)
    extra = (["terms.vorticity_confinement=0.05", "terms.xsph=0.3", "terms.surface_tension=0.02",
              "sph.viscosity_switch='balsara'"]
             if solver == "wcsph" else ["sph.solver='dfsph'", "time.dt=0.004"])
    sc = scene("dam_break", "particles.spacing=0.05", "run.neighbours='walk'", *extra)
    steps = 40
    single = Simulation(sc, "f64")
    assert single.model.neighbours == "walk"
    for _ in range(steps):
        single.step()
    reference = single.final_arrays()
    # When two peers run it, each walking cells that hold ghost rows
    cluster = InProcessCluster(sc, 2, "f64", dims=(2, 1, 1))
    for _ in range(steps):
        cluster.step()
    result = cluster.final_arrays()
    # Then every array is identical to the single process
    assert sum(h.ghosts_received for h in cluster.halos) > 0
    for key in ("id", "x", "v", "rho"):
        assert np.array_equal(result[key], reference[key]), key
