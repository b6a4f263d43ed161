"""Buchner's dam break (configs/dam_break_pressure_2d.toml) at the quick spacing H / 40: where is the
pressure by the downstream wall while the surge turns up it? For t* = 2.6, 2.8, 3.0, 3.2
(t* = t sqrt(g / H)), the particles in boxes by the wall (height band x distance from the wall):
their count, rho / rho0 (min / median / max), p* = p / (rho g H) (median, max) and median velocity.

    python scripts/investigations/buchner_corner_pressure.py [SECTION.KEY=VALUE ...]

About 40 s with one thread. docs/VALIDATION.md (the Buchner section) quotes its output.
"""
import math
import sys

import numpy as np

from launch.validate import CONFIGS
from sphcore.scene import load_scene
from sphcore.solver import Simulation

HEIGHTS = ((0.0, 0.05), (0.05, 0.1), (0.1, 0.2), (0.2, 0.3), (0.3, 0.5), (0.5, 0.8))  # m above the floor
FROM_WALL = ((0.0, 0.03), (0.03, 0.06), (0.06, 0.12), (0.12, 0.25))                    # m from the wall


def main(overrides):
    sc = load_scene(CONFIGS / "dam_break_pressure_2d.toml", ["particles.spacing=0.015", *overrides])
    H = sc.fluid.blocks[0].max[1] - sc.fluid.blocks[0].min[1]  # the column's height
    g = abs(sc.forces.gravity[1])
    rho0 = sc.fluid.rest_density
    wall = sc.domain.center[0] + 0.5 * sc.domain.size[0]       # the downstream wall's x
    sim = Simulation(sc, "f64")
    scale = math.sqrt(g / H)
    for t_star in (2.6, 2.8, 3.0, 3.2):
        while sim.t * scale < t_star:
            sim.step(dt_cap=t_star / scale - sim.t)
        s = sim.state
        n = s.n_owned
        x, v = s.x[:n], s.v[:n]
        rho, p = s.rho[:n] / rho0, s.p[:n] / (rho0 * g * H)
        print(f"--- t* = {t_star}")
        for y0, y1 in HEIGHTS:
            for d0, d1 in FROM_WALL:
                box = (wall - x[:, 0] >= d0) & (wall - x[:, 0] < d1) & (x[:, 1] >= y0) & (x[:, 1] < y1)
                where = f"  y {y0:.2f}-{y1:.2f} m, {d0:.2f}-{d1:.2f} m from the wall:"
                if not box.any():
                    print(where, "-")
                    continue
                print(where, f"n={box.sum():3d} rho/rho0 {rho[box].min():.3f}/{np.median(rho[box]):.3f}/"
                      f"{rho[box].max():.3f} p* median {np.median(p[box]):.3f} max {p[box].max():.3f} "
                      f"u {np.median(v[box, 0]):+.2f} v {np.median(v[box, 1]):+.2f} m/s", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
