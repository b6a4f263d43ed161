"""What Balsara's switch (sph.viscosity_switch = "balsara") costs a step: the bench's 3D dam break
(the spacing of ``sph bench --sizes 50000``, its fixed step), f32, 300 steps after 200, without and
with the switch in turn, each stage's time a step from the simulation's timers.

    NUMBA_NUM_THREADS=2 .venv/bin/python scripts/investigations/viscosity_switch_cost.py [--rounds 2]

About 1 minute a round on 2 cores, compiling included the first time.
"""
import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from launch.bench import _fixed, spacing_for  # noqa: E402
from sphcore.scene import load_scene  # noqa: E402
from sphcore.solver import Simulation  # noqa: E402

SCENE = ROOT / "configs" / "dam_break.toml"
WARM, TIMED = 200, 300


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=2, help="alternating rounds of the two runs")
    args = ap.parse_args()
    dx = spacing_for(SCENE, 50000)
    for rnd in range(args.rounds):
        for switch in ("none", "balsara"):
            sim = Simulation(load_scene(SCENE, [*_fixed(SCENE, dx), f"sph.viscosity_switch='{switch}'"]), "f32")
            for _ in range(WARM):
                sim.step()
            sim.timers.samples.clear()
            t0 = time.perf_counter()
            for _ in range(TIMED):
                sim.step()
            wall = time.perf_counter() - t0
            ms = {k: sum(v) / TIMED * 1e3 for k, v in sim.timers.samples.items()}
            print(f"round {rnd}, switch {switch}: {sim.state.n_owned} particles, {wall / TIMED * 1e3:.2f} ms a step; "
                  f"balsara {ms.get('balsara', 0.0):.2f}, forces {ms.get('forces', 0.0):.2f}, "
                  f"density {ms.get('density', 0.0):.2f} ms", flush=True)


if __name__ == "__main__":
    main()
