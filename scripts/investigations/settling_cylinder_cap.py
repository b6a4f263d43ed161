"""What is around the settling cylinder while it slows (docs/VALIDATION.md, settling_cylinder_closed):
every 0.05 s, the body's speed over Faxen's, the fluid's mean density and pressure range, the smallest gap between it and the particles ahead
(below, 60-120 degrees off the axis) and behind, and in three shells around it (0-1, 1-2 and 2-4
spacings from its surface) how many particles there are and how fast those ahead and behind move
along the axis, in units of the body's speed.

    .venv/bin/python scripts/investigations/settling_cylinder_cap.py      # closed box, quick spacing

Measured 2026-12-05: the fluid 2-4 spacings ahead moves at 0.64 of the body's speed at t = 0.05 s and
0.78 at 0.4 s while the body slows; the gap ahead shrinks from 0.49
to 0.39 spacings. ``--until 0.5``: the speed falls to 0.88 of Faxen's while the mean density creeps
from 1000.09 to 1000.43 kg/m^3 and the lowest pressure from -7 to +39 Pa (the speed is the mean over
each 0.05 s).
"""
import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from launch.validate import faxen_terminal_speed  # noqa: E402
from sphcore.scene import load_scene  # noqa: E402
from sphcore.solver import Simulation  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--scene", default=str(ROOT / "configs" / "settling_cylinder_closed_2d.toml"))
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--until", type=float, default=0.4, help="simulated seconds (default 0.4)")
    args = ap.parse_args()
    scene = load_scene(args.scene, args.overrides)
    ob = scene.obstacles[0]
    a, dx = ob.radius, scene.particles.spacing
    faxen = faxen_terminal_speed(scene)
    sim = Simulation(scene, "f64")
    body = sim.model.walls.bodies[0]
    report, speeds = 0.05, []
    while sim.t < args.until:
        sim.step()
        speeds.append(-body.v[1] / faxen)
        if sim.t < report:
            continue
        report += 0.05
        mean_speed, speeds = np.mean(speeds), []
        n = sim.state.n_owned
        x, v = sim.state.x[:n], sim.state.v[:n]
        c = np.array(ob.center[:2]) + body.x[:2]
        gap = np.hypot(x[:, 0] - c[0], x[:, 1] - c[1]) - a
        angle = np.degrees(np.arctan2(x[:, 1] - c[1], x[:, 0] - c[0]))
        ahead, behind = (angle < -60) & (angle > -120), (angle > 60) & (angle < 120)
        U = -body.v[1]
        shells = []
        for lo, hi in ((0, 1), (1, 2), (2, 4)):
            shell = (gap >= lo * dx) & (gap < hi * dx)
            shells.append(f"{lo}-{hi} dx: {shell.sum()} particles, ahead {np.mean(v[shell & ahead, 1]) / -U:.2f} U, "
                          f"behind {np.mean(v[shell & behind, 1]) / -U:.2f} U")
        rho, p = sim.state.rho[:n], sim.state.p[:n]
        print(f"t = {sim.t:.2f} s: speed {mean_speed:.3f} of Faxen's (its mean since the last line); mean density {rho.mean():.2f} kg/m^3, pressure "
              f"{p.min():.0f} to {p.max():.0f} Pa; gap ahead {gap[ahead].min() / dx:.2f} dx, "
              f"behind {gap[behind].min() / dx:.2f} dx | " + " | ".join(shells), flush=True)


if __name__ == "__main__":
    main()
