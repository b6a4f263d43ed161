"""What the hydrostatic scene's support radius costs and buys: the quick 3D tank (``sph validate
hydrostatic_3d --quick``) at 2.3 and at 3 spacings, interleaved and repeated so that both see the
same machine load. Prints steps, stepping wall time (first step excluded), time per step and the
single-particle pressure error per run.

    python scripts/investigations/hydrostatic_support.py [--repeats 2] [--supports 2.3 3.0]

About 5 minutes on 2 cores with the defaults.
"""
import argparse
from pathlib import Path

from launch.validate import CaseOptions, hydrostatic


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=2, help="rounds of runs, each support once per round")
    ap.add_argument("--supports", type=float, nargs="+", default=[2.3, 3.0], help="support radii in spacings")
    args = ap.parse_args()
    for _ in range(args.repeats):
        for support in args.supports:
            opts = CaseOptions(overrides=(f"sph.support={support}",), plot=False)
            error = hydrostatic(True, Path("."), opts=opts, dim=3)[0].value
            st = opts.stats
            print(f"support {support:g}: {st['steps']} steps, {st['wall_s']:.1f} s, "
                  f"{1e3 * st['wall_s'] / st['steps']:.2f} ms/step, single-particle error {error:.4f}", flush=True)


if __name__ == "__main__":
    main()
