"""Is the walls' friction in the dam break the stress a turbulent surge of that speed feels? The velocity
profile under the surge (the 2D case of `sph validate dam_break`, with its wall friction) against the
log law of the wall that the friction assumes.

The wall function (sphcore/physics/wall_friction.py) takes each near-wall particle's slip U_1 at
its distance y = dx / 2 and applies the stress rho u_tau^2 of Spalding's law through that point. In
a turbulent surge of depth h the log law's profile makes the first layer slower than the depth mean:
u(y) / u_tau = ln(y u_tau / nu) / kappa + B, whose mean over [0, h] is ln(h u_tau / nu) / kappa + B -
1 / kappa. This script reads, at T = 4, 5.5 and 7 (T = t sqrt(2 g / a)) and in sections 0.5, 1.5
and 3 a behind the front, the depth h, the depth-mean speed, the first layer's speed (particles
within dx of the floor), and prints:

- the first layer over the depth mean: the simulation's, and the log law's at the same depth-mean
  speed and depth;
- u_tau as the wall function applies it (from the first layer) and as the log law gives it for the
  depth mean (the depth-integrated law); their square's ratio is the stress ratio.

    .venv/bin/python scripts/investigations/dam_break_profile.py [--dx 0.005] [--threads 2]

dx = 0.005 (a / 40, the full case) takes about 4 minutes with 2 threads; 0.01 (quick) under one.
"""
import argparse
import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

import numba  # noqa: E402

from launch.validate import dam_break_scene  # noqa: E402
from sphcore.physics.wall_friction import B_SMOOTH, KAPPA  # noqa: E402
from sphcore.solver import Simulation  # noqa: E402

TIMES_T = (4.0, 5.5, 7.0)
BEHIND_A = (0.5, 1.5, 3.0)  # a section [front - (b + 0.5) a, front - b a]


def bisect(f, lo, hi, steps=200):
    """The root of an increasing f in [lo, hi]."""
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if f(mid) < 0.0 else (lo, mid)
    return 0.5 * (lo + hi)


def spalding_u_plus(R):
    """u+ of Spalding's law with u+ y+ = R (wall_friction.spalding_u_plus, here in float64 by bisection)."""
    k, e = KAPPA, math.exp(-KAPPA * B_SMOOTH)
    return bisect(lambda u: u * (u + e * (math.exp(k * u) - 1 - k * u - (k * u) ** 2 / 2 - (k * u) ** 3 / 6)) - R,
                  1e-9, 300.0)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dx", type=float, default=0.005, help="particle spacing in m (a = 0.2 m)")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    numba.set_num_threads(args.threads)
    scene = dam_break_scene(args.dx)
    nu = scene.terms.wall_friction
    dx = scene.particles.spacing
    a = scene.fluid.blocks[0].max[0] - scene.fluid.blocks[0].min[0]
    scale = math.sqrt(2.0 * abs(scene.forces.gravity[1]) / a)
    k = KAPPA
    sim = Simulation(scene, "f64")
    print(f"dx = a/{a / dx:.0f}, nu = {nu:.4g} m^2/s; first layer = particles within dx of the floor")
    print("T     behind  h (dx)  depth mean (m/s)  first layer / mean: SPH  log law   u_tau: applied  depth law"
          "  stress ratio")
    for T in TIMES_T:
        while sim.t < T / scale:
            sim.step(dt_cap=T / scale - sim.t)
        n = sim.state.n_owned
        x, v = sim.state.x[:n], sim.state.v[:n]
        front = x[x[:, 1] < 0.25 * a, 0].max()
        for b in BEHIND_A:
            sec = (x[:, 0] > front - (b + 0.5) * a) & (x[:, 0] < front - b * a)
            y, u = x[sec, 1], v[sec, 0]
            h = y.max() + 0.5 * dx
            mean = float(u.mean())
            first = float(u[y < dx].mean())
            applied = first / spalding_u_plus(0.5 * dx * first / nu)
            depth_law = bisect(lambda ut: ut * (math.log(h * ut / nu) / k + B_SMOOTH - 1 / k) - mean, 1e-5, 10.0)
            log_ratio = (math.log(0.5 * dx * depth_law / nu) / k + B_SMOOTH) / (
                math.log(h * depth_law / nu) / k + B_SMOOTH - 1 / k)
            print(f"{T:<5} {b:<6}  {h / dx:6.1f}  {mean:16.3f}  {first / mean:23.3f}  {log_ratio:7.3f}"
                  f"  {applied:14.4f}  {depth_law:9.4f}  {(applied / depth_law) ** 2:12.3f}", flush=True)


if __name__ == "__main__":
    main()
