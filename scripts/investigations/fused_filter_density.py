"""Would filtering the Verlet candidates inside the density pass pay? A prototype on the arrays of the
`sph bench --until` case (3D dam break, 49,152 particles, f32, 2 threads, the automatic skin; DFSPH's
0.45 or, with `--solver wcsph`, WCSPH's 0.2) after 60 steps: a simplified density pass (Wendland C2
sum, m_j grad W_ij stored per entry; no walls) timed

- after the filter, as the step runs them (two passes);
- fused, the filter's test as a branch inside the density loop (one pass);
- fused per row in two phases: the row's candidates filtered branch-free, then its density summed
  over the fresh list while it is in the cache.

All three give the same lists and the same bits (checked). Medians of 30 calls, ms, three rounds.

Read it with care: these loops are compiled without the reassociation licence of the real neighbour
passes (backends/generate.FASTMATH), and the real WCSPH density pass stores no gradient: it takes 2.9
ms where this one takes 5.6-5.8 at WCSPH's skin. Built into the real pass, the fused loop lost
(docs/BENCHMARKS.md, 2026-12-06 evening).

    .venv/bin/python scripts/investigations/fused_filter_density.py [--solver dfsph]
"""
import argparse
import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

import numba  # noqa: E402
import numpy as np  # noqa: E402
from numba import njit, prange  # noqa: E402

from launch import bench  # noqa: E402
from scripts.investigations.peer_pass_cost import median_ms  # noqa: E402
from sphcore.scene import load_scene  # noqa: E402
from sphcore.solver import Simulation  # noqa: E402

SCENE = ROOT / "configs" / "dam_break.toml"
SPACING = 0.012428930023815439  # the bench's 49,152 particles
ONE = np.float32(1.0)


@njit(inline="always")
def w_and_dw_over_r(r, H):
    """Wendland C2 (unnormalised): W(q) and dW/dr / r, q = r / H."""
    q = r / H
    t = ONE - q
    return t * t * t * t * (ONE + np.float32(4.0) * q), np.float32(-20.0) * t * t * t / (H * H)


@njit(inline="always")
def pair(x, m, i, j, xi, yi, zi, H):
    dx, dy, dz = xi - x[j, 0], yi - x[j, 1], zi - x[j, 2]
    w, g = w_and_dw_over_r(math.sqrt(dx * dx + dy * dy + dz * dz), H)
    return m[j] * w, m[j] * g * dx, m[j] * g * dy, m[j] * g * dz


@njit(inline="always")
def filter_row(x, i, cand, cand_counts, H2, nbr, counts):
    """Row i's candidates within H into its list, branch-free (grid.filter_row's loop); the count."""
    cap = nbr.shape[1] - 1
    xi, yi, zi = x[i, 0], x[i, 1], x[i, 2]
    c = 0
    for k in range(cand_counts[i]):
        j = cand[i, k]
        dx, dy, dz = xi - x[j, 0], yi - x[j, 1], zi - x[j, 2]
        nbr[i, min(c, cap)] = j
        c += 1 if dx * dx + dy * dy + dz * dz < H2 else 0
    counts[i] = c
    return c


@njit(parallel=True)
def filter_lists(x, n, cand, cand_counts, H2, nbr, counts):
    for i in prange(n):
        filter_row(x, i, cand, cand_counts, H2, nbr, counts)


@njit(parallel=True)
def density(x, m, n, nbr, counts, H, rho, grad):
    for i in prange(n):
        xi, yi, zi = x[i, 0], x[i, 1], x[i, 2]
        r = m[i]
        for k in range(counts[i]):
            w, gx, gy, gz = pair(x, m, i, nbr[i, k], xi, yi, zi, H)
            r += w
            grad[0, i, k], grad[1, i, k], grad[2, i, k] = gx, gy, gz
        rho[i] = r


@njit(parallel=True)
def fused_branch(x, m, n, cand, cand_counts, H2, H, nbr, counts, rho, grad):
    for i in prange(n):
        xi, yi, zi = x[i, 0], x[i, 1], x[i, 2]
        r = m[i]
        c = 0
        for k in range(cand_counts[i]):
            j = cand[i, k]
            dx, dy, dz = xi - x[j, 0], yi - x[j, 1], zi - x[j, 2]
            if dx * dx + dy * dy + dz * dz < H2:
                nbr[i, c] = j
                w, gx, gy, gz = pair(x, m, i, j, xi, yi, zi, H)
                r += w
                grad[0, i, c], grad[1, i, c], grad[2, i, c] = gx, gy, gz
                c += 1
        counts[i] = c
        rho[i] = r


@njit(parallel=True)
def fused_per_row(x, m, n, cand, cand_counts, H2, H, nbr, counts, rho, grad):
    for i in prange(n):
        c = filter_row(x, i, cand, cand_counts, H2, nbr, counts)
        xi, yi, zi = x[i, 0], x[i, 1], x[i, 2]
        r = m[i]
        for k in range(c):
            w, gx, gy, gz = pair(x, m, i, nbr[i, k], xi, yi, zi, H)
            r += w
            grad[0, i, k], grad[1, i, k], grad[2, i, k] = gx, gy, gz
        rho[i] = r


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--solver", choices=("dfsph", "wcsph"), default="dfsph")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    numba.set_num_threads(args.threads)
    scene = load_scene(SCENE, bench._until_overrides(SCENE, SPACING, args.solver) + ["run.neighbour_skin=-1.0"])
    sim = Simulation(scene, "f32")
    for _ in range(60):
        sim.step()
    g, s = sim.grid, sim.state
    x, m, n = s.x, s.m, s.n_owned
    H = np.float32(sim.prm_now.H)
    H2 = H * H
    cand, cc = g.cand, g.cand_counts
    outs = [(np.zeros((n, cand.shape[1] + 1), np.int32), np.zeros(n, np.int32), np.zeros(n, np.float32),
             np.zeros((3, n, cand.shape[1] + 1), np.float32)) for _ in range(3)]
    (nbr, counts, rho, grad), one, two = outs
    runs = {"filter": lambda: filter_lists(x, n, cand, cc, H2, nbr, counts),
            "density": lambda: density(x, m, n, nbr, counts, H, rho, grad),
            "fused, a branch": lambda: fused_branch(x, m, n, cand, cc, H2, H, *one),
            "fused per row": lambda: fused_per_row(x, m, n, cand, cc, H2, H, *two)}
    for run in runs.values():
        run()
    for other in (one, two):  # the same lists, sums and stored gradients
        assert np.array_equal(other[1], counts) and np.array_equal(other[2], rho)
        assert all(np.array_equal(other[0][i, :counts[i]], nbr[i, :counts[i]]) for i in range(0, n, 97))
    print(f"{args.solver}: {n} rows, {cc[:n].mean():.1f} candidates and {counts.mean():.1f} neighbours a row")
    for _ in range(3):
        t = {name: median_ms(run, repeat=30) for name, run in runs.items()}
        print(f"filter + density {t['filter']:.2f} + {t['density']:.2f} = {t['filter'] + t['density']:.2f} ms; "
              f"fused, a branch {t['fused, a branch']:.2f}; fused per row {t['fused per row']:.2f}", flush=True)


if __name__ == "__main__":
    main()
