"""Does the dam-break's early front lead more at finer spacings because the column starts at p = 0?
A scene's particles start at rest density, so the column first falls under gravity until its
compression carries its weight (an acoustic transient of ~2a / c0). This script runs the case
(``sph validate dam_break``'s scene, with the carried density of ``sph.density = 'continuity'``, which
can start anywhere) from rest density and from the hydrostatic density of Tait's EOS, rho0 (1 +
rho0 g (H - y) / B)^(1/7), and prints the front Z = x / a at Martin & Moyce's early points (T <= 4.4,
the simulated clock + 0.175, as the case reads them) and their RMS relative error, with the mean
pressure at the floor after the first step.

    .venv/bin/python scripts/investigations/dam_break_hydrostatic_start.py 0.01 0.005 0.0025

About 3 minutes on 2 cores (the spacings in m; a = 0.2 m).
"""
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from launch.validate import MARTIN_MOYCE_SHIFT_T, MARTIN_MOYCE_T, MARTIN_MOYCE_Z, dam_break_scene  # noqa: E402
from sphcore.solver import Simulation  # noqa: E402

EARLY = MARTIN_MOYCE_T <= 4.5
TAIT_GAMMA = 7.0


def run(dx: float, start: str):
    """The early fronts and the floor's mean pressure after step 1 (in rho0 g H) from ``start``."""
    scene = dam_break_scene(dx, overrides=("sph.density='continuity'",))
    block = scene.fluid.blocks[0]
    a, H = block.max[0] - block.min[0], block.max[1]
    g, c0, rho0 = abs(scene.forces.gravity[1]), scene.sph.sound_speed, scene.fluid.rest_density
    scale = math.sqrt(2.0 * g / a)
    sim = Simulation(scene, "f64")
    n = sim.state.n_owned
    if start == "hydrostatic":
        p = rho0 * g * np.maximum(H - sim.state.x[:n, 1], 0.0)
        B = rho0 * c0 * c0 / TAIT_GAMMA
        sim.state.extra["density"][:n] = rho0 * (1.0 + p / B) ** (1.0 / TAIT_GAMMA)
    fronts, floor_p = [], None
    for T in MARTIN_MOYCE_T[EARLY] - MARTIN_MOYCE_SHIFT_T:  # the simulated clock + 0.175 = the experiment's
        while sim.t < T / scale:
            sim.step(dt_cap=T / scale - sim.t)
            if floor_p is None:
                s = sim.state
                bottom = s.x[:s.n_owned, 1] < 2 * dx
                floor_p = float(np.mean(s.p[:s.n_owned][bottom])) / (rho0 * g * H)
        x = sim.state.x[:sim.state.n_owned]
        fronts.append(x[x[:, 1] < 0.25 * a, 0].max() / a)
    return a, np.array(fronts), floor_p


def main():
    z_exp = MARTIN_MOYCE_Z[EARLY]
    for dx in [float(s) for s in sys.argv[1:]] or [0.01, 0.005, 0.0025]:
        for start in ("rest", "hydrostatic"):
            a, z, floor_p = run(dx, start)
            rms = float(np.sqrt(np.mean(((z - z_exp) / z_exp) ** 2)))
            print(f"a/{a / dx:.0f} {start:>11} (p at the floor after step 1: {floor_p:.3f} rho g H):",
                  " ".join(f"{v:5.2f}" for v in z), f" RMS {rms:.4f}", flush=True)


if __name__ == "__main__":
    main()
