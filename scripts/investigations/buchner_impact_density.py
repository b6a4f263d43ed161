"""Buchner's dam break (configs/dam_break_pressure_2d.toml) at the quick spacing H / 40: the density
of the fluid before and after the surge reaches the downstream wall, and the particles by the lower
pressure sensor P1 at t* = 2.8 (t* = t sqrt(g / H)), where the experiment reads its impact peak.

    python scripts/investigations/buchner_impact_density.py [SECTION.KEY=VALUE ...]

About 40 s with one thread. docs/VALIDATION.md (the Buchner section) quotes its output.
"""
import math
import sys

import numpy as np

from launch.validate import CONFIGS
from sphcore.scene import load_scene
from sphcore.solver import Simulation


def main(overrides):
    sc = load_scene(CONFIGS / "dam_break_pressure_2d.toml", ["particles.spacing=0.015", *overrides])
    H = sc.fluid.blocks[0].max[1] - sc.fluid.blocks[0].min[1]  # the column's height
    g = abs(sc.forces.gravity[1])
    rho0 = sc.fluid.rest_density
    wall = sc.domain.center[0] + 0.5 * sc.domain.size[0]       # the downstream wall's x
    p1 = next(p for p in sc.probes if p.name == "P1").at       # the lower sensor
    sim = Simulation(sc, "f64")
    scale = math.sqrt(g / H)

    def q(a):
        return " ".join(f"{v:.4f}" for v in np.quantile(a, [0.01, 0.1, 0.5, 0.9]))

    for t_star in (0.5, 1.0, 1.5, 2.0, 2.4, 2.8):
        while sim.t * scale < t_star:
            sim.step(dt_cap=t_star / scale - sim.t)
        s = sim.state
        n = s.n_owned
        x, rho, p = s.x[:n], s.rho[:n] / rho0, s.p[:n] / (rho0 * g * H)
        front = x[:, 0] > x[:, 0].max() - 0.5
        print(f"t*={t_star}: all rho/rho0 q01/10/50/90 {q(rho)} | front 0.5 m ({front.sum()}): {q(rho[front])} "
              f"p* median {np.median(p[front]):.3f} | front tip x={x[:, 0].max():.2f}", flush=True)
    s = sim.state
    n = s.n_owned
    for k in np.argsort(s.rho[:n])[:15]:
        print(f"rho/rho0 {s.rho[k] / rho0:.4f} x {s.x[k, 0]:.3f} y {s.x[k, 1]:.3f} "
              f"v ({s.v[k, 0]:+.2f},{s.v[k, 1]:+.2f}) wall dist {wall - s.x[k, 0]:.4f}")
    near = (s.x[:n, 0] > wall - 0.06) & (np.abs(s.x[:n, 1] - p1[1]) < 0.06)
    print("near P1:", near.sum(), "rho/rho0", np.round(s.rho[:n][near] / rho0, 4))
    print("near P1 y:", np.round(s.x[:n, 1][near], 3))
    print("near P1 wall distance:", np.round(wall - s.x[:n, 0][near], 3))


if __name__ == "__main__":
    main(sys.argv[1:])
