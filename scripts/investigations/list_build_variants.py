"""Where the CPU list build's time goes, with grid cells of H and of H / 2 (docs/BENCHMARKS.md, "Grid
cells of H / 2"): the build as grid.neighbour_row does it (a store per candidate) against three
variants (store neighbours only; test the candidates, store nothing; set up the row ranges alone),
on the 3D dam break at 49,152 particles after two steps, 2 threads, float32, each cell size twice.

    .venv/bin/python scripts/investigations/list_build_variants.py
"""
import time, sys, numpy as np, numba
from numba import njit, prange
from launch.bench import DEFAULT_SCENE, _fixed, spacing_for
from sphcore import grid as G
from sphcore.scene import load_scene
from sphcore.solver import Simulation
numba.set_num_threads(2)
dx = spacing_for(DEFAULT_SCENE, 49152)
sim = Simulation(load_scene(DEFAULT_SCENE, _fixed(DEFAULT_SCENE, dx)), "f32", "cpu")
for _ in range(2): sim.step()
s = sim.state
g0 = sim.grid
gap = G._face_gap2

@njit(parallel=True)
def variant(mode, x, n, cb, ce, origin, cell, inv_cell, ncell, R, H2, nbr, counts):
    cap = nbr.shape[1] - 1
    for i in prange(n):
        nx, ny, nz = ncell[0], ncell[1], ncell[2]
        xi, yi, zi = x[i, 0], x[i, 1], x[i, 2]
        ix = min(max(int((xi - origin[0]) * inv_cell[0]), 0), nx - 1)
        iy = min(max(int((yi - origin[1]) * inv_cell[1]), 0), ny - 1)
        iz = min(max(int((zi - origin[2]) * inv_cell[2]), 0), nz - 1)
        x_lo = origin[0] + np.float32(ix) * cell[0]
        y_lo = origin[1] + np.float32(iy) * cell[1]
        z_lo = origin[2] + np.float32(iz) * cell[2]
        count = 0
        for dz in range(-R, R + 1):
            cz = iz + dz
            if cz < 0 or cz >= nz:
                continue
            gz = gap(dz, zi, z_lo, cell[2])
            if gz >= H2:
                continue
            for dy in range(-R, R + 1):
                cy = iy + dy
                if cy < 0 or cy >= ny:
                    continue
                gyz = gz + gap(dy, yi, y_lo, cell[1])
                if gyz >= H2:
                    continue
                row = (cz * ny + cy) * nx
                left = 0
                while left < R and gyz + gap(-(left + 1), xi, x_lo, cell[0]) < H2:
                    left += 1
                right = 0
                while right < R and gyz + gap(right + 1, xi, x_lo, cell[0]) < H2:
                    right += 1
                lo = cb[row + max(ix - left, 0)]
                hi = ce[row + min(ix + right, nx - 1)]
                if mode == 3:
                    count += hi - lo
                    continue
                for j in range(lo, hi):
                    ddx = xi - x[j, 0]
                    ddy = yi - x[j, 1]
                    ddz = zi - x[j, 2]
                    inside = (ddx * ddx + ddy * ddy + ddz * ddz < H2) & (j != i)
                    if mode == 0:
                        nbr[i, min(count, cap)] = j
                        count += 1 if inside else 0
                    elif mode == 1:
                        if inside:
                            nbr[i, min(count, cap)] = j
                            count += 1
                    else:
                        count += 1 if inside else 0
        counts[i] = count

names = {0: "store every candidate (today)", 1: "store neighbours only (branch)", 2: "test, no store", 3: "ranges only"}
for R in (1, 2, 1, 2):
    g = G.Grid(g0.origin.astype(np.float64), g0.origin.astype(np.float64) + g0.ncell * g0.cell.astype(np.float64),
               float(np.sqrt(g0.H2)), (False,) * 3, np.float32, reach=R)
    g.bin(s)
    n = s.n_owned
    nbr = np.empty((n, g.capacity + 1), np.int32); counts = np.empty(n, np.int32)
    for mode in range(4):
        variant(mode, s.x, n, g.cell_begin, g.cell_end, g.origin, g.cell, g.inv_cell, g.ncell, R, g.H2, nbr, counts)
        t0 = time.perf_counter()
        for _ in range(5):
            variant(mode, s.x, n, g.cell_begin, g.cell_end, g.origin, g.cell, g.inv_cell, g.ncell, R, g.H2, nbr, counts)
        print(f"reach {R}: {names[mode]:32s} {1e3 * (time.perf_counter() - t0) / 5:6.1f} ms  (count mean {counts.mean():.1f})")
