"""Is the walls' density share beyond a curved wall different from a flat wall's (docs/VALIDATION.md,
circular Couette)? The virtual lattice of sphcore.boundaries.wall_tables (rows at normal offsets
d + (k + 1/2) dx from the particle, columns aligned with it), counted only where it lies beyond a
circle of radius R: a concave container wall (fluid inside) and a convex obstacle (fluid outside),
against the flat wall, 2D Wendland C2, support 3 spacings.

    .venv/bin/python scripts/investigations/curved_wall_share.py [--radii 40 20] [--support 3]
"""
import argparse
import math

from sphcore.choices import Kernel
from sphcore.physics.kernels import kernel_constants, w


def share(d: float, R: float, concave: bool, H: float, s_w: float, K: int, S: float) -> float:
    """Phi(d) (units of rho0) of the virtual lattice beyond the wall; R = inf: a flat wall."""
    total = 0.0
    for i in range(-K, K + 1):
        for k in range(-K, K + 1):
            l, z = float(i), d + k + 0.5  # lateral and normal offsets from the particle (spacings), z toward the wall
            r = math.hypot(l, z)
            if r >= H:
                continue
            if math.isinf(R):
                beyond = z > d
            elif concave:  # the circle's centre R - d behind the particle
                beyond = math.hypot(l, z + (R - d)) > R
            else:          # the obstacle's centre d + R ahead of it
                beyond = math.hypot(l, z - (d + R)) < R
            if beyond:
                total += w(int(Kernel.WENDLAND_C2), r, H, s_w)
    return total / S


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--radii", type=float, nargs=2, default=(40.0, 20.0), metavar=("CONCAVE", "CONVEX"),
                    help="the circles' radii in spacings (default: the case's outer 40 and inner 20 at 40 across)")
    ap.add_argument("--support", type=float, default=3.0, help="support radius in spacings (default 3)")
    a = ap.parse_args()
    H = a.support
    s_w = kernel_constants(Kernel.WENDLAND_C2, 2, H)[0]
    K = int(math.ceil(H)) + 2
    S = sum(w(int(Kernel.WENDLAND_C2), math.hypot(i, j), H, s_w) for i in range(-K, K + 1) for j in range(-K, K + 1))
    for d in (0.5, 0.8, 1.0, 1.5):  # the first lattice layer sits at 0.5 spacings
        args = (H, s_w, K, S)
        print(f"d = {d} dx: flat {share(d, math.inf, True, *args):.4f}, concave R = {a.radii[0]:g} dx "
              f"{share(d, a.radii[0], True, *args):.4f}, convex R = {a.radii[1]:g} dx {share(d, a.radii[1], False, *args):.4f}")


if __name__ == "__main__":
    main()
