"""The 2D dam-break case (``sph validate dam_break``) at any spacing, in several orders of its sums
(``launch.validate.run_orders``, as ``sph validate --orders K`` runs it at the case's own spacings):
each metric's mean over the orders, the spread and every order's figure.

    python scripts/investigations/dam_break_orders.py [--spacing 0.0025] [--orders 4] [--out DIR] \\
        [--set SECTION.KEY=VALUE ...]

a = 0.2 m: 0.01 = a/20 (the quick case), 0.005 = a/40 (the full case), 0.0025 = a/80 (12,800
particles, about 4 minutes a run on 2 cores).
"""
import argparse
import logging
from pathlib import Path

from launch.validate import ORDERS, run_orders


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spacing", type=float, default=0.0025, help="particle spacing in m (a = 0.2 m)")
    ap.add_argument("--orders", type=int, default=4, choices=range(1, len(ORDERS) + 1),
                    help="how many orders of the sums")
    ap.add_argument("--out", type=Path, default=Path("runs/dam_break_orders"), help="folder for the plots")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="a scene override for every run (repeatable), after the case's own")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s", datefmt="%H:%M:%S")
    args.out.mkdir(parents=True, exist_ok=True)
    print(f"dam break at a/{0.2 / args.spacing:.0f}, {args.orders} orders of its sums"
          + (f"; overrides {' '.join(args.set)}" if args.set else ""))
    for m in run_orders("dam_break", False, args.out, "cpu", tuple(args.set), args.orders, dx=args.spacing):
        print(m.line(), flush=True)


if __name__ == "__main__":
    main()
