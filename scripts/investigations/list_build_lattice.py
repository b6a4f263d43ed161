"""Is the list build cheap at the start of the dam break because the particles still sit on their
lattice? Times the build (1 thread, the bench's 49,152 particles after 20 steps) on the positions
as they are and with every coordinate moved by a uniform random amount of up to --jitter spacings,
and says how much of the sort order and of the neighbour sets that moved.

    .venv/bin/python scripts/investigations/list_build_lattice.py [--jitter 0.01 0.05 0.2]
"""
import argparse
import time

import numba
import numpy as np

from launch.bench import DEFAULT_SCENE, _fixed, spacing_for
from sphcore.scene import load_scene
from sphcore.solver import Simulation
from sphcore.state import ParticleState

NO_SKIN = ["run.neighbour_skin=0"]  # a list a step, as measured when this was written (grid.py)


def build(sim, x, ids, repeats=15):
    """(median build ms, ids in sorted order, neighbour id sets of every 97th row) on positions x."""
    # copies: the grid keeps the arrays it sorted from as next time's scratch
    state = ParticleState.create(ids.copy(), x.copy(), np.zeros_like(x), np.ones(len(ids)), x.dtype)
    grid = sim.grid
    grid.sort(state)
    n = state.n_owned
    grid.build_neighbours(state.x, n)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        grid.build_neighbours(state.x, n)
        times.append(time.perf_counter() - t0)
    sets = [frozenset(state.id[grid.nbr[i, :grid.counts[i]]]) for i in range(0, n, 97)]
    return 1e3 * float(np.median(times)), state.id.copy(), sets, float(grid.counts[:n].mean())


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--jitter", type=float, nargs="+", default=[0.01, 0.05, 0.2], help="in spacings")
    args = ap.parse_args()
    numba.set_num_threads(1)
    dx = spacing_for(DEFAULT_SCENE, 49152)
    sim = Simulation(load_scene(DEFAULT_SCENE, _fixed(DEFAULT_SCENE, dx) + NO_SKIN), "f32", "cpu")
    while sim.step_index < 20:
        sim.step()
    s = sim.state
    x0, ids = s.x[:s.n_owned].copy(), s.id[:s.n_owned].copy()
    ms, order0, sets0, found = build(sim, x0, ids)
    print(f"t = {sim.t:.4f} s, as is: build {ms:.2f} ms, {found:.1f} neighbours a particle")
    rng = np.random.default_rng(1)
    for amp in args.jitter:
        xj = (x0 + rng.uniform(-amp, amp, x0.shape) * dx).astype(x0.dtype)
        ms, order, sets, found = build(sim, xj, ids)
        same_sets = np.mean([a == b for a, b in zip(sets0, sets)])
        print(f"jitter {amp:g} dx: build {ms:.2f} ms, {found:.1f} neighbours; sort order the same for "
              f"{np.mean(order == order0):.0%} of the rows, neighbour sets for {same_sets:.0%}")


if __name__ == "__main__":
    main()
