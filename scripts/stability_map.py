"""Maps of stable and stopped runs over two knobs of the tiny scene (a drop hitting a pool), float64:
a fixed time step against the speed of sound (60 steps each), and the adaptive step's CFL number
against the speed of sound (150 steps each). Writes docs/img/stability_map.png and prints the grids;
docs/ACCURACY.md shows them.

    .venv/bin/python scripts/stability_map.py          # about a minute on 2 cores
"""
from pathlib import Path

import numpy as np

from sphcore.scene import load_scene
from sphcore.solver import Simulation, SimulationError

ROOT = Path(__file__).resolve().parent.parent

DTS = np.geomspace(1e-5, 1e-2, 10)
CFLS = np.geomspace(0.05, 2.0, 9)
SOUND = np.geomspace(1.0, 300.0, 10)
CAUSES = {"stable": 0, "CFL violation": 1, "speed of sound": 2, "density ratio": 3, "NaN or Inf": 4}


def outcome(dt, c0, steps=60, cfl=None):
    time_keys = (["time.mode='fixed'", f"time.dt={float(dt)!r}"] if cfl is None else
                 ["time.mode='adaptive'", f"time.cfl={float(cfl)!r}"])
    scene = load_scene(ROOT / "configs" / "tiny.toml", time_keys + [f"sph.sound_speed={float(c0)!r}"])
    sim = Simulation(scene, "f64")
    try:
        for _ in range(steps):
            sim.step()
    except SimulationError as e:
        return next(c for c in CAUSES if c in str(e)), sim.step_index
    return "stable", steps


def sweep(xs, label, run):
    grid = np.zeros((len(SOUND), len(xs)), dtype=int)
    print(label)
    for i, c0 in enumerate(SOUND):
        row = []
        for j, x in enumerate(xs):
            cause, step = run(x, c0)
            grid[i, j] = CAUSES[cause]
            row.append("." if cause == "stable" else f"{cause.split()[0][:4]}@{step}")
        print(f"c0 = {c0:7.2f} m/s: " + " ".join(f"{r:>10}" for r in row), flush=True)
    return grid


def main():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch
    fixed = sweep(DTS, "fixed dt (columns: " + ", ".join(f"{d:.2g}" for d in DTS) + " s)",
                  lambda dt, c0: outcome(dt, c0))
    adaptive = sweep(CFLS, "adaptive, CFL (columns: " + ", ".join(f"{c:.2g}" for c in CFLS) + ")",
                     lambda cfl, c0: outcome(None, c0, steps=150, cfl=cfl))
    colours = ["#4caf50", "#ffb300", "#e53935", "#8e24aa", "#212121"]
    cmap = ListedColormap(colours)
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 5))
    h = 0.5 * 2.3 * 0.0125
    ax.pcolormesh(DTS, SOUND, fixed, cmap=cmap, vmin=-0.5, vmax=len(CAUSES) - 0.5, shading="nearest")
    ax.plot(DTS, h / DTS, "w--", lw=1.5)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlim(DTS[0], DTS[-1])
    ax.set_ylim(SOUND[0], SOUND[-1])
    ax.set_xlabel("fixed time step dt (s)")
    ax.set_ylabel("speed of sound c0 (m/s)")
    ax.set_title("fixed step, 60 steps (dashes: dt = h / c0)")
    bx.pcolormesh(CFLS, SOUND, adaptive, cmap=cmap, vmin=-0.5, vmax=len(CAUSES) - 0.5, shading="nearest")
    bx.set_xscale("log")
    bx.set_yscale("log")
    bx.set_xlabel("adaptive step: CFL number")
    bx.set_ylabel("speed of sound c0 (m/s)")
    bx.set_title("adaptive step, 150 steps")
    handles = [Patch(color=c, label=n) for n, c in zip(CAUSES, colours)]
    bx.legend(handles=handles, fontsize=8, loc="upper left", facecolor="#dddddd")
    fig.suptitle("tiny scene (a drop hitting a pool at 1 m/s): stable, or stopped and by which diagnostic")
    fig.tight_layout()
    out = ROOT / "docs" / "img" / "stability_map.png"
    fig.savefig(out, dpi=100)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
