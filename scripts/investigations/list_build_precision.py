"""Is the float32 neighbour-list build as fast as the float64 one? It was not: numba types a prange
index as uint64, uint64 with int64 is float64 arithmetic, and the list's j != i converted every
candidate to float64 (docs/BENCHMARKS.md, "2026-12-05 (evening)"). This times grid._build_neighbours
on the same positions (the 3D dam break at 49,152 particles after --steps steps, float32) as float32
and as float64 arrays, the same neighbours either way, twice each, and prints the neighbour count as a
check that both built the same lists.

    .venv/bin/python scripts/investigations/list_build_precision.py [--steps 20] [--threads 1]
"""
import argparse
import time

import numba
import numpy as np

from launch.bench import DEFAULT_SCENE, _fixed, spacing_for
from sphcore import grid as grid_mod
from sphcore.scene import load_scene
from sphcore.solver import Simulation

NO_SKIN = ["run.neighbour_skin=0"]  # a list a step, as measured when this was written (grid.py)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=20, help="steps from rest before timing (default 20)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=15)
    a = ap.parse_args()
    numba.set_num_threads(a.threads)
    dx = spacing_for(DEFAULT_SCENE, 49152)
    sim = Simulation(load_scene(DEFAULT_SCENE, _fixed(DEFAULT_SCENE, dx) + NO_SKIN), "f32", "cpu")
    for _ in range(a.steps):
        sim.step()
    g, s = sim.grid, sim.state

    def timed(x, dtype):
        as_ = lambda arr: arr.astype(dtype)
        args = (g.contiguous, g.cell_begin, g.cell_end, as_(g.origin), as_(g.cell), as_(g.inv_cell), g.ncell,
                g.reach, as_(g.period), dtype(g.H2), g.nbr, g.counts)
        grid_mod._build_neighbours(0, x, s.n_owned, *args)
        times = []
        for _ in range(a.repeat):
            t0 = time.perf_counter()
            grid_mod._build_neighbours(0, x, s.n_owned, *args)
            times.append(time.perf_counter() - t0)
        return np.median(times) * 1e3, min(times) * 1e3, int(g.counts[:s.n_owned].sum())

    print(f"{s.n_owned} particles, t = {sim.t:.4f} s, {a.threads} thread(s): list build, median of {a.repeat}")
    for _ in range(2):
        for name, x, dtype in (("float32", s.x, np.float32), ("float64", s.x.astype(np.float64), np.float64)):
            ms, fastest, found = timed(x, dtype)
            print(f"  {name}: {ms:6.2f} ms (min {fastest:6.2f})  ({found} neighbours)")


if __name__ == "__main__":
    main()
