"""Why does the list build cost more once the dam break has flowed? This counts the candidates the
builder tests per particle (the rows in the row ranges grid.neighbour_row scans, its pruning
included) and the ranges it scans, at t after --steps fixed steps (the bench's 49,152 particles),
beside the neighbours found, and times the build at 1 thread.

    .venv/bin/python scripts/investigations/list_candidates.py --steps 20 600
"""
import argparse
import time

import numba
import numpy as np
from numba import njit, prange

from launch.bench import DEFAULT_SCENE, _fixed, spacing_for
from sphcore import grid as G
from sphcore.scene import load_scene
from sphcore.solver import Simulation

NO_SKIN = ["run.neighbour_skin=0"]  # a list a step, as measured when this was written (grid.py)


@njit(parallel=True)
def count(x, n, cell_begin, cell_end, origin, cell, inv_cell, ncell, reach, H2, candidates, ranges):
    """The scanned rows and row ranges of every particle, as neighbour_row's contiguous path scans them."""
    for k in prange(n):
        i = np.int64(k)
        nx, ny, nz = ncell[0], ncell[1], ncell[2]
        xi, yi, zi = x[i, 0], x[i, 1], x[i, 2]
        ix = min(max(int((xi - origin[0]) * inv_cell[0]), 0), nx - 1)
        iy = min(max(int((yi - origin[1]) * inv_cell[1]), 0), ny - 1)
        iz = min(max(int((zi - origin[2]) * inv_cell[2]), 0), nz - 1)
        x_lo = origin[0] + ix * cell[0]
        y_lo = origin[1] + iy * cell[1]
        z_lo = origin[2] + iz * cell[2]
        c = 0
        r = 0
        for dz in range(-reach, reach + 1):
            cz = iz + dz
            if cz < 0 or cz >= nz:
                continue
            gz = G._face_gap2(dz, zi, z_lo, cell[2])
            if gz >= H2:
                continue
            for dy in range(-reach, reach + 1):
                cy = iy + dy
                if cy < 0 or cy >= ny:
                    continue
                gyz = gz + G._face_gap2(dy, yi, y_lo, cell[1])
                if gyz >= H2:
                    continue
                row = (cz * ny + cy) * nx
                left = 0
                while left < reach and gyz + G._face_gap2(-(left + 1), xi, x_lo, cell[0]) < H2:
                    left += 1
                right = 0
                while right < reach and gyz + G._face_gap2(right + 1, xi, x_lo, cell[0]) < H2:
                    right += 1
                c += cell_end[row + min(ix + right, nx - 1)] - cell_begin[row + max(ix - left, 0)]
                r += 1
        candidates[i] = c
        ranges[i] = r


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, nargs="+", default=[20, 600])
    a = ap.parse_args()
    numba.set_num_threads(1)
    dx = spacing_for(DEFAULT_SCENE, 49152)
    sim = Simulation(load_scene(DEFAULT_SCENE, _fixed(DEFAULT_SCENE, dx) + NO_SKIN), "f32", "cpu")
    for target in sorted(a.steps):
        while sim.step_index < target:
            sim.step()
        g, s = sim.grid, sim.state
        n = s.n_owned
        cand, ranges = np.zeros(n, np.int64), np.zeros(n, np.int64)
        count(s.x, n, g.cell_begin, g.cell_end, g.origin, g.cell, g.inv_cell, g.ncell, g.reach, g.H2, cand, ranges)
        g.build_neighbours(s.x, n)
        times = []
        for _ in range(10):
            t0 = time.perf_counter()
            g.build_neighbours(s.x, n)
            times.append(time.perf_counter() - t0)
        found = g.counts[:n]
        print(f"t = {sim.t:.4f} s: build {np.median(times) * 1e3:.2f} ms; per particle {cand.mean():.1f} candidates "
              f"in {ranges.mean():.1f} ranges, {found.mean():.1f} neighbours ({found.mean() / cand.mean():.0%} accepted); "
              f"range length mean {cand.sum() / ranges.sum():.2f}")


if __name__ == "__main__":
    main()
