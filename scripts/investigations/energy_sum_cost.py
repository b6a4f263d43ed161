"""What one check of the energy watchdog costs (sphcore/health.py, physics/energy.py): the closed 3D
dam break of sph bench at N particles, the energy summed three times (the first compiles or loads
the stage).

    python scripts/investigations/energy_sum_cost.py 4000000 [--precision f32] [--backend cpu|cuda]

2026-12-04, 2-core development machine, f32, 4,018,768 particles: 39 ms a check as a stage, against
197-332 ms for the host sum it replaced (which, on a GPU, also downloaded the whole state first).
"""
import argparse
import time

from launch.bench import DEFAULT_SCENE, _fixed, spacing_for
from sphcore.halo import NULL_HALO
from sphcore.scene import load_scene
from sphcore.solver import Simulation


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("particles", type=int)
    ap.add_argument("--precision", choices=("f32", "f64"), default="f32")
    ap.add_argument("--backend", choices=("cpu", "cuda"), default="cpu")
    args = ap.parse_args()
    dx = spacing_for(DEFAULT_SCENE, args.particles)
    scene = load_scene(DEFAULT_SCENE, _fixed(DEFAULT_SCENE, dx), backend=args.backend)
    sim = Simulation(scene, args.precision, args.backend)
    for _ in range(3):
        t0 = time.perf_counter()
        check = sim.health._energy_sum(NULL_HALO, scene, "energy")
        try:
            next(check)
        except StopIteration as done:
            total = done.value
        print(f"{sim.n_particles} particles: energy {total:.10g} in {(time.perf_counter() - t0) * 1e3:.1f} ms")


if __name__ == "__main__":
    main()
