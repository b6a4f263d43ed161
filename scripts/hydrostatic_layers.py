"""Where the settled 3D hydrostatic tank's pressure error sits: the error of each particle's pressure
(averaged over the last 0.5 s, as ``sph validate hydrostatic_3d`` does) against rho0 g (H - y), split
into the particle layers next to the floor, the side walls, the edges where two walls meet, and the
interior.

    python scripts/hydrostatic_layers.py [--dx 0.02] [--t-end 4.0]

Prints, per group, the number of particles, the largest |error| and the mean error, in units of
rho0 g H; the worst particle of each single sample (before averaging); then the five worst particles. The quick tank (dx = 0.02) takes about a minute on 2 cores.
"""
import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from launch.validate import CONFIGS, HYDROSTATIC_3D, settle_and_average  # noqa: E402
from sphcore.scene import load_scene  # noqa: E402
from sphcore.solver import Simulation  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dx", type=float, default=0.02, help="particle spacing in m (validate: 0.02 quick, 0.01 full)")
    ap.add_argument("--t-end", type=float, default=4.0, help="settling time in s (validate: 4)")
    args = ap.parse_args()
    dx = args.dx
    scene = load_scene(CONFIGS / "hydrostatic_2d.toml", [f"particles.spacing={dx}", *HYDROSTATIC_3D])
    rho0, g = scene.fluid.rest_density, abs(scene.forces.gravity[1])
    lo = np.array(scene.domain.center) - 0.5 * np.array(scene.domain.size)
    hi = np.array(scene.domain.center) + 0.5 * np.array(scene.domain.size)
    sim = Simulation(scene, "f64", "cpu")
    single = []  # each sample's worst particle, unaveraged: the acoustic noise the average removes

    def worst_of_one_sample(sim):
        s = sim.state
        y, p = s.x[: s.n_owned, 1], s.p[: s.n_owned]
        h = float(np.max(y)) + 0.5 * dx
        inside = y < h - 3 * dx
        single.append((sim.t, float(np.max(np.abs(p[inside] - rho0 * g * (h - y[inside])))) / (rho0 * g * h)))
    _, _, (pos, p, _), top = settle_and_average(sim, args.t_end, on_sample=worst_of_one_sample)
    x, y, z = pos.T
    H = top + 0.5 * dx
    below = y < H - 3 * dx  # the metric's particles: below the surface layer
    err = (p - rho0 * g * (H - y)) / (rho0 * g * H)
    near_x = np.minimum(x - lo[0], hi[0] - x) < 1.5 * dx
    near_z = np.minimum(z - lo[2], hi[2] - z) < 1.5 * dx
    floor = y - lo[1] < 1.5 * dx
    groups = [("all", below), ("floor layer", below & floor), ("x walls' layer", below & near_x & ~floor),
              ("z walls' layer", below & near_z & ~floor), ("edges (x and z walls)", below & near_x & near_z),
              ("interior", below & ~near_x & ~near_z & ~floor)]
    print(f"t = {sim.t:.2f} s, dx = {dx:g} m, H = {H:.4f} m, {sim.n_particles} particles; error in rho0 g H")
    for name, mask in groups:
        if mask.any():
            print(f"{name:24s} n = {int(mask.sum()):6d}  max |error| = {np.max(np.abs(err[mask])):.4f}"
                  f"  mean error = {np.mean(err[mask]):+.4f}")
    print("single samples' worst particle: " + ", ".join(f"{e:.4f} at {t:.2f} s" for t, e in single))
    for i in np.argsort(-np.abs(np.where(below, err, 0.0)))[:5]:
        print(f"  x = {x[i]:.3f}  y = {y[i]:.3f}  z = {z[i]:.3f}  error = {err[i]:+.4f}")


if __name__ == "__main__":
    main()
