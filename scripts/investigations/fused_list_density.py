"""Would writing the neighbour lists in the density pass save a pass? A prototype outside the stage
machinery: the list builder's loops (grid.neighbour_row: rows of cells, each one range, no periodic
axis) with the fluid part of the density sum (Wendland C2, no walls) added for each neighbour,
against the builder followed by a density loop over the lists, on the same positions (the 3D dam
break at 49,152 particles after 20 steps, float32, 1 thread); "branch-free" sums W over every
candidate (W(H) = 0) instead of branching on the neighbour test. Prints the times (median of 15)
twice, and checks that the fused lists equal the builder's. The stage-machinery version, a third
value of the neighbours choice whose spans are the runs of cells, measured slower than the
builder (docs/BENCHMARKS.md, "2026-12-05 (evening)"; scripts/investigations/listing_walk.patch).

    .venv/bin/python scripts/investigations/fused_list_density.py
"""
import math
import time

import numba
import numpy as np
from numba import njit, prange
from launch.bench import DEFAULT_SCENE, _fixed, spacing_for
from sphcore import grid as G
from sphcore.scene import load_scene
from sphcore.solver import Simulation

NO_SKIN = ["run.neighbour_skin=0"]  # a list a step, as measured when this was written (grid.py)
numba.set_num_threads(1)
dx = spacing_for(DEFAULT_SCENE, 49152)
sim = Simulation(load_scene(DEFAULT_SCENE, _fixed(DEFAULT_SCENE, dx) + NO_SKIN), "f32", "cpu")
for _ in range(20): sim.step()
s, g = sim.state, sim.grid
prm = sim._ramped_params()
H = np.float32(prm.H); s_w = np.float32(prm.s_w); w0 = np.float32(prm.w0)

@njit(inline="always")
def wend(r, H, s_w):
    q = r / H
    t = np.float32(1.0) - q
    t2 = t * t
    return s_w * t2 * t2 * (np.float32(1.0) + np.float32(4.0) * q)

@njit(parallel=True, fastmath={"arcp", "contract", "nsz", "reassoc"})
def density_over_list(x, m, nbr, counts, n, H, s_w, w0, rho):
    for k in prange(n):
        i = np.int64(k)
        r_i = m[i] * w0
        for c in range(counts[i]):
            j = nbr[i, c]
            ddx = x[i, 0] - x[j, 0]; ddy = x[i, 1] - x[j, 1]; ddz = x[i, 2] - x[j, 2]
            r = math.sqrt(ddx * ddx + ddy * ddy + ddz * ddz)
            r_i += m[j] * wend(r, H, s_w)
        rho[i] = r_i

@njit(inline="always")
def scan_fused(i, lo, hi, x, m, xi, yi, zi, H2, H, s_w, nbr, count, cap, acc):
    for j in range(lo, hi):
        ddx = xi - x[j, 0]; ddy = yi - x[j, 1]; ddz = zi - x[j, 2]
        r2 = ddx * ddx + ddy * ddy + ddz * ddz
        inside = r2 < H2
        nbr[i, min(count, cap)] = j
        count += 1 if inside else 0
        if inside:
            acc += m[j] * wend(math.sqrt(r2), H, s_w)
    return count, acc

@njit(inline="always")
def scan_fused_bf(i, lo, hi, x, m, xi, yi, zi, H2, H, s_w, nbr, count, cap, acc):
    for j in range(lo, hi):
        ddx = xi - x[j, 0]; ddy = yi - x[j, 1]; ddz = zi - x[j, 2]
        r2 = ddx * ddx + ddy * ddy + ddz * ddz
        inside = r2 < H2
        nbr[i, min(count, cap)] = j
        count += 1 if inside else 0
        r = math.sqrt(min(r2, H2))
        acc += m[j] * wend(r, H, s_w)   # W(H) = 0: outside adds 0
    return count, acc

def make(scan):
    @njit(parallel=True, fastmath={"arcp", "contract", "nsz", "reassoc"})
    def fused(x, m, n_query, cell_begin, cell_end, origin, cell, inv_cell, ncell, reach, H2, H, s_w, w0, nbr, counts, rho):
        for k in prange(n_query):
            i = np.int64(k)
            nx, ny, nz = ncell[0], ncell[1], ncell[2]
            cap = nbr.shape[1] - 1
            xi, yi, zi = x[i, 0], x[i, 1], x[i, 2]
            ix = min(max(int((xi - origin[0]) * inv_cell[0]), 0), nx - 1)
            iy = min(max(int((yi - origin[1]) * inv_cell[1]), 0), ny - 1)
            iz = min(max(int((zi - origin[2]) * inv_cell[2]), 0), nz - 1)
            x_lo = origin[0] + np.float32(ix) * cell[0]
            y_lo = origin[1] + np.float32(iy) * cell[1]
            z_lo = origin[2] + np.float32(iz) * cell[2]
            count = 0
            acc = m[i] * w0
            for dz in range(-reach, reach + 1):
                cz = iz + dz
                if cz < 0 or cz >= nz: continue
                gz = G._face_gap2(dz, zi, z_lo, cell[2])
                if gz >= H2: continue
                for dy in range(-reach, reach + 1):
                    cy = iy + dy
                    if cy < 0 or cy >= ny: continue
                    gyz = gz + G._face_gap2(dy, yi, y_lo, cell[1])
                    if gyz >= H2: continue
                    row = (cz * ny + cy) * nx
                    left = 0
                    while left < reach and gyz + G._face_gap2(-(left + 1), xi, x_lo, cell[0]) < H2: left += 1
                    right = 0
                    while right < reach and gyz + G._face_gap2(right + 1, xi, x_lo, cell[0]) < H2: right += 1
                    lo = max(ix - left, 0); hi = min(ix + right, nx - 1)
                    a, b = cell_begin[row + lo], cell_end[row + hi]
                    if a <= i < b:
                        count, acc = scan(i, a, i, x, m, xi, yi, zi, H2, H, s_w, nbr, count, cap, acc)
                        count, acc = scan(i, i + 1, b, x, m, xi, yi, zi, H2, H, s_w, nbr, count, cap, acc)
                    else:
                        count, acc = scan(i, a, b, x, m, xi, yi, zi, H2, H, s_w, nbr, count, cap, acc)
            counts[i] = count
            rho[i] = acc
    return fused

fused, fused_bf = make(scan_fused), make(scan_fused_bf)
n = s.n_owned
rho1 = np.zeros(n, np.float32); rho2 = np.zeros(n, np.float32); rho3 = np.zeros(n, np.float32)
nbr2 = np.empty_like(g.nbr); counts2 = np.empty_like(g.counts)
def t(f, rep=15):
    f(); ts = []
    for _ in range(rep):
        t0 = time.perf_counter(); f(); ts.append(time.perf_counter() - t0)
    return np.median(ts) * 1e3
args = (g.cell_begin, g.cell_end, g.origin, g.cell, g.inv_cell, g.ncell, g.reach, g.H2)
for _ in range(2):
    tb = t(lambda: g.build_neighbours(s.x, n))
    td = t(lambda: density_over_list(s.x, s.m, g.nbr, g.counts, n, H, s_w, w0, rho1))
    tf = t(lambda: fused(s.x, s.m, n, *args, H, s_w, w0, nbr2, counts2, rho2))
    tbf = t(lambda: fused_bf(s.x, s.m, n, *args, H, s_w, w0, nbr2, counts2, rho3))
    print(f"build {tb:.2f} + density {td:.2f} = {tb+td:.2f} ms; fused (branch) {tf:.2f}; fused (branch-free) {tbf:.2f}")
print("lists equal:", np.array_equal(counts2[:n], g.counts[:n]), "rho max rel diff", np.max(np.abs(rho2 - rho1) / rho1), np.max(np.abs(rho3 - rho1) / rho1))
