"""The cost of setting a run up at N particles, before its first step: seconds and the peak host
memory per particle (generating the lattice, the walls, the state), on the 3D dam break of sph bench.

    python scripts/bench_setup.py 10000000 [--precision f32|f64] [--neighbours walk|lists]

This is what sphcore.scene.HOST_BYTES_PER_PARTICLE["cuda"] rests on: with --backend cuda the host holds
this much, and the device the rest (sph bench prints device bytes per particle).
"""
import argparse
import time

from launch.bench import DEFAULT_SCENE, _fixed, _memory_kb, spacing_for
from sphcore.scene import load_scene
from sphcore.solver import Simulation


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("particles", type=int, help="target particle count")
    ap.add_argument("--precision", choices=("f32", "f64"), default="f32")
    ap.add_argument("--neighbours", choices=("walk", "lists"), default="walk")
    args = ap.parse_args()
    dx = spacing_for(DEFAULT_SCENE, args.particles)
    scene = load_scene(DEFAULT_SCENE, _fixed(DEFAULT_SCENE, dx) + [f"run.neighbours={args.neighbours!r}"], backend="cuda")
    before = _memory_kb("VmRSS")
    t0 = time.perf_counter()
    sim = Simulation(scene, args.precision, "cpu")
    seconds = time.perf_counter() - t0
    n = sim.n_particles
    print(f"{n} particles ({args.precision}): set-up {seconds:.2f} s, host peak {(_memory_kb('VmHWM') - before) * 1024 / n:.0f} "
          f"B/particle, held after {(_memory_kb('VmRSS') - before) * 1024 / n:.0f} B/particle")


if __name__ == "__main__":
    main()
