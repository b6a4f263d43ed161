"""The 2D dam-break front with free-slip walls and with the walls' turbulent friction at Martin &
Moyce's Reynolds number, side by side at one spacing, against the experiment and the inviscid
shallow-water front (Ritter: dZ/dT = 2): docs/img/validation/dam_break_friction.png.

    python scripts/investigations/dam_break_friction.py [--dx 0.005] [--out docs/img/validation]

About 2 minutes with one thread at dx = a/40.
"""
import argparse
from pathlib import Path

import matplotlib
import numpy as np

from launch.validate import MARTIN_MOYCE_SHIFT_T, MARTIN_MOYCE_T, MARTIN_MOYCE_Z, CaseOptions, dam_break, martin_moyce_nu

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dx", type=float, default=0.005, help="particle spacing in m (a = 0.2 m)")
    ap.add_argument("--out", type=Path, default=Path("docs/img/validation"), help="folder for the plot")
    args = ap.parse_args()
    nu = martin_moyce_nu(0.2)
    runs = {"free-slip walls": "terms.wall_friction=0", f"wall friction, nu = {nu:.3g} m$^2$/s": f"terms.wall_friction={nu!r}"}
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for k, (label, override) in enumerate(runs.items()):
        opts = CaseOptions(dx=args.dx, overrides=(override,), plot=False)
        metrics = dam_break(False, Path("."), opts=opts)
        rms, speed = metrics[0].value, f"{opts.stats['front_speed']:.3f}"
        T = np.asarray(opts.stats["front_T"]) + MARTIN_MOYCE_SHIFT_T
        ax.plot(T, opts.stats["front_Z"], color=f"C{k}",
                label=f"{label}: RMS {100 * rms:.1f} %, late dZ/dT {speed}")
        print(f"{label}: {metrics[0].name} {rms:.4f}; {metrics[1].note}", flush=True)
    ax.plot(MARTIN_MOYCE_T, MARTIN_MOYCE_Z, "ko", mfc="none", label="Martin & Moyce (1952): late dZ/dT 1.716")
    t0, z0 = MARTIN_MOYCE_T[8], MARTIN_MOYCE_Z[8]
    ax.plot([t0, t0 + 3.5], [z0, z0 + 7.0], "k:", lw=0.8, label="dZ/dT = 2 (inviscid shallow water)")
    ax.set_xlabel(f"T = t sqrt(2g/a) (simulated clock + {MARTIN_MOYCE_SHIFT_T})")
    ax.set_ylabel("Z = x_front / a")
    ax.set_xlim(0, 9.8)
    ax.set_ylim(0, 15.5)
    ax.legend(fontsize=7.5, loc="upper left")
    ax.set_title(f"2D dam break, dx = a/{0.2 / args.dx:.0f}: what the walls' friction does to the front")
    fig.tight_layout()
    args.out.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out / "dam_break_friction.png", dpi=100)
    print(f"plot: {args.out / 'dam_break_friction.png'}")


if __name__ == "__main__":
    main()
