"""Neighbour search: grid lists equal the brute-force oracle; deterministic (cell, id) order."""
import numpy as np
import pytest

from sphcore.grid import Grid, brute_force_neighbours
from sphcore.state import ParticleState

pytestmark = pytest.mark.fast  # make check runs this whole module


def make_state(x, rng):
    n = len(x)
    ids = rng.permutation(n).astype(np.int64)  # ids unrelated to the initial row order
    return ParticleState.create(ids, x, np.zeros((n, 3)), np.ones(n), np.float64)


def check_lists_match_oracle(grid, state, H, period=(0.0, 0.0, 0.0)):
    grid.bin(state)
    oracle = brute_force_neighbours(state.x, H, period)
    for i in range(state.n):
        got = grid.nbr[i, : grid.counts[i]]
        assert sorted(got.tolist()) == oracle[i].tolist(), f"row {i}"


def cell_key(grid, x):
    idx = np.clip(np.floor((x - grid.origin) * grid.inv_cell).astype(int), 0, grid.ncell - 1)
    return (idx[:, 2] * grid.ncell[1] + idx[:, 1]) * grid.ncell[0] + idx[:, 0]


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("reach", [1, 2])
def test_random_particles_non_cubic_box(dim, reach):
    # Given random particles in a box that is not a whole number of cells in any direction
    rng = np.random.default_rng(1)
    lo, hi = np.zeros(3), np.array([1.3, 0.7, 0.45 if dim == 3 else 0.0])
    x = rng.uniform(lo, hi, size=(600, 3))
    H = 0.13
    grid = Grid(lo - H, hi + H, H, (False, False, False), np.float64, reach=reach)
    state = make_state(x, rng)
    # Then every list equals the brute-force set
    check_lists_match_oracle(grid, state, H)


@pytest.mark.parametrize("reach", [1, 2])
def test_particles_on_cell_faces_and_corners(reach):
    rng = np.random.default_rng(2)
    H = 0.1
    lo = np.zeros(3)
    # lattice whose points coincide with cell faces, edges and corners of the grid
    g = np.arange(0, 6) * H
    x = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    x = np.concatenate([x, x[:50] + np.array([0.5 * H, 0.0, 0.0])])  # half-way points too
    grid = Grid(lo, lo + 5 * H, H, (False, False, False), np.float64, reach=reach)
    check_lists_match_oracle(grid, make_state(x, rng), H)


@pytest.mark.parametrize("periodic", [(True, False, False), (True, True, False), (True, True, True)])
@pytest.mark.parametrize("reach", [1, 2])
def test_periodic_axes_use_minimum_image(periodic, reach):
    rng = np.random.default_rng(3)
    L = np.array([1.0, 0.8, 0.6])
    H = 0.15  # 0.8 / 0.15 -> 5 cells of 0.16 along y: cells stretched to tile the period
    x = rng.uniform(0, L, size=(500, 3))
    lo, hi = np.zeros(3), L.copy()
    for d in range(3):
        if not periodic[d]:
            lo[d] -= H
            hi[d] += H
    grid = Grid(lo, hi, H, periodic, np.float64, reach=reach)
    period = tuple(L[d] if periodic[d] else 0.0 for d in range(3))
    check_lists_match_oracle(grid, make_state(x, rng), H, period)


@pytest.mark.parametrize("reach", [1, 2])
def test_rows_sorted_by_cell_then_id_and_lists_in_that_order(reach):
    rng = np.random.default_rng(4)
    x = rng.uniform(0, 1, size=(400, 3))
    H = 0.2
    grid = Grid(np.zeros(3) - H, np.ones(3) + H, H, (False, False, False), np.float64, reach=reach)
    state = make_state(x, rng)
    grid.bin(state)
    keys = cell_key(grid, state.x)
    order = np.lexsort((state.id, keys))
    assert np.array_equal(order, np.arange(state.n)), "rows are not in (cell, id) order"
    for i in range(state.n):
        js = grid.nbr[i, : grid.counts[i]]
        # neighbour cells are visited z, y, x ascending (no wrap here), so rows come in ascending order
        assert np.all(np.diff(js) > 0)


@pytest.mark.parametrize("reach", [1, 2])
def test_same_particles_in_any_input_order_give_identical_rows(reach):
    rng = np.random.default_rng(5)
    x = rng.uniform(0, 1, size=(300, 3))
    ids = np.arange(300)
    H = 0.2
    results = []
    for perm in (np.arange(300), rng.permutation(300)):
        state = ParticleState.create(ids[perm], x[perm], np.zeros((300, 3)), np.ones(300), np.float64)
        grid = Grid(np.zeros(3) - H, np.ones(3) + H, H, (False, False, False), np.float64, reach=reach)
        grid.bin(state)
        results.append((state.id.copy(), grid.nbr[:, :].copy(), grid.counts.copy()))
    assert np.array_equal(results[0][0], results[1][0])
    assert np.array_equal(results[0][2], results[1][2])
    for i in range(300):
        c = results[0][2][i]
        assert np.array_equal(results[0][1][i, :c], results[1][1][i, :c])


@pytest.mark.parametrize("reach", [1, 2])
def test_capacity_grows_for_crowded_particles(reach):
    # 300 particles in a tiny cluster: every particle has 299 neighbours, more than the capacity
    rng = np.random.default_rng(6)
    x = 0.5 + rng.uniform(-0.01, 0.01, size=(300, 3))
    grid = Grid(np.zeros(3), np.ones(3), 0.1, (False, False, False), np.float64, reach=reach, capacity=16)
    state = make_state(x, rng)
    most = grid.bin(state)
    assert most == 299
    assert grid.capacity >= 299
    assert np.all(grid.counts == 299)


@pytest.mark.parametrize("reach", [1, 2])
def test_lists_built_for_two_subsets_of_rows_equal_one_build_also_when_the_capacity_grows(reach):
    # Given sparse particles and a dense cluster that overflows the capacity, sorted once
    rng = np.random.default_rng(7)
    x = np.concatenate([rng.uniform(0.0, 1.0, size=(400, 3)), 0.5 + rng.uniform(-0.01, 0.01, size=(40, 3))])
    full = Grid(np.zeros(3), np.ones(3), 0.1, (False, False, False), np.float64, reach=reach, capacity=8)
    state = make_state(x, rng)
    full.bin(state)
    # When another grid lists the sparse rows first (no growth), then the others (which grow it)
    parts = Grid(np.zeros(3), np.ones(3), 0.1, (False, False, False), np.float64, reach=reach, capacity=8)
    parts.sort(state)
    crowded = full.counts > 8
    first, second = np.flatnonzero(~crowded), np.flatnonzero(crowded)
    assert len(first) and len(second)
    assert parts.build_neighbours(state.x, state.n, first) <= 8 and parts.capacity == 8
    assert parts.build_neighbours(state.x, state.n, second) == full.counts.max() and parts.capacity > 8
    # Then every row's list is the one a single build gives, the first rows' kept through the growth
    assert np.array_equal(parts.counts, full.counts)
    for i in range(state.n):
        assert np.array_equal(parts.nbr[i, :parts.counts[i]], full.nbr[i, :full.counts[i]]), i


@pytest.mark.parametrize("reach", [1, 2])
def test_periodic_axis_needs_three_cells(reach):
    with pytest.raises(ValueError, match="at least 3 support radii"):
        Grid(np.zeros(3), np.array([0.25, 1.0, 1.0]), 0.1, (True, False, False), np.float64, reach=reach)


@pytest.mark.parametrize("dims,periodic", [((2, 1, 1), (False, False, False)), ((2, 2, 1), (True, False, False))])
@pytest.mark.parametrize("reach", [1, 2])
def test_a_peer_with_ghost_rows_sees_the_same_neighbours_in_the_same_order(dims, periodic, reach):
    # Given random particles, one global grid, and a decomposition into blocks of cells
    from sphcore.decomposition import Decomposition
    rng = np.random.default_rng(7)
    L = np.array([1.2, 0.9, 0.6])
    H = 0.15
    lo, hi = np.zeros(3), L.copy()
    for d in range(3):
        if not periodic[d]:
            lo[d] -= H
            hi[d] += H
    x = rng.uniform(0, L, size=(800, 3))
    ids = rng.permutation(800).astype(np.int64)
    whole = ParticleState.create(ids, x, np.zeros((800, 3)), np.ones(800), np.float64)
    g_all = Grid(lo, hi, H, periodic, np.float64, reach=reach)
    g_all.bin(whole)
    reference = {int(whole.id[i]): whole.id[g_all.nbr[i, : g_all.counts[i]]].tolist() for i in range(800)}
    cells = np.clip(np.floor((x - g_all.origin) * g_all.inv_cell).astype(int), 0, g_all.ncell - 1)
    dec = Decomposition.uniform(tuple(g_all.ncell), dims, periodic, reach=reach)
    owner = dec.owner(cells)
    for r in range(dec.n_peers):
        # When a peer holds its own particles first and its ghosts (its halo cells) after them
        own = np.nonzero(owner == r)[0]
        ghost = np.nonzero(dec.in_halo(cells, r))[0]
        rows = np.concatenate([own, rng.permutation(ghost)])
        peer = ParticleState.create(ids[rows], x[rows], np.zeros((len(rows), 3)), np.ones(len(rows)), np.float64)
        peer.n_owned = len(own)
        g = Grid(lo, hi, H, periodic, np.float64, reach=reach)
        g.bin(peer)
        # Then owned rows come first and every owned particle has the single-process neighbours, in order
        assert set(peer.id[: peer.n_owned].tolist()) == set(ids[own].tolist())
        for i in range(peer.n_owned):
            got = peer.id[g.nbr[i, : g.counts[i]]].tolist()
            assert got == reference[int(peer.id[i])]


@pytest.mark.parametrize("periodic", [(False, False, False), (True, True, False)])
@pytest.mark.parametrize("reach", [1, 2])
def test_the_cell_by_cell_scan_gives_the_lists_of_the_row_at_once(periodic, reach):
    # Given one process's particles, binned: each x-row of cells is one range of rows in memory
    rng = np.random.default_rng(11)
    L, H = np.array([1.2, 0.9, 0.6]), 0.15
    lo, hi = np.zeros(3), L.copy()
    for d in range(3):
        if not periodic[d]:
            lo[d] -= H
            hi[d] += H
    state = make_state(rng.uniform(0, L, size=(700, 3)), rng)
    grid = Grid(lo, hi, H, periodic, np.float64, reach=reach)
    grid.bin(state)
    at_once = grid.nbr[: state.n].copy(), grid.counts[: state.n].copy()
    # When the lists are built again through the path a peer with ghost rows takes (cells scanned
    # one by one, runs of cells that follow one another in memory joined into one scan)
    grid.contiguous = False
    grid.build_neighbours(state.x, state.n)
    # Then every list is the same, entry for entry
    assert np.array_equal(grid.counts[: state.n], at_once[1])
    for i in range(state.n):
        assert np.array_equal(grid.nbr[i, : grid.counts[i]], at_once[0][i, : at_once[1][i]]), i


@pytest.mark.parametrize("reach", [1, 2])
def test_sorting_the_ghosts_after_the_owned_rows_gives_the_order_of_one_sort(reach):
    # Given a peer's owned rows (in no order) and its ghost rows after them, as in exchange 1
    from sphcore.decomposition import Decomposition
    rng = np.random.default_rng(8)
    H = 0.1
    lo, hi = np.full(3, -H), np.full(3, 1.0 + H)
    x = rng.uniform(0.0, 1.0, size=(900, 3))
    ids = rng.permutation(900).astype(np.int64)
    probe = Grid(lo, hi, H, (False, False, False), np.float64, reach=reach)
    cells = probe.cells_of(x)
    dec = Decomposition.uniform(tuple(probe.ncell), (2, 2, 1), (False, False, False), reach=reach)
    own = rng.permutation(np.nonzero(dec.owner(cells) == 0)[0])
    ghost = rng.permutation(np.nonzero(dec.in_halo(cells, 0))[0])
    rows = np.concatenate([own, ghost])

    def state(r, n_owned):
        s = ParticleState.create(ids[r], x[r], rng.normal(size=(len(r), 3)), np.ones(len(r)), np.float64)
        s.v[:] = x[r] * 3.0  # a carried field that must follow its row
        s.extra["kappa"] = ids[r].astype(np.float64)
        s.n_owned = n_owned
        return s

    # When one grid sorts every row at once, and another the owned rows first and the ghosts after
    whole = state(rows, len(own))
    once = Grid(lo, hi, H, (False, False, False), np.float64, reach=reach)
    once.sort(whole)
    apart = Grid(lo, hi, H, (False, False, False), np.float64, reach=reach)
    owned = state(own, len(own))
    apart.sort(owned)
    first = apart.last_permutation.copy()
    both = state(rows, len(own))
    for name in ("id", "x", "v", "m"):
        getattr(both, name)[:len(own)] = getattr(owned, name)
    both.extra["kappa"][:len(own)] = owned.extra["kappa"]
    apart.sort_ghosts(both)
    # Then the rows, their carried fields, the bins and the cell ranges are the same, and the owned
    # rows' permutation followed by the ghosts' is the single sort's
    for name in ("id", "x", "v", "m"):
        assert np.array_equal(getattr(both, name), getattr(whole, name)), name
    assert np.array_equal(both.extra["kappa"], whole.extra["kappa"])
    assert np.array_equal(apart.bin_start, once.bin_start)
    assert np.array_equal(apart.cell_begin, once.cell_begin) and np.array_equal(apart.cell_end, once.cell_end)
    assert np.array_equal(apart.last_permutation[:len(own)], np.arange(len(own)))
    assert np.array_equal(np.concatenate([first, apart.last_permutation[len(own):]]), once.last_permutation)
    # and sorting the ghosts is refused when the owned rows were not sorted alone first
    with pytest.raises(RuntimeError, match="sorted alone"):
        once.sort_ghosts(whole)


def test_cells_are_half_the_support_with_lists_and_the_support_with_the_walk_unless_the_scene_says():
    # Given the same scene with lists, with the walk, and with cells_per_support set either way
    from conftest import scene
    from sphcore.scene import SceneError, grid_reach, resource_estimate
    from sphcore.solver import Simulation
    lists = scene("dam_break", "particles.spacing=0.05", "run.neighbour_skin=0")  # cells for H, not H (1 + skin)
    walk = scene("dam_break", "particles.spacing=0.05", "run.neighbours='walk'")
    cells_h = scene("dam_break", "particles.spacing=0.05", "run.cells_per_support=1", "run.neighbour_skin=0")
    walk_half = scene("dam_break", "particles.spacing=0.05", "run.neighbours='walk'", "run.cells_per_support=2")
    # Then the default (0) gives lists cells of H / 2 and the walk cells of H, and a set value wins
    assert [grid_reach(s) for s in (lists, walk, cells_h, walk_half)] == [2, 1, 1, 2]
    grids = [Simulation(s, "f64").grid for s in (lists, cells_h)]
    H = lists.sph.support * lists.particles.spacing
    assert [g.reach for g in grids] == [2, 1]
    assert np.allclose(grids[0].cell[:2], H / 2) and np.allclose(grids[1].cell[:2], H)
    # and the memory estimate counts the cells of the grid the run will have (up to 2^dim as many:
    # the estimate adds 3 cells of margin per axis whatever their size)
    ratio = resource_estimate(lists)["cells"] / resource_estimate(cells_h)["cells"]
    assert 2 ** lists.dim / 2 < ratio <= 2 ** lists.dim
    with pytest.raises(SceneError, match="run.cells_per_support"):
        scene("dam_break", "run.cells_per_support=3")


@pytest.mark.parametrize("keys", [[], [0, 0, 0], [5, 4, 5, 3], [9, 0, 9], "random", "owned half"])
def test_the_counting_scatter_is_a_stable_sort_with_every_bin_start(keys):
    """_scatter_by_key: perm is the stable order of the keys and bin b starts at the number of keys
    below b, for every bin: those after the largest key (left to a fill) and the last one too."""
    from sphcore.grid import _scatter_by_key
    rng = np.random.default_rng(5)
    nbins = 10
    if keys == "random":
        nbins = 5000
        keys = rng.integers(0, nbins, 3000)
    elif keys == "owned half":  # an owned-rows sort: keys in the first half of the bins only
        nbins = 5000
        keys = np.sort(rng.integers(0, nbins // 2, 3000))
        keys[rng.integers(0, 3000, 40)] = rng.integers(0, nbins // 2, 40)  # a few rows changed cells
    keys = np.asarray(keys, dtype=np.int64)
    start = np.full(nbins + 1, -7, dtype=np.int64)  # stale values from an earlier step
    perm = np.full(len(keys), -1, dtype=np.int64)
    _scatter_by_key(keys, start, perm)
    assert perm.tolist() == np.argsort(keys, kind="stable").tolist()
    assert start.tolist() == np.searchsorted(np.sort(keys), np.arange(nbins + 1)).tolist()


def _scalar_list(x, i, candidates, H2):
    """Row i's list as the scalar loop forms it: the candidates within H2, in their order, each
    squared distance rounded as that loop rounds it ((dx dx + dy dy) + dz dz in x's precision)."""
    d = x[i] - x[candidates]
    r2 = (d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) + d[:, 2] * d[:, 2]
    return candidates[r2 < H2]


def _crowded(dtype, seed=3):
    """(x, H^2): 412 random particles and a lattice of 288 whose spacing, 2^-6, is exactly H / 4 (ties
    at the support, which are not neighbours); ~30 neighbours a particle, up to ~60."""
    rng = np.random.default_rng(seed)
    lattice = np.stack(np.meshgrid(np.arange(12), np.arange(12), np.arange(2), indexing="ij"), -1).reshape(-1, 3)
    x = np.concatenate([rng.random((412, 3)) * 0.2, lattice * 2.0 ** -6])
    return x.astype(dtype), dtype(2.0 ** -8)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("layout", ["C", "F"])
def test_a_scanned_range_lists_what_the_scalar_loop_lists_also_past_the_capacity(dtype, layout):
    # (On a CPU with AVX-512 the scan goes through compress-stored chunks, sphcore/simd.py; the CUDA
    # simulator's lists are column-major, layout F. Either way the lists must be the scalar loop's.)
    # Given crowded particles and lists of 24 columns and a spare: many rows hold more neighbours
    from numba import njit
    from sphcore import grid as grid_module
    x, H2 = _crowded(dtype)
    n = x.shape[0]
    nbr = np.zeros((n, 25), np.int32, order=layout)

    @njit
    def scan_all(x, H2, nbr, counts):
        period = np.zeros(3, x.dtype)
        for i in range(x.shape[0]):
            lo, hi = (i * 7) % 50, x.shape[0] - (i * 11) % 50  # ranges of every length and start
            counts[i] = grid_module._scan_span(True, np.int64(i), lo, hi, x, x[i, 0], x[i, 1], x[i, 2], H2,
                                               period, 0, nbr, 0, nbr.shape[1] - 1)

    counts = np.zeros(n, np.int64)
    # When every row's range is scanned
    scan_all(x, H2, nbr, counts)
    # Then each count is the number within H (counted past the capacity) and the stored columns are
    # the scalar loop's first ones, in its order
    assert (counts > 24).any() and (counts <= 24).any()
    for i in range(n):
        lo, hi = (i * 7) % 50, n - (i * 11) % 50
        want = _scalar_list(x, i, np.arange(lo, hi), H2)
        assert counts[i] == len(want), i
        kept = min(counts[i], 24)
        assert np.array_equal(nbr[i, :kept], want[:kept]), i


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_the_filter_keeps_what_the_scalar_loop_keeps_also_past_the_capacity(dtype):
    # Given candidate lists in no particular order, of every length up to 120 (drawn from each row's
    # 150 nearest particles, so that half of them or more are neighbours), and lists of 24 columns
    # and a spare
    from sphcore import grid as grid_module
    x, H2 = _crowded(dtype)
    n = x.shape[0]
    rng = np.random.default_rng(5)
    cand = np.zeros((n, 121), np.int32)
    cand_counts = rng.integers(0, 121, n).astype(np.int32)
    for i in range(n):
        nearest = np.argsort(((x - x[i]) ** 2).sum(axis=1))[:150]
        cand[i, :cand_counts[i]] = rng.choice(nearest, cand_counts[i], replace=False)
    nbr = np.zeros((n, 25), np.int32)
    counts = np.zeros(n, np.int32)
    # When they are filtered
    grid_module._filter_neighbours(0, x, n, cand, cand_counts, np.zeros(3, dtype), H2, nbr, counts)
    # Then each count is the number within H and the stored columns are the scalar loop's first ones
    assert (counts > 24).any() and (counts <= 24).any()
    for i in range(n):
        want = _scalar_list(x, i, cand[i, :cand_counts[i]].astype(np.int64), H2)
        assert counts[i] == len(want), i
        kept = min(counts[i], 24)
        assert np.array_equal(nbr[i, :kept], want[:kept]), i
