"""Where did the Taylor-Green vortex lose its speed? max |v| over its exact value at t = 0.1 s for
the old setting (support 2.3 spacings, no shifting), one change at a time, and the shipped one, all
at dx = 0.02 unless said (docs/VALIDATION.md quotes the output).

    .venv/bin/python scripts/investigations/probe_taylor_green.py        # about 2 minutes on 2 cores
"""
import math
from pathlib import Path

import numpy as np

from sphcore.scene import load_scene
from sphcore.solver import Simulation

ROOT = Path(__file__).resolve().parents[2]

OLD = ["sph.support=2.3", "terms.shifting=0.0"]  # the scene before the support and shifting changes
CASES = [("support 2.3 (dx = 0.02)", OLD), ("support 2.3, dx = 0.01", OLD + ["particles.spacing=0.01"]),
         ("support 2.3, nearly inviscid", OLD + ["sph.nu=1e-7"]), ("support 2.3, c0 = 40 m/s", OLD + ["sph.sound_speed=40.0"]),
         ("support 3", ["sph.support=3.0", "terms.shifting=0.0"]), ("support 4", ["sph.support=4.0", "terms.shifting=0.0"]),
         ("support 4, shifting 8 (shipped)", [])]


def ratio_at(overrides, t_end=0.1):
    scene = load_scene(ROOT / "configs" / "taylor_green_2d.toml", ["particles.spacing=0.02"] + overrides)
    sim = Simulation(scene, "f64")
    b = -8.0 * math.pi**2 * scene.sph.nu
    v0 = np.max(np.linalg.norm(sim.state.v, axis=1))
    while sim.t < t_end:
        sim.step(dt_cap=t_end - sim.t)
    v = np.max(np.linalg.norm(sim.synchronised_velocity()[: sim.state.n_owned, :2], axis=1))
    return v / v0 / math.exp(b * sim.t)


if __name__ == "__main__":
    for name, overrides in CASES:
        print(f"{name:<24} max|v| / exact at t = 0.1 s: {ratio_at(overrides):.3f}", flush=True)
