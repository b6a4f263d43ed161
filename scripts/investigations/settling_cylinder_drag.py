"""Why the settling cylinder was slow, and what fixed it (docs/VALIDATION.md, "A cylinder settling
between two walls"): the scene with --set overrides, its mean settling speed over t = 0.2-0.3 s in
units of the terminal speed for a density difference of 1000 kg/m^3 and the drag F = mu U lambda of
the given reference. The case now runs the corrected difference form with shifting and the
traction's force (configs/settling_cylinder_2d.toml); the defaults are one override set away:

    .venv/bin/python scripts/investigations/settling_cylinder_drag.py                           # the case: 1.010
    .venv/bin/python scripts/investigations/settling_cylinder_drag.py --held                    # force / buoyancy 1.012
    .venv/bin/python scripts/investigations/settling_cylinder_drag.py --set obstacles[0].density=1000.0   # -0.004
    .venv/bin/python scripts/investigations/settling_cylinder_drag.py \
        --set "sph.pressure_gradient='symmetric'" --set "sph.body_force='reaction'" \
        --set terms.shifting=0.0                                                                # the defaults: 0.677

and, with those three overrides added (the defaults, 2026-12-05):

        --set sph.nu=2e-3                                                                       # 0.826
        --set "forces.gravity=[0.0, -0.981]" --set obstacles[0].density=11000.0                 # 0.997
        --lambda 29.1278 --area 2.5e-5 \
        --set 'obstacles[0].shape="box"' --set "obstacles[0].size=[0.005, 0.005]"             # a square: 0.628

(lambda 29.1278: the square's finite-element drag, a variant of faxen_fem_check.py with a square
hole of side 2a). A weight less buoyancy other than 1000 kg/m^3 x g0 x area reads as a speed
relative to that reference: a neutrally buoyant body's speed is in units of the case's U.
``--held`` holds the body (free across the channel only, where the flow pushes it neither way)
and prints the fluid's vertical force on it over the last 0.1 s in units of the buoyancy rho0 g pi a^2
(the defaults' reaction: 1.04; the uncorrected difference form's reaction 0.54-0.61, its traction
0.949; today 1.012). ``--profile OUT.npz`` also saves the particles' positions and velocities
over t = 0.25-0.3 s in units of the half-width and of the body's speed, for a comparison with the
finite elements.
"""
import argparse
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from launch.validate import faxen_drag  # noqa: E402
from sphcore.boundaries import table_end, wall_tables  # noqa: E402
from sphcore.choices import KERNELS  # noqa: E402
from sphcore.scene import load_scene  # noqa: E402
from sphcore.solver import Simulation  # noqa: E402

G0 = 9.81  # m/s^2: the case's gravity, which sets the reference speed


def around_the_body(sim, body_spec, body):
    """The held body's neighbourhood at the end: the vertical pressure gradient fitted in three layers
    of particles around it (p = c0 + c1 sin(theta) + c2 cos(theta); rho g in still water), how many
    particles lie within H above and below it, and the part of the body's force estimate that a
    uniform pressure makes through their arrangement: sum_i w_i n_i times the particles' mean pressure,
    w_i = theta_i m_i 2 rho0 G0(d_i) / rho_i^2 (physics/bodies.py's weights), over the buoyancy."""
    scene, n = sim.scene, sim.state.n_owned
    x, p, rho = sim.state.x[:n], sim.state.p[:n], sim.state.rho[:n]
    fill, m = sim.engine.scratch.fill[:n], sim.state.m[:n]
    dx, a, rho0 = scene.particles.spacing, body_spec.radius, scene.fluid.rest_density
    g = abs(scene.forces.gravity[1])
    centre = np.array(body_spec.center[:2]) + body.x[:2]
    r = np.hypot(x[:, 0] - centre[0], x[:, 1] - centre[1])
    ny, gap = (x[:, 1] - centre[1]) / r, r - a
    for lo, hi in ((0, 1), (1, 2), (2, 3)):
        shell = (gap > lo * dx) & (gap <= hi * dx)
        fit = np.linalg.lstsq(np.c_[np.ones(shell.sum()), ny[shell], (x[shell, 0] - centre[0]) / r[shell]],
                              p[shell], rcond=None)[0]
        print(f"  layer {lo}-{hi} spacings: {shell.sum()} particles, dp/dy {fit[1] / r[shell].mean():.0f} Pa/m "
              f"(rho0 g = {rho0 * g:.0f})")
    tables = wall_tables(KERNELS[scene.sph.kernel], scene.dim, sim.H, dx)
    G0 = np.interp(gap, np.linspace(0.0, table_end(sim.H, dx), tables.shape[1]), tables[1])
    near = gap < sim.H
    w = fill * m * 2.0 * rho0 * G0 / rho ** 2
    print(f"  within H: {np.count_nonzero(near & (ny > 0.5))} particles above the body, "
          f"{np.count_nonzero(near & (ny < -0.5))} below; sum w n_y x mean p ({p[near].mean():.0f} Pa) = "
          f"{np.sum((w * ny)[near]) * p[near].mean() / (rho0 * g * math.pi * a * a):+.3f} of the buoyancy")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--lambda", dest="lam", type=float, default=None,
                    help="the reference drag F / (mu U) (default: Faxen's for the scene's cylinder)")
    ap.add_argument("--area", type=float, default=None, help="the body's area in m^2 (default: pi a^2)")
    ap.add_argument("--until", type=float, default=0.3, help="simulated seconds (default 0.3)")
    ap.add_argument("--profile", type=Path, default=None)
    ap.add_argument("--held", action="store_true", help="hold the body: its force over buoyancy, not its speed")
    args = ap.parse_args()
    held = ["obstacles[0].free=[true, false]"] if args.held else []
    scene = load_scene(ROOT / "configs" / "settling_cylinder_2d.toml", [*held, *args.overrides])
    body_spec = scene.obstacles[0]
    half = 0.5 * scene.domain.size[0]
    lam = args.lam or faxen_drag(body_spec.radius / half)
    area = args.area or math.pi * body_spec.radius ** 2
    U = 1000.0 * G0 * area / (scene.fluid.rest_density * scene.sph.nu * lam)
    buoyancy = scene.fluid.rest_density * G0 * area
    sim = Simulation(scene, "f64")
    body = sim.model.walls.bodies[0]
    speeds, frames, body_speeds = [], [], []
    while sim.t < args.until:
        sim.step()
        if sim.t > args.until - 0.1:
            speeds.append(body.force[1] / buoyancy if args.held else -body.v[1] / U)
        if args.profile and sim.t > args.until - 0.05 and sim.step_index % 20 == 0:
            n = sim.state.n_owned
            centre = np.array(body_spec.center[:2]) + body.x[:2]
            frames.append(np.column_stack([(sim.state.x[:n, :2] - centre) / half, sim.state.v[:n, :2] / -body.v[1]]))
            body_speeds.append(-body.v[1])
    what = "force / buoyancy, the body held," if args.held else "speed / U"
    print(f"{' '.join(args.overrides) or '(the case)'}: mean {what} over t = {args.until - 0.1:g}-{args.until:g} s "
          f"{np.mean(speeds):.4f} (min {min(speeds):.3f}, max {max(speeds):.3f}); U = {1e3 * U:.3f} mm/s, "
          f"lambda = {lam:.4f}")
    if args.held:
        around_the_body(sim, body_spec, body)
    if args.profile:
        np.savez(args.profile, points=np.concatenate(frames), speed=np.mean(body_speeds), k=body_spec.radius / half)


if __name__ == "__main__":
    main()
