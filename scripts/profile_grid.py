"""Time each part of the CPU grid stage (cell keys, counting sort, per-cell id sort, cell ranges,
gather, neighbour lists) on the benchmark's 3D dam break, after two steps.

    python scripts/profile_grid.py [--particles 1000000] [--threads N]

Prints the mean of 5 calls of each part, in ms, and of the whole ``Grid.bin``.
"""
import argparse
import time

import numba

from launch.bench import DEFAULT_SCENE, _fixed, spacing_for
from sphcore import grid as G
from sphcore.scene import load_scene
from sphcore.solver import Simulation

NO_SKIN = ["run.neighbour_skin=0"]  # a list a step, as measured when this was written (grid.py)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--particles", type=int, default=1_000_000)
    ap.add_argument("--threads", type=int, default=numba.config.NUMBA_NUM_THREADS)
    args = ap.parse_args()
    numba.set_num_threads(args.threads)
    dx = spacing_for(DEFAULT_SCENE, args.particles)
    sim = Simulation(load_scene(DEFAULT_SCENE, _fixed(DEFAULT_SCENE, dx) + NO_SKIN), "f32", "cpu")
    sim.step()
    sim.step()
    g, s = sim.grid, sim.state
    print(f"{sim.n_particles} particles, {args.threads} threads, f32")

    def timed(name, f, k=5):
        f()
        t0 = time.perf_counter()
        for _ in range(k):
            f()
        print(f"{name:20s} {1e3 * (time.perf_counter() - t0) / k:8.1f} ms")
    timed("cell keys", lambda: G.compute_cell_keys(s.x, s.n_owned, g.origin, g.inv_cell, g.ncell, g._keys))
    timed("counting sort", lambda: G._scatter_by_key(g._keys, g.bin_start, g._perm))
    timed("sort cells by id", lambda: G._sort_bins_by_id(0, g._keys, g.bin_start, g._perm, s.id))
    timed("cell ranges", lambda: G._cell_ranges(g.bin_start, g.ncells, g.cell_begin, g.cell_end))
    timed("gather x", lambda: g._gather("x", s.x))
    timed("neighbour lists", lambda: g.build_neighbours(s.x, s.n_owned))
    timed("whole bin", lambda: g.bin(s))


if __name__ == "__main__":
    main()
