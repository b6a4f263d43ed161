"""Are the wave maker's heights (sph validate wave_maker, a 2 m flume) those of a steady wave train?
The same piston in a 4 m flume, gauges at 0.3, 0.5, 1.0 and 1.5 m, the first-harmonic height
(launch.validate.harmonic) over two windows, 3-7 T and 6-10 T, and the phase speed over the 0.5 m
between the 0.5 m and 1.0 m gauges (k 0.5 m = 5.1 rad: one valued).

    .venv/bin/python scripts/investigations/wave_maker_long_flume.py [--spacing 0.00667] [--set KEY=VALUE ...]

About 5 minutes on 2 cores at the default (the validation's quick) spacing.
"""
import argparse
import math

import numpy as np


from launch.validate import CONFIGS, PistonWave, Simulation, harmonic, load_scene, probe_record
from sphcore.scene import scene_from_dict

GAUGES = (0.3, 0.5, 1.0, 1.5)
WINDOWS_T = ((3, 7), (6, 10))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spacing", type=float, default=0.1 / 15, help="particle spacing in m (depth 0.1 m)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a scene override (repeatable), e.g. sph.viscosity=morris")
    ap.add_argument("--ramp", type=float, default=0.0, metavar="PERIODS",
                    help="instead of X = A (1 - cos wt), drive the piston along a path table X = A r(t) sin wt with "
                         "r rising from 0 to 1 over this many periods (0.5 (1 - cos pi t / t_ramp)): no mean displacement, "
                         "so no long-wave step")
    args = ap.parse_args()
    base = load_scene(CONFIGS / "wave_maker_2d.toml", [f"particles.spacing={args.spacing}", "fluid.blocks[0].max=[4.0,0.1]",
                                                       "domain.bounds_max=[4.0,0.25]", "domain.planes[1].point=[4.0,0.0]",
                                                       *args.set])
    data = base.to_dict()
    data["probes"] = [{"name": f"G{x:g}", "kind": "height", "at": [x, 0.0]} for x in GAUGES]
    wave = PistonWave.of(scene_from_dict(data, source=base.source))
    if args.ramp > 0:
        piston = next(p for p in data["domain"]["planes"] if p.get("frequency", 0.0) > 0.0)
        A = wave.stroke / 2
        t_ramp = args.ramp * wave.period
        ts = np.linspace(0.0, WINDOWS_T[-1][1] * wave.period + 0.5, int(40 * (WINDOWS_T[-1][1] + 2)) + 1)
        r = np.where(ts < t_ramp, 0.5 * (1.0 - np.cos(np.pi * ts / t_ramp)), 1.0)
        piston.update(amplitude=[0.0, 0.0], frequency=0.0, phase=0.0,
                      path=[[t, A * ri * math.sin(wave.omega * t), 0.0] for t, ri in zip(ts, r)])
    scene = scene_from_dict(data, source=base.source)
    sim = Simulation(scene, "f64")
    print(f"{sim.n_particles} particles, 4 m flume, H of linear theory {100 * wave.height:.2f} cm"
          f"{', ' + ', '.join(args.set) if args.set else ''}{f', ramp {args.ramp:g} T' if args.ramp else ''}", flush=True)
    rec = probe_record(sim, WINDOWS_T[-1][1] * wave.period)
    t = rec[:, 0]
    print("| window | " + " | ".join(f"H / H_theory at {x:g} m" for x in GAUGES) + " | c, 0.5-1.0 m (theory "
          f"{wave.omega / wave.k:.3f} m/s) |")
    print("|---|" + "---|" * (len(GAUGES) + 1))
    for lo, hi in WINDOWS_T:
        w = (t >= lo * wave.period - 1e-9) & (t <= hi * wave.period + 1e-9)
        fits = [harmonic(t[w], rec[w, 1 + j] - wave.depth, wave.omega) for j in range(len(GAUGES))]
        c = wave.omega * (GAUGES[2] - GAUGES[1]) / ((fits[2][1] - fits[1][1]) % (2.0 * math.pi))
        print(f"| {lo}-{hi} T | " + " | ".join(f"{2 * a / wave.height:.3f}" for a, _ in fits) + f" | {c:.3f} |",
              flush=True)


if __name__ == "__main__":
    main()
