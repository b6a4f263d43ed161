"""The wave maker's flume (configs/wave_maker_2d.toml) with and without its damping zone, and with
the summation or the carried density: first-harmonic heights at three gauges (0.3, 0.5 and 0.8 m)
over three windows, the phase speed between neighbouring gauges, and the incident and reflected
waves split from all three (least squares, Goda & Suzuki's method with k of linear theory).

    .venv/bin/python scripts/investigations/wave_maker_damping.py [--spacing 0.00667] [--rate 20]
        [--set KEY=VALUE ...]

--rate 0 drops the damping zone (the bare far wall of the case before 2026-12-05). About 1 min at
the quick spacing (15 over the depth) on one thread, 3 min at 20, 8 min at 30.
"""
import argparse
import math

from launch.validate import (CONFIGS, PistonWave, Simulation, harmonic, incident_and_reflected, load_scene,
                             probe_record)
from sphcore.scene import scene_from_dict

GAUGES = (0.3, 0.5, 0.8)
WINDOWS_T = ((3, 7), (4, 8), (6, 10))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spacing", type=float, default=0.1 / 15, help="particle spacing in m (depth 0.1 m)")
    ap.add_argument("--rate", type=float, default=20.0, help="the damping zone's rate (1/s; 0: no zone)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a scene override (repeatable)")
    args = ap.parse_args()
    base = load_scene(CONFIGS / "wave_maker_2d.toml", [f"particles.spacing={args.spacing}", *args.set])
    data = base.to_dict()
    data["probes"] = [{"name": f"G{x:g}", "kind": "height", "at": [x, 0.0]} for x in GAUGES]
    if args.rate > 0:
        data["damping_zones"][0]["rate"] = args.rate
    else:
        data["damping_zones"] = []
    scene = scene_from_dict(data, source=base.source)
    wave = PistonWave.of(scene)
    sim = Simulation(scene, "f64")
    print(f"{sim.n_particles} particles, density {scene.sph.density}, damping rate {args.rate:g} / s"
          f"{', ' + ', '.join(args.set) if args.set else ''}; H of linear theory {100 * wave.height:.2f} cm, "
          f"c = {wave.omega / wave.k:.3f} m/s", flush=True)
    rec = probe_record(sim, WINDOWS_T[-1][1] * wave.period)
    t = rec[:, 0]
    c_theory = wave.omega / wave.k
    print("| window | " + " | ".join(f"H / H_theory at {x:g} m" for x in GAUGES)
          + " | c / c_theory, 0.3-0.5 m | 0.5-0.8 m | incident H / H_theory | reflected / incident |")
    print("|---|" + "---|" * (len(GAUGES) + 4))
    for lo, hi in WINDOWS_T:
        w = (t >= lo * wave.period - 1e-9) & (t <= hi * wave.period + 1e-9)
        fits = [harmonic(t[w], rec[w, 1 + j] - wave.depth, wave.omega) for j in range(len(GAUGES))]
        speeds = [wave.omega * (GAUGES[j + 1] - GAUGES[j]) / ((fits[j + 1][1] - fits[j][1]) % (2.0 * math.pi))
                  for j in range(len(GAUGES) - 1)]
        a_i, a_r = incident_and_reflected(fits, GAUGES, wave.k)
        print(f"| {lo}-{hi} T | " + " | ".join(f"{2 * a / wave.height:.3f}" for a, _ in fits) + " | "
              + " | ".join(f"{c / c_theory:.3f}" for c in speeds)
              + f" | {2 * a_i / wave.height:.3f} | {a_r / a_i:.3f} |", flush=True)


if __name__ == "__main__":
    main()
