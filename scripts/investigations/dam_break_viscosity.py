"""The 2D dam break's late front speed against the artificial viscosity's shear viscosity.

Monaghan's artificial viscosity acts in a shear flow as a kinematic viscosity nu_AV ~ alpha c0 h / 8
in 2D (h = H / 2). This script runs ``sph validate dam_break``'s case (with its walls' friction) for
several alpha, c0 and spacings, and plots the late front speed dZ/dT (T = 5.7-8.6, Martin & Moyce:
1.716) and the RMS of the front with the fixed shift T + 0.175 against nu_AV, one marker per spacing.

    .venv/bin/python scripts/investigations/dam_break_viscosity.py [--out docs/img/validation/dam_break_viscosity.png]

About 9 minutes on 2 cores (the two a/80 runs take most of it).
"""
import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from launch.validate import CaseOptions, _plot, dam_break  # noqa: E402
from sphcore.scene import load_scene  # noqa: E402

A = 0.2                      # the case's column width (m)
EXPERIMENT = 1.716           # Martin & Moyce's late dZ/dT
RUNS = [(dx, alpha, c0) for dx in (0.01, 0.005) for alpha in (0.02, 0.01, 0.005) for c0 in (30.0,)] + \
    [(0.01, 0.02, 60.0), (0.005, 0.02, 60.0), (0.0025, 0.02, 30.0), (0.0025, 0.01, 30.0)]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "img" / "validation" / "dam_break_viscosity.png")
    args = ap.parse_args()
    support = load_scene(ROOT / "configs" / "dam_break_2d.toml").sph.support
    rows = []
    print("| dx | alpha | c0 (m/s) | nu_AV (m^2/s) | late dZ/dT | front RMS, T + 0.175 | raw |")
    print("|---|---|---|---|---|---|---|")
    for dx, alpha, c0 in RUNS:
        opts = CaseOptions(dx=dx, overrides=(f"sph.alpha={alpha}", f"sph.sound_speed={c0}"), plot=False)
        metrics = dam_break(False, Path("."), opts=opts)
        nu = alpha * c0 * 0.5 * support * dx / 8.0
        rows.append((dx, alpha, c0, nu, opts.stats["front_speed"], metrics[0].value))
        print(f"| a/{A / dx:.0f} | {alpha} | {c0:g} | {nu:.2e} | {opts.stats['front_speed']:.3f} "
              f"| {metrics[0].value:.4f} | {opts.stats['front_rms_raw']:.4f} |", flush=True)
    plt = _plot()
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(10, 4))
    for dx, marker in ((0.01, "o"), (0.005, "s"), (0.0025, "^")):
        mine = [r for r in rows if r[0] == dx]
        ax.semilogx([r[3] for r in mine], [r[4] for r in mine], marker, label=f"dx = a/{A / dx:.0f}")
        bx.semilogx([r[3] for r in mine], [100 * r[5] for r in mine], marker, label=f"dx = a/{A / dx:.0f}")
    ax.axhline(EXPERIMENT, color="k", lw=0.8, label="Martin & Moyce 1.716")
    ax.axhspan(0.97 * EXPERIMENT, 1.03 * EXPERIMENT, color="k", alpha=0.08, label="within 3 %")
    ax.set_xlabel(r"artificial viscosity's shear viscosity $\alpha c_0 h / 8$ (m$^2$/s)")
    ax.set_ylabel("late front speed dZ/dT (T = 5.7-8.6)")
    ax.legend(fontsize=8)
    bx.axhline(3.0, color="k", lw=0.8, label="target 3 %")
    bx.set_xlabel(r"$\alpha c_0 h / 8$ (m$^2$/s)")
    bx.set_ylabel("front RMS with the shift T + 0.175 (%)")
    bx.legend(fontsize=8)
    fig.suptitle("2D dam break with the walls' friction: the late front follows the artificial viscosity")
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
