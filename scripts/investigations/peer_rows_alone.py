"""Does a peer's filter cost more per row than a lone process's when nothing else runs between calls?
The bench's 3D dam break (49,152 particles, f32, 1 thread, skin 0.2) after 60 steps, as one process and
as two peers in this process (nodes/cluster.py, no Zenoh): the mean candidate count a row, then the
list filter timed back to back (median of 30 calls) over every row of each, over one process's rows
split at its median x as a peer splits them (interior, then boundary) and over the same rows (those
left of the median) at once. Three rounds.

    .venv/bin/python scripts/investigations/peer_rows_alone.py
"""
import time

import numba
import numpy as np

from launch.bench import DEFAULT_SCENE, _fixed, spacing_for
from nodes.cluster import InProcessCluster
from sphcore.scene import load_scene
from sphcore.solver import Simulation


def median_ms(grid, x, n, rows=None, calls=30) -> float:
    times = []
    for _ in range(calls):
        t0 = time.perf_counter()
        grid.filter_neighbours(x, n, rows)
        times.append(time.perf_counter() - t0)
    return float(np.median(times)) * 1e3


def main():
    numba.set_num_threads(1)
    dx = spacing_for(DEFAULT_SCENE, 49152)
    scene = load_scene(DEFAULT_SCENE, _fixed(DEFAULT_SCENE, dx) + ["decomposition.balance_every=0",
                                                                    "run.neighbour_skin=0.2"])
    one = Simulation(scene, "f32")
    cluster = InProcessCluster(scene, 2, "f32")
    for _ in range(60):
        one.step()
        cluster.step()
    for name, sim in (("one process", one), *((f"peer {r}", p) for r, p in enumerate(cluster.peers))):
        n = sim.state.n_owned
        print(f"{name}: {n} owned rows, {sim.state.n - n} ghosts, "
              f"{sim.grid.cand_counts[:n].mean():.2f} candidates a row")
    s, g, n = one.state, one.grid, one.state.n_owned
    xs = s.x[:n, 0].astype(np.float64)
    cut = float(np.median(xs))
    near = np.abs(xs - cut) < 2.0 * g.H2 ** 0.5
    interior = np.flatnonzero((xs < cut) & ~near).astype(np.int64)
    boundary = np.flatnonzero((xs < cut) & near).astype(np.int64)
    left = np.flatnonzero(xs < cut).astype(np.int64)
    for round_ in range(3):
        whole = median_ms(g, s.x, n)
        peers = [median_ms(p.grid, p.state.x, p.state.n_owned) for p in cluster.peers]
        print(f"round {round_ + 1}: one process {whole:.3f} ms (half {whole / 2:.3f}); peers' owned rows "
              f"{peers[0]:.3f}, {peers[1]:.3f}; one process's rows split as a peer's: interior "
              f"{median_ms(g, s.x, n, interior):.3f} + boundary {median_ms(g, s.x, n, boundary):.3f} ms; "
              f"the same rows at once {median_ms(g, s.x, n, left):.3f} ms")


if __name__ == "__main__":
    main()
