"""Decomposition invariance at full size: the 3D dam break run as 1, 2, 3 and 4 peer processes
(slabs) and 2x2x1 blocks, load balancing on, must write bitwise identical final.npz files.

    .venv/bin/python scripts/check_invariance.py [--steps 150] [--out runs/invariance] [--set KEY=VALUE ...]

Prints one line per layout (wall time, cuts moved, bytes against the halo minimum) and exits 1 if
any final.npz differs from the single-process one. docs/BENCHMARKS.md quotes its output.
"""
import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
LAYOUTS = [(1, None), (2, None), (3, None), (4, None), (4, "[2, 2, 1]")]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "invariance")
    parser.add_argument("--config", default="configs/dam_break.toml")
    parser.add_argument("--set", dest="overrides", action="append", default=[])
    args = parser.parse_args()
    reference, ok = None, True
    for peers, dims in LAYOUTS:
        name = f"{peers}_peers" + (f"_{dims.strip('[]').replace(', ', 'x')}" if dims else "")
        out = args.out / name
        cmd = [sys.executable, "-m", "launch.cli", "run", args.config, "--peers", str(peers), "--precision", "f64",
               "--steps", str(args.steps), "--out", str(out), "--quiet", "--set", "decomposition.balance_every=25"]
        for o in args.overrides:
            cmd += ["--set", o]
        if dims:
            cmd += ["--set", f"decomposition.dims={dims}"]
        t0 = time.perf_counter()
        subprocess.run(cmd, cwd=ROOT, check=True)
        wall = time.perf_counter() - t0
        final = np.load(out / "final.npz")
        summary = json.loads((out / "summary.json").read_text())
        if reference is None:
            reference = final
            same = True
        else:
            same = all(np.array_equal(final[k], reference[k]) for k in ("id", "x", "v", "rho"))
        ok &= same
        extra = ""
        if peers > 1:
            moved = sum(p["rebalances"] for p in summary["per_peer"]) // peers
            extra = (f"  rebalances {moved}, cuts {summary['per_peer'][0]['cuts']}, "
                     f"bytes {summary['bytes_over_minimum']:.3f}x the halo minimum")
        print(f"{name:>16}: {summary['particles']} particles, {summary['steps']} steps, wall {wall:6.1f} s, "
              f"final.npz {'IDENTICAL' if same else 'DIFFERS'}{extra}", flush=True)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
