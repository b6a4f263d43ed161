"""Plot the particles of one or more runs' final.npz side by side, coloured by speed (docs/TUTORIAL.md).

    python docs/tutorial/plot.py runs/splash_0 runs/splash_0.12 --out splash.png
"""
import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # no display needed
import matplotlib.pyplot as plt
import numpy as np


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="output folders of sph run")
    parser.add_argument("--out", type=Path, default=Path("splash.png"), help="the PNG to write")
    args = parser.parse_args()
    fig, axes = plt.subplots(1, len(args.runs), figsize=(3.2 * len(args.runs), 2.9), squeeze=False)
    for ax, run in zip(axes[0], args.runs):
        summary = json.loads((run / "summary.json").read_text())
        with np.load(run / "final.npz") as f:
            x, v = f["x"], f["v"]
        speed = np.linalg.norm(v, axis=1)
        dots = ax.scatter(x[:, 0], x[:, 1], c=speed, s=4, cmap="viridis", vmin=0.0, vmax=2.0)
        ax.set_title(f"t = {summary['sim_time']:.2f} s (step {summary['steps']})", fontsize=9)
        ax.set_xlim(0.0, 0.6)
        ax.set_ylim(0.0, 0.5)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=7)
    fig.colorbar(dots, ax=axes[0].tolist(), label="speed (m/s)", shrink=0.8)
    fig.savefig(args.out, dpi=110, bbox_inches="tight")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
