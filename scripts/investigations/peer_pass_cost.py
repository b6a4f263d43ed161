"""What does being a peer cost, free of another process and of waiting? Two peers of the 3D dam break
stepped in turn in one process (the in-process transport delivers at once) against one process of the
same particles, one numba thread, fixed dt: ms per step of each and the stage totals (summary.json's
names). Then each neighbour pass alone, called again and again on the arrays of the last step, in ns
per owned row (one process; each peer in one call and split as a step computes it); and the density
pass in ms: each peer's and the single process's, and each peer's once more after its positions
were copied into a fresh array (where the arrays lie in memory, not what they hold).

    .venv/bin/python scripts/investigations/peer_pass_cost.py [--spacing 0.00782973528233773] [--steps 60]

The default spacing is the bench's 197,676 particles; --spacing 0.012428930023815439 its 49,152."""
import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

import numba  # noqa: E402
import numpy as np  # noqa: E402

from nodes.cluster import InProcessCluster  # noqa: E402
from sphcore import stages as st  # noqa: E402
from sphcore.scene import load_scene  # noqa: E402
from sphcore.solver import Simulation  # noqa: E402


def median_ms(f, repeat=9):
    f()
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        f()
        times.append(time.perf_counter() - t)
    return 1e3 * float(np.median(times))


def density_ms(sim):
    prm = sim._ramped_params()
    return median_ms(lambda: sim.engine.run(st.DENSITY, prm=prm, dt_prev=sim.dtype.type(sim.dt_prev), commit=False))


def pass_per_row(one, cluster):
    """Each neighbour pass alone, called again and again on the arrays of the last step: ns per owned
    row in one process and in each peer, the peer's rows in one call and split into its interior and
    boundary rows as a step computes them (while a halo travels, then after)."""
    prm = one._ramped_params()

    def passes(sim, rows):
        f = sim.dtype.type
        return {"density": lambda: sim.engine.run(st.DENSITY, prm=prm, rows=rows, dt_prev=f(sim.dt_prev), commit=False),
                "filter": lambda: sim.grid.filter_neighbours(sim.state.x, sim.state.n_owned, rows),
                "forces": lambda: sim.engine.run(st.FORCES, prm=prm, rows=rows)}

    n1 = one.state.n_owned
    for name in ("density", "filter", "forces"):
        line = f"{name}: one process {1e6 * median_ms(passes(one, None)[name]) / n1:.0f} ns a row; peers"
        for sim, halo in zip(cluster.peers, cluster.halos):
            if sim.grid.skin == 0 and name == "filter":
                continue
            n = sim.state.n_owned
            interior, boundary = sim.engine.split_rows(halo.dec, halo.rank, halo.neighbours)
            whole = median_ms(passes(sim, None)[name])
            split = median_ms(passes(sim, interior)[name]) + median_ms(passes(sim, boundary)[name])
            line += f" {1e6 * whole / n:.0f} (split {1e6 * split / n:.0f}, {len(boundary)} boundary rows)"
        print(line + " ns a row")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spacing", type=float, default=0.00782973528233773)
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--overlap", choices=("true", "false"), default="true", help="decomposition.overlap")
    a = ap.parse_args()
    numba.set_num_threads(1)
    sc = load_scene(ROOT / "configs" / "dam_break.toml", ["time.mode='fixed'", "time.dt=1e-4",
                                                          f"particles.spacing={a.spacing}",
                                                          f"decomposition.overlap={a.overlap}"])
    one = Simulation(sc, "f32", "cpu")
    cluster = InProcessCluster(sc, 2, "f32", dims=(2, 1, 1))
    for _ in range(3):  # compiled, the first allocations done
        one.step()
        cluster.step()
    for sim in [one, *cluster.peers]:
        sim.timers.reset()
    for round_ in range(2):
        t0 = time.perf_counter()
        for _ in range(a.steps):
            one.step()
        t1 = time.perf_counter()
        for _ in range(a.steps):
            cluster.step()
        t2 = time.perf_counter()
        print(f"round {round_}: one process {1e3 * (t1 - t0) / a.steps:.1f} ms a step, two peers in turn "
              f"{1e3 * (t2 - t1) / a.steps:.1f} ({(t2 - t1) / (t1 - t0):.3f}x)")
    print("stage seconds, one process:", {k: round(v["total_s"], 3) for k, v in one.timers.summary().items()})
    for p in cluster.peers:
        print(f"stage seconds, a peer of {p.state.n_owned} rows + {p.state.n - p.state.n_owned} ghosts:",
              {k: round(v["total_s"], 3) for k, v in p.timers.summary().items()})
    pass_per_row(one, cluster)
    print(f"density pass alone: one process {density_ms(one):.2f} ms; peers "
          + ", ".join(f"{density_ms(p):.2f}" for p in cluster.peers) + " ms")
    for p in cluster.peers:
        p.state.x = p.state.x.copy()
    print("the peers again, their x copied into fresh arrays: " + ", ".join(f"{density_ms(p):.2f}" for p in cluster.peers)
          + " ms")


if __name__ == "__main__":
    main()
