"""The density and force passes alone: each timed 15 times (median) at 1 and 2 threads on the 3D dam
break at 49,152 particles after 20 steps, float32 (docs/BENCHMARKS.md, "2026-12-05 (evening)"). The
figures there for a pass without its wall terms, or with one division fewer, came from this script
run on a scratch copy of the row function so changed (the wrong physics, to time it only).

    .venv/bin/python scripts/investigations/pass_times.py [--set KEY=VALUE ...]
"""
import argparse
import time

import numba
import numpy as np

from launch.bench import DEFAULT_SCENE, _fixed, spacing_for
from sphcore import stages as st
from sphcore.scene import load_scene
from sphcore.solver import Simulation


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a scene override")
    a = ap.parse_args()
    dx = spacing_for(DEFAULT_SCENE, 49152)
    sim = Simulation(load_scene(DEFAULT_SCENE, _fixed(DEFAULT_SCENE, dx) + a.set), "f32")
    for _ in range(20):
        sim.step()
    prm = sim._ramped_params()
    for threads in (1, 2):
        numba.set_num_threads(threads)
        for stage, extra in ((st.DENSITY, dict(dt_prev=sim.dtype.type(sim.dt_prev), commit=False)), (st.FORCES, {})):
            sim.engine.run(stage, prm=prm, **extra)
            times = []
            for _ in range(15):
                t0 = time.perf_counter()
                sim.engine.run(stage, prm=prm, **extra)
                times.append(time.perf_counter() - t0)
            print(f"{threads} thread(s): {stage.name} {np.median(times) * 1e3:.2f} ms")


if __name__ == "__main__":
    main()
