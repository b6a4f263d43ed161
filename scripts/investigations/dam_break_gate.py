"""Does a gate that opens in a finite time take away the dam break's resolution-dependent early
front? The case (``sph validate dam_break``'s scene, with its walls' friction) with a gate, a box
0.01 m thick against the column's face, lifted by 0.5 m over LIFT seconds from t = 0 (a moving
obstacle with a ``path``, docs/USAGE.md "Moving walls and floating bodies"), instead of an instant
release; the front Z = x / a at Martin & Moyce's early points (T <= 4.4) on the raw clock (the gate
stands for the release, so no shift), and their RMS relative error.

    .venv/bin/python scripts/investigations/dam_break_gate.py LIFT DX [DX ...]   # e.g. 0.1 0.01 0.005 0.0025

About 1.5 minutes on 2 cores for 0.1 0.01 0.005 0.0025.
"""
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from launch.validate import CONFIGS, LONG_TANK_2D, MARTIN_MOYCE_T, MARTIN_MOYCE_Z, martin_moyce_nu  # noqa: E402
from sphcore.scene import load_scene  # noqa: E402
from sphcore.solver import Simulation  # noqa: E402

EARLY = MARTIN_MOYCE_T <= 4.5
THICKNESS = 0.01  # m
A = 0.2           # m, the column's width in configs/dam_break_2d.toml


def gate_scene(dx: float, lift: float, folder: Path):
    """The case's scene with the gate (an [[obstacles]] entry appended to its TOML)."""
    text = (CONFIGS / "dam_break_2d.toml").read_text() + (
        f"\n[[obstacles]]\nshape = \"box\"\ncenter = [{A + 0.5 * THICKNESS + 0.5 * dx!r}, 0.25]\n"
        f"size = [{THICKNESS!r}, 0.5]\npath = [[0.0, 0.0, 0.0], [{lift!r}, 0.0, 0.5]]\n")
    path = folder / "dam_break_gate.toml"
    path.write_text(text)
    return load_scene(path, [f"particles.spacing={dx}", *LONG_TANK_2D, f"terms.wall_friction={martin_moyce_nu(A)!r}"])


def main():
    lift, spacings = float(sys.argv[1]), [float(s) for s in sys.argv[2:]]
    t_exp, z_exp = MARTIN_MOYCE_T[EARLY], MARTIN_MOYCE_Z[EARLY]
    with tempfile.TemporaryDirectory() as tmp:
        for dx in spacings:
            scene = gate_scene(dx, lift, Path(tmp))
            scale = math.sqrt(2.0 * abs(scene.forces.gravity[1]) / A)
            sim = Simulation(scene, "f64")
            fronts = []
            for T in t_exp:
                while sim.t < T / scale:
                    sim.step(dt_cap=T / scale - sim.t)
                x = sim.state.x[:sim.state.n_owned]
                fronts.append(x[x[:, 1] < 0.25 * A, 0].max() / A)
            fronts = np.array(fronts)
            rms = float(np.sqrt(np.mean(((fronts - z_exp) / z_exp) ** 2)))
            print(f"lift {lift} s, a/{A / dx:.0f}:", " ".join(f"{z:5.2f}" for z in fronts), f" raw RMS {rms:.4f}",
                  flush=True)


if __name__ == "__main__":
    main()
