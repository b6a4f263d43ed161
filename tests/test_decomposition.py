"""Decomposition geometry: blocks tile the grid; zones equal their brute-force definitions."""
import itertools

import numpy as np
import pytest

from sphcore.decomposition import Decomposition, choose_dims, halo_particles
from conftest import scene


def all_cells(ncell):
    return np.array(list(itertools.product(*(range(n) for n in ncell))))


def brute_gap(cell, lo, hi, ncell, periodic):
    """Chebyshev distance from a cell to the box [lo, hi), trying every periodic image."""
    best = None
    shifts = [[0] + ([-ncell[a], ncell[a]] if periodic[a] else []) for a in range(3)]
    for s in itertools.product(*shifts):
        c = np.asarray(cell) + np.asarray(s)
        d = max(max(lo[a] - c[a], 0, c[a] - (hi[a] - 1)) for a in range(3))
        best = d if best is None else min(best, d)
    return best


@pytest.mark.parametrize("dims,periodic", [
    ((4, 1, 1), (False, False, False)),
    ((2, 2, 1), (False, False, False)),
    ((3, 1, 1), (True, False, False)),
    ((2, 2, 2), (True, True, False)),
])
@pytest.mark.parametrize("reach", [1, 2])
def test_blocks_tile_the_grid_and_zones_match_brute_force(dims, periodic, reach):
    # the incoming zone is reach cells deep (cells of H / reach)
    ncell = tuple(reach * n for n in (9, 7, 6))
    dec = Decomposition.uniform(ncell, dims, periodic, reach=reach)
    cells = all_cells(ncell)
    owner = dec.owner(cells)
    # Then every cell has exactly one owner and each block is the box cell_box says
    for r in range(dec.n_peers):
        lo, hi = dec.cell_box(r)
        inside = np.all((cells >= lo) & (cells < hi), axis=1)
        assert np.array_equal(inside, owner == r)
    # and the halo / outgoing zones / neighbours equal their definitions
    for r in range(dec.n_peers):
        lo, hi = dec.cell_box(r)
        halo = np.array([1 <= brute_gap(c, lo, hi, ncell, periodic) <= reach for c in cells])
        assert np.array_equal(dec.in_halo(cells, r), halo)
        expected_neighbours = sorted(set(owner[halo]) - {r})
        assert dec.neighbours(r) == expected_neighbours
        mine = cells[owner == r]
        for q in dec.neighbours(r):
            qlo, qhi = dec.cell_box(q)
            want = np.array([1 <= brute_gap(c, qlo, qhi, ncell, periodic) <= reach for c in mine])
            assert np.array_equal(dec.outgoing(mine, r, q), want)


def test_choose_dims():
    assert choose_dims(4, (40, 10, 10), 3, "slabs", reach=1) == (4, 1, 1)
    assert choose_dims(4, (20, 20, 4), 3, "auto", reach=1) == (2, 2, 1)
    assert choose_dims(3, (30, 8, 8), 3, "auto", reach=1) == (3, 1, 1)
    assert choose_dims(2, (10, 10, 1), 2, "auto", reach=1) in {(2, 1, 1), (1, 2, 1)}
    with pytest.raises(ValueError, match="do not fit"):
        choose_dims(8, (5, 1, 1), 3, "slabs", reach=1)
    # blocks keep 2 support radii along a cut axis: 4 cells of H / 2
    assert choose_dims(4, (16, 1, 1), 3, "slabs", reach=2) == (4, 1, 1)
    with pytest.raises(ValueError, match="at least 4 cells"):
        choose_dims(4, (15, 1, 1), 3, "slabs", reach=2)


@pytest.mark.fast
def test_auto_layout_cuts_where_the_fewest_particles_are_near_the_cut():
    # a column 8 cells long in x, 8 high in y and 12 deep in z in a domain 32 x 12 x 12 cells: by the
    # blocks' surface x is cut (its face is the domain's smallest), but the column's face across z
    # (8 x 8 cells) holds fewer particles than its face across x (8 x 12); both halve the particles
    ncell = (32, 12, 12)
    cells = np.stack(np.meshgrid(np.arange(8), np.arange(8), np.arange(12), indexing="ij"), -1).reshape(-1, 3)
    cells = np.repeat(cells, 3, axis=0)  # 3 particles a cell
    hist = [np.bincount(cells[:, a], minlength=ncell[a]) for a in range(3)]
    assert choose_dims(2, ncell, 3, "auto", reach=1) == (2, 1, 1)
    assert choose_dims(2, ncell, 3, "auto", reach=1, cells=cells) == (1, 1, 2)
    dec = Decomposition.balanced(ncell, (1, 1, 2), cells, reach=1)
    assert dec.cuts[2] == (0, 6, 12)
    assert halo_particles(dec, hist) == 2 * 8 * 8 * 3           # the layers z = 5 and z = 6
    dec_x = Decomposition.balanced(ncell, (2, 1, 1), cells, reach=1)
    assert halo_particles(dec_x, hist) == 2 * 8 * 12 * 3        # x = 3 and x = 4
    # periodic in z: the wrap is a second plane between the two blocks, and z is no longer the best cut
    dec_p = Decomposition.balanced(ncell, (1, 1, 2), cells, (False, False, True), reach=1)
    assert halo_particles(dec_p, hist) == 4 * 8 * 8 * 3
    assert choose_dims(2, ncell, 3, "auto", reach=1, cells=cells, periodic=(False, False, True)) == (2, 1, 1)
    # gravity along z: z stays uncut while another layout fits, whatever its halo
    assert choose_dims(2, ncell, 3, "auto", reach=1, cells=cells, vertical=2) == (2, 1, 1)
    assert choose_dims(2, ncell, 3, "auto", reach=1, cells=cells, vertical=0) == (1, 1, 2)
    assert choose_dims(2, (3, 3, 12), 3, "auto", reach=1, vertical=2) == (1, 1, 2)   # nothing else fits
    # with 2 cells a support radius the zone is twice as deep
    dec2 = Decomposition.balanced((64, 24, 24), (1, 1, 2), cells * 2, reach=2)
    hist2 = [np.bincount(cells[:, a] * 2, minlength=n) for a, n in enumerate((64, 24, 24))]
    assert halo_particles(dec2, hist2) == 2 * 8 * 8 * 3


@pytest.mark.fast
def test_auto_layout_does_not_leave_peers_idle_where_the_particles_fill_part_of_an_axis():
    # the column fills 8 of x's 32 cells: blocks of 2 support radii (2 cells) along x leave at most 4
    # x-blocks with particles, so 8 x 1 x 2 leaves half the peers empty while 4 x 1 x 4 balances all
    # 16 (its halo is larger: the smallest halo alone would pick 8 x 1 x 2)
    ncell = (32, 12, 12)
    cells = np.stack(np.meshgrid(np.arange(8), np.arange(8), np.arange(12), indexing="ij"), -1).reshape(-1, 3)
    hist = [np.bincount(cells[:, a], minlength=ncell[a]) for a in range(3)]
    lopsided = Decomposition.balanced(ncell, (8, 1, 2), cells, reach=1)
    even = Decomposition.balanced(ncell, (4, 1, 4), cells, reach=1)
    assert np.count_nonzero(np.bincount(lopsided.owner(cells), minlength=16)) == 8
    assert np.bincount(even.owner(cells), minlength=16).max() == len(cells) // 16
    assert halo_particles(lopsided, hist) < halo_particles(even, hist)
    assert choose_dims(16, ncell, 3, "auto", reach=1, cells=cells, vertical=1) == (4, 1, 4)


def test_balanced_cuts_equalise_particle_counts():
    rng = np.random.default_rng(0)
    ncell = (40, 8, 8)
    # particles crowded at low x, as in a dam break
    cells = np.stack([np.minimum((rng.exponential(6.0, 20000)).astype(int), 39),
                      rng.integers(0, 8, 20000), rng.integers(0, 8, 20000)], axis=1)
    dec = Decomposition.balanced(ncell, (4, 1, 1), cells, reach=1)
    counts = np.bincount(dec.owner(cells), minlength=4)
    assert counts.max() / counts.mean() < 1.25
    assert all(b - a >= 2 for a, b in zip(dec.cuts[0][:-1], dec.cuts[0][1:]))
    # with cells of H / 2 a block keeps 4 of them (2 support radii), however crowded the low end
    crowded = cells.copy()
    crowded[:, 0] = np.minimum(crowded[:, 0], 1)
    dec = Decomposition.balanced(ncell, (4, 1, 1), crowded, reach=2)
    assert all(b - a >= 4 for a, b in zip(dec.cuts[0][:-1], dec.cuts[0][1:])), dec.cuts[0]


@pytest.mark.fast
@pytest.mark.parametrize("dims,periodic", [
    ((4, 1, 1), (False, False, False)),
    ((2, 2, 1), (False, False, False)),
    ((3, 1, 1), (True, False, False)),
    ((2, 2, 2), (True, True, False)),
    ((3, 2, 2), (True, True, True)),
])
@pytest.mark.parametrize("reach", [1, 2])
def test_zone_code_is_the_owner_and_the_outgoing_zones(dims, periodic, reach):
    """decomposition.zone_code (exchange 1's question, asked on the host or a GPU) gives every cell the
    rank Decomposition.owner gives it and, bit b, whether it lies in the incoming zone of neighbour b
    (Decomposition.outgoing), on balanced, uneven cuts."""
    from sphcore.decomposition import zone_codes, zone_tables
    ncell = tuple(reach * n for n in (9, 7, 6))
    rng = np.random.default_rng(3)
    cells = all_cells(ncell)
    dec = Decomposition.balanced(ncell, dims, cells[rng.integers(0, len(cells), 400)], periodic, reach=reach)
    for rank in range(dec.n_peers):
        neighbours = dec.neighbours(rank)
        owner = np.empty(len(cells), dtype=np.int64)
        mask = np.empty(len(cells), dtype=np.int64)
        zone_codes(cells, *zone_tables(dec, rank, neighbours), owner, mask)
        assert np.array_equal(owner, dec.owner(cells))
        for b, q in enumerate(neighbours):
            assert np.array_equal((mask >> b) & 1, dec.outgoing(cells, rank, q).astype(np.int64)), (rank, q)
        assert not (mask >> len(neighbours)).any()


@pytest.mark.parametrize("name,dims", [("dam_break", (1, 1, 2)), ("dam_break_2d", (2, 1, 1))])
def test_the_dam_breaks_are_cut_along_the_floor_where_the_halo_is_smallest(name, dims):
    # 3D: the column (0.4 x 0.4 x 0.6 m) is cut across z, whose face holds 2/3 of the particles of
    # the face across x; y (gravity's) stays uncut. 2D: x, as gravity leaves no other choice.
    from nodes.peer import decomposition_for
    from sphcore.solver import Simulation

    sc = scene(name, "particles.spacing=0.025" if name == "dam_break" else "particles.spacing=0.02")
    sim = Simulation(sc, "f64")
    dec = decomposition_for(sc, sim.grid, 2, sim.state.x)
    assert dec.dims == dims
    counts = np.bincount(dec.owner(sim.grid.cells_of(sim.state.x)), minlength=2)
    assert abs(counts[0] - counts[1]) <= 0.1 * counts.sum()
