"""Best-of-K times of the grid, density and force stages and of a whole step, on the benchmark's 3D
dam break after a few steps: a comparison that stays meaningful on a shared machine (the best of
several calls drops the ones another process interrupted; run two trees one after the other).

    python scripts/bench_stages.py [--particles 50000] [--precision f32] [--threads 1]
                                   [--neighbours lists|walk|scene] [--tag NAME]

Prints one line: the stages' and the step's best times in ms and the particle-steps/s of the best step.
"""
import argparse
import time

import numba

from launch.bench import DEFAULT_SCENE, _fixed, spacing_for
from sphcore import stages as st
from sphcore.scene import load_scene
from sphcore.solver import Simulation


def best_ms(f, k: int) -> float:
    f()
    best = float("inf")
    for _ in range(k):
        t0 = time.perf_counter()
        f()
        best = min(best, time.perf_counter() - t0)
    return best * 1e3


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--particles", type=int, default=50_000)
    ap.add_argument("--precision", choices=("f32", "f64"), default="f32")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--neighbours", choices=("lists", "walk", "scene"), default="scene",
                    help="run.neighbours (scene: leave the scene's value, for trees that predate the key)")
    ap.add_argument("--repeat", type=int, default=12, help="calls per stage; the best counts")
    ap.add_argument("--tag", default="", help="a label for the line (the tree)")
    args = ap.parse_args()
    numba.set_num_threads(args.threads)
    overrides = _fixed(DEFAULT_SCENE, spacing_for(DEFAULT_SCENE, args.particles))
    if args.neighbours != "scene":
        overrides.append(f"run.neighbours={args.neighbours!r}")
    sim = Simulation(load_scene(DEFAULT_SCENE, overrides), args.precision)
    for _ in range(3):
        sim.step()
    e, prm = sim.engine, sim.prm_now
    grid = best_ms(e.bin, args.repeat)
    density = best_ms(lambda: e.run(st.DENSITY, prm=prm, dt_prev=sim.dtype.type(sim.dt_prev), commit=False),
                      args.repeat)
    forces = best_ms(lambda: e.run(st.FORCES, prm=prm), args.repeat)
    step = best_ms(sim.step, max(args.repeat // 2, 3))
    print(f"{args.tag:8s} {args.neighbours:5s} {args.precision} threads={args.threads} N={sim.n_particles} "
          f"grid {grid:6.2f} density {density:6.2f} forces {forces:6.2f} step {step:6.2f} ms "
          f"-> {sim.n_particles / step * 1e3:.3e} particle-steps/s (best step)")


if __name__ == "__main__":
    main()
