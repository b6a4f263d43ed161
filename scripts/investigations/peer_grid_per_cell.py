"""What do a peer's grid passes over every cell cost, whatever its particle count?

Each peer holds the global grid: with cells of H / 2 the 49k-particle 3D dam break of ``sph bench``
has about 258,000 cells, and a peer of two sorts its owned rows (``_scatter_by_key``: histogram,
prefix sum and scatter over the bins up to its largest key, the owned half of the 2 x 258,000, and a
fill of the rest since 2026-12-05: 0.65 ms against 1.74 over all of them), sets every cell's range (``_cell_ranges``), then bins
its ghost rows (``_scatter_ghosts``: the ghost half of the bins again) and sets every range again.
Those passes cost the same on a peer holding half the particles, so they weigh twice as much in its
step. This times them alone at one thread, with 24,576 owned rows and 3,072 ghost rows (one peer of
two at that size) on random cells: the per-cell work does not depend on where the keys fall. Since
2026-12-05 the ghost rows' bins are a stable sort of their keys and a fill, and only the cells
holding ghosts get their range set again (``_ghost_cell_ranges``); before, the ghost bins were a
histogram and prefix sum over every cell and every range was set again (4.2 ms a step at 258,000 cells).

    .venv/bin/python scripts/investigations/peer_grid_per_cell.py [--cells 258000] [--repeat 50]
"""
import argparse
import time

import numba
import numpy as np

from sphcore import grid


def timed(f, *args, repeat):
    f(*args)  # compile and warm
    t0 = time.perf_counter()
    for _ in range(repeat):
        f(*args)
    return (time.perf_counter() - t0) / repeat * 1e3


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cells", type=int, default=258_000, help="grid cells (default: the bench's 49k dam break at H / 2)")
    ap.add_argument("--owned", type=int, default=24_576)
    ap.add_argument("--ghosts", type=int, default=3_072)
    ap.add_argument("--repeat", type=int, default=50)
    a = ap.parse_args()
    numba.set_num_threads(1)
    rng = np.random.default_rng(0)
    ncells, n_owned, n_ghosts = a.cells, a.owned, a.ghosts
    owned_keys = np.sort(rng.integers(0, ncells, n_owned)).astype(np.int64)
    ghost_keys = rng.integers(0, ncells, n_ghosts).astype(np.int64) + ncells  # ghost bins follow the owned ones
    keys = np.concatenate([owned_keys, ghost_keys])
    bin_start = np.zeros(2 * ncells + 1, np.int64)
    perm = np.zeros(n_owned + n_ghosts, np.int64)
    begin, end = np.zeros(ncells, np.int64), np.zeros(ncells, np.int64)
    t_owned = timed(grid._scatter_by_key, owned_keys, bin_start, perm[:n_owned], repeat=a.repeat)
    grid._scatter_by_key(owned_keys, bin_start, perm[:n_owned])
    t_ranges = timed(grid._cell_ranges, bin_start, ncells, begin, end, repeat=a.repeat)
    owned_bins = bin_start.copy()

    def ghosts():  # from the owned sort's bins, as every step
        bin_start[:] = owned_bins
        grid._scatter_ghosts(keys, n_owned, ncells, bin_start, perm)

    t_copy = timed(lambda: bin_start.__setitem__(slice(None), owned_bins), repeat=a.repeat)
    t_ghosts = max(timed(ghosts, repeat=a.repeat) - t_copy, 0.0)
    t_ghost_ranges = timed(grid._ghost_cell_ranges, keys, n_owned, ncells, bin_start, perm, begin, end, repeat=a.repeat)
    print(f"{ncells} cells, {n_owned} owned and {n_ghosts} ghost rows, 1 thread, ms per call:")
    print(f"  owned rows' counting scatter                     {t_owned:.2f}")
    print(f"  cell ranges (every cell)                         {t_ranges:.2f}")
    print(f"  ghost rows' order and bins                       {t_ghosts:.2f}")
    print(f"  ghost cells' ranges                              {t_ghost_ranges:.2f}")
    print(f"  a peer's step: {t_owned + t_ranges + t_ghosts + t_ghost_ranges:.2f} ms")


if __name__ == "__main__":
    main()
