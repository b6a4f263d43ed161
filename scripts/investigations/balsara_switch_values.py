"""What Balsara's switch f reads in the 2D dam break: the case of ``sph validate dam_break`` (3 m
tank, the walls' friction) at a/40 with ``sph.viscosity_switch = "balsara"``, f's mean, median and
quartiles over the particles at T = 0.5, 1, 2, 4, 6, and its mean within 0.03 m of the floor.

    .venv/bin/python scripts/investigations/balsara_switch_values.py [--spacing 0.005]

About 1 minute on one core. docs/VALIDATION.md, the dam break ("Balsara's switch").
"""
import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from launch.validate import dam_break_scene  # noqa: E402
from sphcore.solver import Simulation  # noqa: E402

A, G = 0.2, 9.81  # the column's width (m) and gravity: T = t sqrt(2 g / a)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spacing", type=float, default=0.005, help="particle spacing in m (a = 0.2 m)")
    args = ap.parse_args()
    sim = Simulation(dam_break_scene(args.spacing, overrides=("sph.viscosity_switch='balsara'",)), "f64")
    print(f"floor 1e-4 c0 / h = {1e-4 * sim.prm.c0 / sim.prm.h:.3f} 1/s")
    for T in (0.5, 1.0, 2.0, 4.0, 6.0):
        while sim.t * math.sqrt(2 * G / A) < T:
            sim.step()
        n = sim.state.n_owned
        f = sim.engine.scratch.balsara[:n]
        low = sim.state.x[:n, 1] < 0.03
        print(f"T = {T}: f mean {f.mean():.3f}, median {np.median(f):.3f}, quartiles {np.percentile(f, 25):.3f}-"
              f"{np.percentile(f, 75):.3f}; within 0.03 m of the floor: mean {f[low].mean():.3f}", flush=True)


if __name__ == "__main__":
    main()
