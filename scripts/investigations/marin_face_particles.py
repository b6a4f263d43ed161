"""MARIN's dam break against a box (configs/dam_break_obstacle.toml) at the quick spacing H0 / 15: what
the particles by the pressure sensors on the box's face (P1-P4) do after the surge has struck it.

    python scripts/investigations/marin_face_particles.py [SECTION.KEY=VALUE ...]

Steps the scene to t = 0.45 s (the impact peaks are at 0.415-0.459 s in the experiment), then every
step to 1.4 s records, for each sensor, the probe's reading and the particles within a support radius
of the sensor: how many, the share of them at p = 0 (the clamp: rho < rho0), their median rho / rho0,
and the nearest one's distance from the face in spacings. Prints each sensor's summary over the steps.
About 2 minutes with two threads. docs/VALIDATION.md (the MARIN section) quotes its output.
"""
import sys

import numpy as np

from launch.validate import CONFIGS, MARIN_SENSORS
from sphcore.scene import load_scene
from sphcore.solver import Simulation


def main(overrides):
    sc = load_scene(CONFIGS / "dam_break_obstacle.toml", list(overrides))
    sim = Simulation(sc)
    dx, rho0 = sc.particles.spacing, sc.fluid.rest_density
    names = sim.probes.names
    probes = {s: (names.index(s), np.array(sc.probes[names.index(s)].at)) for s in MARIN_SENSORS}
    while sim.t < 0.45:
        sim.step(dt_cap=0.45 - sim.t)
        sim.probes.take_samples()
    rows = {s: [] for s in MARIN_SENSORS}
    while sim.t < 1.4:
        sim.step(dt_cap=1.4 - sim.t)
        samples = sim.probes.take_samples()
        n = sim.state.n_owned
        x, rho, p = sim.state.x[:n], sim.state.rho[:n], sim.state.p[:n]
        for s, (k, at) in probes.items():
            near = np.linalg.norm(x - at, axis=1) < sim.H
            d = x[near, 0] - at[0]  # distance from the face, into the fluid (the water is on its +x side)
            rows[s].append((samples[-1][2][k], near.sum(), np.mean(p[near] == 0.0) if near.any() else np.nan,
                            np.median(rho[near]) / rho0 if near.any() else np.nan,
                            d.min() / dx if near.any() else np.nan))
    print(f"H0 / {0.55 / dx:.0f}, support {sim.H:.4f} m = {sim.H / dx:.2f} spacings; t = 0.45-1.4 s, "
          f"{len(rows['P1'])} steps")
    print("sensor  probe mean (Pa)  probe = 0 (share of steps)  particles in support  share at p = 0  "
          "median rho/rho0  nearest to the face (spacings: median, 10 %)")
    for s, r in rows.items():
        a = np.array(r, dtype=float)
        print(f"{s:6}  {a[:, 0].mean():15.0f}  {np.mean(a[:, 0] < 1.0):26.2f}  {np.nanmean(a[:, 1]):20.1f}  "
              f"{np.nanmean(a[:, 2]):14.2f}  {np.nanmedian(a[:, 3]):15.4f}  "
              f"{np.nanmedian(a[:, 4]):.2f}, {np.nanquantile(a[:, 4], 0.1):.2f}")


if __name__ == "__main__":
    main(sys.argv[1:])
