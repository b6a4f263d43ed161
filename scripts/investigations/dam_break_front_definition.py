"""Does the dam-break front lead more at finer spacings because single particles run ahead of the
surge? The case's front (``sph validate dam_break``) is the furthest particle within a/4 of the
floor; this script follows the same runs and reads, besides it, two fronts that one particle or a
few cannot set:

- ``k-th``: the 5th furthest particle within a/4 of the floor;
- ``bulk``: the end of the chain of those particles, ordered by x, whose gaps stay under 2 dx,
  grown from the one furthest back (a particle separated from the chain by more than two spacings,
  or behind such a gap, is spray).

For each spacing it prints Z = x / a at Martin & Moyce's early points (T <= 4.4), with the
literature's fixed shift T + 0.175 (as the case reads them), and the RMS of the relative error over
those points for each front.

    .venv/bin/python scripts/investigations/dam_break_front_definition.py [--spacings 0.01 0.005 0.0025]

About 3 minutes on 2 cores with the defaults (dx = a/80 takes 2 of them).
"""
import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from launch.validate import MARTIN_MOYCE_SHIFT_T, MARTIN_MOYCE_T, MARTIN_MOYCE_Z, dam_break_scene  # noqa: E402
from sphcore.solver import Simulation  # noqa: E402

EARLY = MARTIN_MOYCE_T <= 4.5
KTH = 5


def fronts(x, a, dx):
    low = x[:, 1] < 0.25 * a
    xs = np.sort(x[low, 0])
    if len(xs) == 0:
        return (math.nan,) * 3
    gaps = np.diff(xs)
    breaks = np.nonzero(gaps > 2.0 * dx)[0]
    bulk = xs[breaks[0]] if len(breaks) else xs[-1]
    return xs[-1] / a, xs[max(len(xs) - KTH, 0)] / a, bulk / a


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spacings", type=float, nargs="*", default=[0.01, 0.005, 0.0025])
    args = ap.parse_args()
    t_exp, z_exp = MARTIN_MOYCE_T[EARLY], MARTIN_MOYCE_Z[EARLY]
    print("T (experiment):", " ".join(f"{t:6.2f}" for t in t_exp))
    print("Z (experiment):", " ".join(f"{z:6.2f}" for z in z_exp))
    for dx in args.spacings:
        scene = dam_break_scene(dx)
        a = scene.fluid.blocks[0].max[0] - scene.fluid.blocks[0].min[0]
        scale = math.sqrt(2.0 * abs(scene.forces.gravity[1]) / a)
        sim = Simulation(scene, "f64")
        rows = []
        for T in t_exp - MARTIN_MOYCE_SHIFT_T:  # the simulated clock + 0.175 = the experiment's
            while sim.t < T / scale:
                sim.step(dt_cap=T / scale - sim.t)
            rows.append(fronts(sim.state.x[:sim.state.n_owned], a, dx))
        rows = np.array(rows)
        for k, name in enumerate(("furthest", f"{KTH}th", "bulk")):
            rms = float(np.sqrt(np.mean(((rows[:, k] - z_exp) / z_exp) ** 2)))
            print(f"a/{a / dx:.0f} {name:>8}:", " ".join(f"{z:6.2f}" for z in rows[:, k]), f"  RMS {rms:.4f}")


if __name__ == "__main__":
    main()
