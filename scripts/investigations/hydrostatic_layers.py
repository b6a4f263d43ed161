"""Where the settled 3D hydrostatic tank's pressure error sits. Each particle's pressure is averaged
over the last 0.5 s, as ``sph validate hydrostatic_3d`` does, and compared with rho0 g (H - y).

    python scripts/investigations/hydrostatic_layers.py [--dx 0.02] [--t-end 4.0] [--set KEY=VALUE ...]

Prints, in units of rho0 g H:
- per group (the particle layers next to the floor, the side walls, the edges where two walls meet,
  and the interior): the number of particles, the largest |error| and the mean error;
- the kinetic energy, as means over 0.5 s windows;
- the worst particle of each single sample, before averaging;
- the mean error of the 10 depth layers (the profile metric's), against rho0 g (H - y) and against
  the hydrostatic pressure of the simulated compressible fluid (dp/dy = -rho(p) g with the scene's
  Tait EOS; the difference is what the weak compressibility alone accounts for), with the scatter
  about the layer means;
- each particle row's mean error, and the five worst particles.

The quick tank (dx = 0.02) takes about a minute on 2 cores, the full one (--dx 0.01) 15 minutes.
"""
import argparse

import numpy as np

from launch.validate import CONFIGS, HYDROSTATIC_3D, depth_layers, settle_and_average
from sphcore.scene import load_scene
from sphcore.solver import Simulation


def tait_hydrostatic(y, H, rho0, c0, g, steps=20000):
    """Pressure at heights y of a Tait fluid (gamma = 7) at rest under gravity g with its surface at H:
    dp/dy = -g rho0 (1 + 7 p / (rho0 c0^2))^(1/7), integrated down from p(H) = 0 (midpoint rule)."""
    levels = np.linspace(H, min(0.0, float(np.min(y))), steps + 1)
    p = np.zeros_like(levels)
    B = rho0 * c0 * c0 / 7.0
    for k in range(steps):
        dy = levels[k] - levels[k + 1]
        half = p[k] + 0.5 * g * rho0 * (1.0 + p[k] / B) ** (1.0 / 7.0) * dy
        p[k + 1] = p[k] + g * rho0 * (1.0 + half / B) ** (1.0 / 7.0) * dy
    return np.interp(y, levels[::-1], p[::-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dx", type=float, default=0.02, help="particle spacing in m (validate: 0.02 quick, 0.01 full)")
    ap.add_argument("--t-end", type=float, default=4.0, help="settling time in s (validate: 4)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="scene override, as sph validate --set (e.g. sph.support=2.3)")
    args = ap.parse_args()
    dx = args.dx
    scene = load_scene(CONFIGS / "hydrostatic_2d.toml", [f"particles.spacing={dx}", *HYDROSTATIC_3D, *args.set])
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
    times, ke, (pos, p, _), top = settle_and_average(sim, args.t_end, on_sample=worst_of_one_sample)
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
    times, ke = np.asarray(times), np.asarray(ke)
    ends = np.arange(0.5, args.t_end + 1e-9, 0.5)
    print("kinetic energy (J), means over 0.5 s windows ending at: " + ", ".join(
        f"{t:g} s {np.mean(ke[(times > t - 0.5) & (times <= t)]):.2g}" for t in ends))
    print("single samples' worst particle: " + ", ".join(f"{e:.4f} at {t:.2f} s" for t, e in single))
    layer = depth_layers(y, H, dx)
    compressible = (p - tait_hydrostatic(y, H, rho0, scene.sph.sound_speed, g)) / (rho0 * g * H)
    for name, e in (("rho0 g (H - y)", err), ("compressible (Tait)", compressible)):
        means = np.array([np.mean(e[layer == k]) if np.any(layer == k) else 0.0 for k in range(10)])
        inside = below & (layer >= 0) & (layer < 10)
        scatter = float(np.std(e[inside] - means[layer[inside]]))
        print(f"depth layers' mean error, floor to surface, against {name}: "
              + " ".join(f"{v:+.4f}" for v in means) + f"; max |error| {np.max(np.abs(e[below])):.4f}; "
              f"scatter about the layer means {scatter:.4f} (std)")
    rows = np.floor(y / dx).astype(int)  # particle rows, floor up
    print("each particle row's mean error, floor up: "
          + " ".join(f"{np.mean(err[rows == r]):+.4f}" for r in range(rows.max() + 1) if np.any(rows == r)))
    for i in np.argsort(-np.abs(np.where(below, err, 0.0)))[:5]:
        print(f"  x = {x[i]:.3f}  y = {y[i]:.3f}  z = {z[i]:.3f}  error = {err[i]:+.4f}")


if __name__ == "__main__":
    main()
