"""A square log held at its floating draft (configs/floating_square_2d.toml at 0.02 m, tilted 5 degrees,
free to drift sideways only), t = 0.6-1.0 s: the fluid's vertical force on it against its weight
(196.2 N/m, the buoyancy of that draft) and the torque at t = 1.0 s against the flat waterline's
0.283 N (hydrostatics of the tilted square; at this spacing the tilt moves the waterline by less
than half a spacing, so no estimate resolves it well).

    .venv/bin/python scripts/investigations/held_square_force.py                       # the reaction: 198 N/m
    .venv/bin/python scripts/investigations/held_square_force.py --set "sph.body_force='traction'" \\
        --set "sph.pressure_gradient='difference'" --set terms.shifting=2.0            # 195 N/m

Measured 2026-12-06: the reaction 197.7 N/m (torque +0.445 N); the traction with the difference form
195.0 (+0.037). The traction with the symmetric form (a checkout of 228f3ed, before the scene refused
it): 265.1 N/m (-0.324 N): the particles under the body carried 1,400-1,500 Pa against the
hydrostatic 1,000.
"""
import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from sphcore.halo import NULL_HALO  # noqa: E402
from sphcore.scene import load_scene  # noqa: E402
from sphcore.solver import Simulation  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    scene = load_scene(ROOT / "configs" / "floating_square_2d.toml",
                       ["particles.spacing=0.02", "obstacles[0].free=[true, false]",
                        "obstacles[0].free_rotation=[false, false, false]", *args.overrides])
    sim = Simulation(scene, "f64")
    body = sim.model.walls.bodies[0]
    forces = []
    while sim.t < 1.0:
        sim.step()
        if sim.t > 0.6:
            forces.append(body.force[1])
    gen = sim._body_forces(NULL_HALO, sim._ramped_params())  # the torque too (a body that does not turn keeps none)
    try:
        while True:
            next(gen)
    except StopIteration as done:
        _, torque = done.value[0]
    print(f"{' '.join(args.overrides) or '(the defaults)'}: mean vertical force over t = 0.6-1.0 s "
          f"{np.mean(forces):.1f} N/m (weight 196.2); torque at t = 1.0 s {torque[2]:+.3f} N (flat waterline +0.283)")


if __name__ == "__main__":
    main()
