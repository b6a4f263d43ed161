"""Where does a peer's step go, against half of one process's? Two peers of the 3D dam break
(49,152 particles, float32, 1 thread, the 2-peer benchmark's case) run in this one process, round
robin over the in-process transport (nodes/cluster.py; not rebalanced: in one process a peer's time
is not its own), so that each peer's kernels and numpy bookkeeping can be timed without the other
process's noise; then one process alone. Wrapped and
timed: the list build, the sorts, each stage's launch (interior and boundary rows apart), the halo's
state rebuilds and row packing. The halo's generator phases (exchange_positions, receive_ghosts,
reduce_max) are timed inclusively and include the other peer's work: they are printed, not summed.
Waiting on and sending over Zenoh are not here (a real run's summary.json has its waits).

    .venv/bin/python scripts/investigations/peer_step_breakdown.py [--steps 200] [--set KEY=VALUE ...]
"""
import argparse
import collections
import time

import numba

from launch.bench import DEFAULT_SCENE, _fixed, spacing_for
from nodes.cluster import InProcessCluster
from sphcore import grid as grid_mod, halo as halo_mod
from sphcore.backends import cpu
from sphcore.scene import load_scene
from sphcore.solver import Simulation

T = collections.defaultdict(float)


def wrap(cls, name):
    f = getattr(cls, name)

    def timed(*args, **kw):
        t0 = time.perf_counter()
        out = f(*args, **kw)
        T[name] += time.perf_counter() - t0
        return out
    setattr(cls, name, timed)


def wrap_generator(cls, name):
    f = getattr(cls, name)

    def timed(*args, **kw):
        t0 = time.perf_counter()
        out = yield from f(*args, **kw)
        T["(incl.) " + name] += time.perf_counter() - t0
        return out
    setattr(cls, name, timed)


def part_of(rows, n_owned):
    """' (interior rows)' or ' (boundary rows)' for a peer's pass over part of its rows (the boundary
    rows are about 1 in 8 here), '' for a pass over all."""
    if rows is None or rows.shape[0] == 0:
        return ""
    return " (interior rows)" if rows.shape[0] > n_owned // 2 else " (boundary rows)"


def wrap_lists(name):
    """Time Grid.<name>(x, n_query, rows=None), interior and boundary rows apart."""
    f = getattr(grid_mod.Grid, name)

    def timed(self, x, n_query, rows=None):
        t0 = time.perf_counter()
        out = f(self, x, n_query, rows)
        T[name + part_of(rows, n_query)] += time.perf_counter() - t0
        return out
    setattr(grid_mod.Grid, name, timed)


def instrument():
    for name in ("build_neighbours", "build_candidates", "filter_neighbours"):
        wrap_lists(name)
    for name in ("sort", "sort_ghosts"):
        wrap(grid_mod.Grid, name)
    for name in ("rebuild", "append_ghosts", "zone_rows", "split_rows", "rows_of", "set_rows"):
        wrap(cpu.CpuStages, name)
    wrap(halo_mod.PeerHalo, "_send")
    for name in ("exchange_positions", "receive_ghosts", "reduce_max"):
        wrap_generator(halo_mod.PeerHalo, name)
    launch = cpu.CpuStages.launch

    def timed_launch(self, stage, choices, n, rows, arguments, wait):
        t0 = time.perf_counter()
        out = launch(self, stage, choices, n, rows, arguments, wait)
        T["stage " + stage.name + part_of(rows, self.sim.state.n_owned)] += time.perf_counter() - t0
        return out
    cpu.CpuStages.launch = timed_launch


def report(title, per, steps):
    print(title)
    for k, v in sorted(T.items(), key=lambda kv: -kv[1]):
        print(f"  {k:34s} {v / steps / per * 1e3:7.3f} ms")
    T.clear()


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a scene override")
    a = ap.parse_args()
    numba.set_num_threads(1)
    dx = spacing_for(DEFAULT_SCENE, 49152)
    scene = load_scene(DEFAULT_SCENE, _fixed(DEFAULT_SCENE, dx) + ["decomposition.balance_every=0", "run.neighbour_skin=0"] + a.set)
    instrument()
    cluster = InProcessCluster(scene, 2, "f32")
    wall = timed_steps(cluster.step, a.steps)
    owned = [p.state.n_owned for p in cluster.peers]
    ghosts = [p.state.n - p.state.n_owned for p in cluster.peers]
    report(f"2 peers in one process: {wall / a.steps / 2 * 1e3:.2f} ms a step per peer (owned {owned}, "
           f"ghosts {ghosts}); per peer-step:", 2, a.steps)
    wall = timed_steps(Simulation(scene, "f32").step, a.steps)
    report(f"1 process: {wall / a.steps * 1e3:.2f} ms a step, half of it {wall / a.steps / 2 * 1e3:.2f}; "
           "per half-step:", 2, a.steps)


def timed_steps(step, steps: int) -> float:
    """Seconds for ``steps`` steps after 50 untimed ones (compiling, the first lists), the timers cleared."""
    for _ in range(50):
        step()
    T.clear()
    t0 = time.perf_counter()
    for _ in range(steps):
        step()
    return time.perf_counter() - t0

if __name__ == "__main__":
    main()
