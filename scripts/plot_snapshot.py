"""Plot a run's final.npz as side and top views coloured by speed (the pictures in docs/).

    .venv/bin/python scripts/plot_snapshot.py runs/db/final.npz docs/img/dam_break_3d.png --title "..."
"""
import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("final", type=Path, help="final.npz of a run (its summary.json is read if present)")
    ap.add_argument("png", type=Path, help="output image")
    ap.add_argument("--title", default=None)
    args = ap.parse_args()
    d = np.load(args.final)
    x, speed = d["x"], np.linalg.norm(d["v"], axis=1)
    summary = args.final.parent / "summary.json"
    info = json.loads(summary.read_text()) if summary.exists() else {}
    title = args.title or f"{info.get('scene', '')}  t = {info.get('sim_time', 0):.3g} s, {len(x)} particles"
    is_3d = np.ptp(x[:, 2]) > 0
    views = [("x", "y", 0, 1)] + ([("x", "z", 0, 2)] if is_3d else [])
    fig, axes = plt.subplots(1, len(views), figsize=(6 * len(views), 3.2), squeeze=False)
    lo, hi = x.min(axis=0), x.max(axis=0)
    for ax, (a, b, i, j) in zip(axes[0], views):
        order = np.argsort(x[:, 3 - i - j]) if is_3d else slice(None)
        sc = ax.scatter(x[order, i], x[order, j], c=speed[order], s=0.4, cmap="viridis", vmin=0,
                        vmax=np.percentile(speed, 99.5))
        ax.set_aspect("equal")
        ax.set_xlim(lo[i], hi[i])
        ax.set_ylim(lo[j], hi[j])
        ax.set_xlabel(f"{a} (m)")
        ax.set_ylabel(f"{b} (m)")
    fig.colorbar(sc, ax=axes[0].tolist(), label="speed (m/s)")
    fig.suptitle(title)
    args.png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.png, dpi=90, bbox_inches="tight")
    print(f"wrote {args.png}")


if __name__ == "__main__":
    main()
