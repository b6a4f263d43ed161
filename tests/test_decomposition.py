"""Decomposition geometry: blocks tile the grid; zones equal their brute-force definitions."""
import itertools

import numpy as np
import pytest

from sphcore.decomposition import Decomposition, choose_dims


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
