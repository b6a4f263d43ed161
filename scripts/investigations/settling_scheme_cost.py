"""What the settling cylinder's scheme costs a step (docs/VALIDATION.md): the case (the corrected
difference form, shifting, the traction) against the defaults (symmetric, reaction, no shifting),
300 steps each from rest, the stage timers' medians. Measured 2026-12-06 (1 thread, the quick
spacing): the traction 0.375 ms a step, the case's step 4.85 ms, its force pass 1.87 ms; the
reaction 0.291 ms, the defaults' step 3.09 ms, their force pass 0.91 ms.

    NUMBA_NUM_THREADS=1 .venv/bin/python scripts/investigations/settling_scheme_cost.py
"""
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from sphcore.scene import load_scene  # noqa: E402
from sphcore.solver import Simulation  # noqa: E402

for body_force in ("traction", "reaction"):
    ov = [] if body_force == "traction" else ["sph.pressure_gradient='symmetric'", "sph.body_force='reaction'",
                                              "terms.shifting=0.0"]
    sim = Simulation(load_scene(ROOT / "configs" / "settling_cylinder_2d.toml", ov), "f64")
    for _ in range(300):
        sim.step()
    t = sim.timers.summary()
    step = sum(v["median_s"] * v["calls"] / 300 for v in t.values())
    key = "body_traction" if body_force == "traction" else "body_reaction"
    print(f"{body_force}: {key} {t[key]['median_s'] * 1e3 * t[key]['calls'] / 300:.3f} ms a step (medians), "
          f"the step {step * 1e3:.2f} ms, the forces pass {t['forces']['median_s'] * 1e3:.3f} ms")
