"""The grid sort and list build with cells of H and of H / 2 on the 3D dam break after it has
flowed to t = T (49,152 particles, 2 threads, float32; docs/BENCHMARKS.md, "Grid cells of H / 2").

    .venv/bin/python scripts/investigations/grid_by_cell_size_at.py 0.3
"""
import time, sys, numpy as np, numba
from launch.bench import DEFAULT_SCENE, _fixed, spacing_for
from sphcore import grid as G
from sphcore.scene import load_scene
from sphcore.solver import Simulation

NO_SKIN = ["run.neighbour_skin=0"]  # a list a step, as measured when this was written (grid.py)
numba.set_num_threads(2)
dx = spacing_for(DEFAULT_SCENE, 49152)
sim = Simulation(load_scene(DEFAULT_SCENE, _fixed(DEFAULT_SCENE, dx) + NO_SKIN), "f32", "cpu")
T = float(sys.argv[1])
while sim.t < T:
    sim.step()
s = sim.state
g0 = sim.grid
print("t", sim.t, "steps", sim.step_index)
for reach in (1, 2, 1, 2):
    g = G.Grid(g0.origin.astype(np.float64) , g0.origin.astype(np.float64) + g0.ncell * g0.cell.astype(np.float64) , float(np.sqrt(g0.H2)), (False,)*3, np.float32, reach=reach)
    # same box approx; bins
    g.bin(s)
    t0 = time.perf_counter()
    for _ in range(5):
        g.sort(s)
    t1 = time.perf_counter()
    for _ in range(5):
        g.build_neighbours(s.x, s.n_owned)
    t2 = time.perf_counter()
    print(f"reach {reach}: sort {1e3*(t1-t0)/5:.1f} ms, lists {1e3*(t2-t1)/5:.1f} ms, mean nbrs {g.counts[:s.n_owned].mean():.1f}, ncells {g.ncells}")
