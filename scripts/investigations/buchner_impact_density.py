"""Buchner's dam break (configs/dam_break_pressure_2d.toml) at the quick spacing H / 40: the density
of the fluid before and after the surge reaches the downstream wall, and the particles by the lower
pressure sensor P1 at t* = 2.8 (t* = t sqrt(g / H)), where the experiment reads its impact peak.

    python scripts/investigations/buchner_impact_density.py [SECTION.KEY=VALUE ...]

About 40 s with one thread. docs/VALIDATION.md (the Buchner section) quotes its output.
"""
import sys, math, numpy as np
from launch.validate import CONFIGS
from sphcore.scene import load_scene
from sphcore.solver import Simulation
over = sys.argv[1:]
sc = load_scene(CONFIGS / "dam_break_pressure_2d.toml", ["particles.spacing=0.015", *over])
sim = Simulation(sc, "f64")
scale = math.sqrt(9.81 / 0.6)
for t_star in (0.5, 1.0, 1.5, 2.0, 2.4, 2.8):
    while sim.t * scale < t_star:
        sim.step(dt_cap=t_star / scale - sim.t)
    s = sim.state; n = s.n_owned
    x, rho, p = s.x[:n], s.rho[:n] / 1000.0, s.p[:n] / (1000 * 9.81 * 0.6)
    front = x[:, 0] > x[:, 0].max() - 0.5
    q = lambda a: " ".join(f"{v:.4f}" for v in np.quantile(a, [0.01, 0.1, 0.5, 0.9]))
    print(f"t*={t_star}: all rho/rho0 q01/10/50/90 {q(rho)} | front 0.5 m ({front.sum()}): {q(rho[front])} "
          f"p* median {np.median(p[front]):.3f} | front tip x={x[:,0].max():.2f}", flush=True)
s = sim.state; n = s.n_owned
order = np.argsort(s.rho[:n])[:15]
for k in order:
    print(f"rho/rho0 {s.rho[k]/1000:.4f} x {s.x[k,0]:.3f} y {s.x[k,1]:.3f} v ({s.v[k,0]:+.2f},{s.v[k,1]:+.2f}) wall dist {3.22-s.x[k,0]:.4f}")
near = (s.x[:n,0] > 3.22 - 0.06) & (np.abs(s.x[:n,1] - 0.16) < 0.06)
print("near P1:", near.sum(), "rho/rho0", np.round(s.rho[:n][near]/1000, 4))
print("near P1 y:", np.round(s.x[:n,1][near],3)); print("near P1 x:", np.round(3.22-s.x[:n,0][near],3))
