"""The grid's sort (cell keys, counting sort, per-bin id sort, cell ranges, the whole sort with the
gathers) and its list build with cells of H and of H / 2, on the same positions of the 3D dam break
(49,152 particles after two steps, 1 thread, float32; docs/BENCHMARKS.md, "Grid cells of H / 2").

    .venv/bin/python scripts/investigations/grid_sort_by_cell_size.py
"""
import time, numpy as np, numba
from launch.bench import DEFAULT_SCENE, _fixed, spacing_for
from sphcore import grid as G
from sphcore.scene import load_scene
from sphcore.solver import Simulation

NO_SKIN = ["run.neighbour_skin=0"]  # a list a step, as measured when this was written (grid.py)
numba.set_num_threads(1)
dx = spacing_for(DEFAULT_SCENE, 49152)
sim = Simulation(load_scene(DEFAULT_SCENE, _fixed(DEFAULT_SCENE, dx) + NO_SKIN), "f32", "cpu")
sim.step(); sim.step()
s = sim.state; g0 = sim.grid
def timed(f, k=10):
    f(); t0 = time.perf_counter()
    for _ in range(k): f()
    return 1e3 * (time.perf_counter() - t0) / k
for R in (1, 2, 1, 2):
    g = G.Grid(g0.origin.astype(np.float64), g0.origin.astype(np.float64) + g0.ncell * g0.cell.astype(np.float64),
               float(np.sqrt(g0.H2)), (False,) * 3, np.float32, reach=R)
    g.bin(s)
    g._ensure(s.n)
    t_keys = timed(lambda: G.compute_cell_keys(s.x, s.n_owned, g.origin, g.inv_cell, g.ncell, g._keys))
    t_scatter = timed(lambda: G._scatter_by_key(g._keys, g.bin_start, g._perm))
    t_id = timed(lambda: G._sort_bins_by_id(0, g._keys, g.bin_start, g._perm, s.id))
    t_ranges = timed(lambda: G._cell_ranges(g.bin_start, g.ncells, g.cell_begin, g.cell_end))
    t_sort = timed(lambda: g.sort(s))
    t_lists = timed(lambda: g.build_neighbours(s.x, s.n_owned), 3)
    print(f"reach {R}: keys {t_keys:.2f} scatter {t_scatter:.2f} id-sort {t_id:.2f} ranges {t_ranges:.2f} | whole sort {t_sort:.2f} | lists {t_lists:.1f} ms (1 thread)")
