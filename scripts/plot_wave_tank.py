"""Picture of a wave tank's damping zone (docs/USAGE.md, "Damping zones"): two runs of the piston wave
maker at the same time, one ending in its damping zone and one in a bare wall. Top: the first run's
particles coloured by their horizontal velocity, the zone shaded; bottom: both runs' free surface
along the flume (half a spacing above the highest particle in each column of one spacing: the
particles' centres sit that far below the surface), in wave heights of linear theory.

    .venv/bin/sph run configs/wave_maker_2d.toml --until 6.43 --no-viewer --out runs/wm_zone
    .venv/bin/sph run NO_ZONE.toml --until 6.43 --no-viewer --out runs/wm_wall   # the scene without [[damping_zones]]
    .venv/bin/python scripts/plot_wave_tank.py runs/wm_zone runs/wm_wall docs/img/damping_zone.png
"""
import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from launch.validate import PistonWave  # noqa: E402
from sphcore.scene import load_scene  # noqa: E402


def surface(x, dx, length):
    """(column centres, the free surface of each column of width dx: half a spacing above its highest
    particle) along the flume."""
    edges = np.arange(0.0, length + dx, dx)
    column = np.clip(np.digitize(x[:, 0], edges) - 1, 0, len(edges) - 2)
    top = np.full(len(edges) - 1, np.nan)
    np.fmax.at(top, column, x[:, 1])
    return 0.5 * (edges[1:] + edges[:-1]), top + 0.5 * dx


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("zone", type=Path, help="the run with the damping zone (its scene.toml and final.npz)")
    ap.add_argument("wall", type=Path, help="the same run without it")
    ap.add_argument("png", type=Path)
    args = ap.parse_args()
    scene = load_scene(args.zone / "scene.toml")
    wave = PistonWave.of(scene)
    dx = scene.particles.spacing
    length = scene.domain.bounds_max[0]
    (zone,) = scene.damping_zones
    t = json.loads((args.zone / "summary.json").read_text())["sim_time"]
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(11, 5.2), sharex=True, layout="constrained",
                                      gridspec_kw={"height_ratios": [1.2, 1]})
    d = np.load(args.zone / "final.npz")
    x, u = d["x"], d["v"][:, 0]
    lim = float(np.percentile(np.abs(u), 99))
    top.axvspan(zone.min[0], zone.max[0], color="#dbe6fb", zorder=0)
    sc = top.scatter(x[:, 0], x[:, 1], c=u, s=1.2, cmap="coolwarm", vmin=-lim, vmax=lim, linewidths=0)
    top.set_ylim(0.0, 0.14)
    top.set_ylabel("y (m)")
    top.text(zone.min[0] + 0.02, 0.125, f"damping zone: a -= k v, k = {zone.rate:g} s$^{{-1}}$ x s$^2$, s from 0 at "
             f"x = {zone.min[0]:g} m to 1 at {zone.max[0]:g} m", fontsize=8, color="#2a4d9b")
    top.set_title(f"Piston wave maker, t = {t:.2f} s = {t / wave.period:.1f} T: the waves run into the damping zone "
                  f"and die out ({len(x):,} particles)", fontsize=10)
    for run, label, colour in ((args.zone, "flume ending in the damping zone", "C0"),
                               (args.wall, "the same flume ending in a bare wall", "C3")):
        xs, eta = surface(np.load(run / "final.npz")["x"], dx, length)
        bottom.plot(xs, (eta - wave.depth) / wave.height, lw=1.1, color=colour, label=label)
    bottom.axvspan(zone.min[0], zone.max[0], color="#dbe6fb", zorder=0)
    for sign in (-0.5, 0.5):
        bottom.axhline(sign, color="k", lw=0.6, ls="--")
    bottom.set_xlim(0.0, length)
    bottom.set_xlabel("x (m)")
    bottom.set_ylabel("surface / H of linear theory")
    bottom.legend(fontsize=8, loc="lower right")
    fig.colorbar(sc, ax=[top, bottom], pad=0.01, label="u (m/s), top panel")
    fig.savefig(args.png, dpi=110)


if __name__ == "__main__":
    main()
