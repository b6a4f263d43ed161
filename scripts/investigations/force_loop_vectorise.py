"""Why the force pass was scalar: the pressure and artificial-viscosity pair terms of a float32 force
pass over the bench's neighbour lists (the 3D dam break at 49,152 particles after 20 steps, 1 thread),
written three ways with the same arithmetic and timed side by side (docs/BENCHMARKS.md, 2026-12-06):

    with_continue  the pair loop as the passes had it: a coincident pair skipped by `continue`
    two_phase      each row's neighbours gathered into short buffers first, then a branch-free loop
    with_select    the `continue` replaced by a select (what kernels.pair_dw_dr_over_r now does)

A branch in the loop keeps LLVM from vectorising it; either way round it gives the speed.

    .venv/bin/python scripts/investigations/force_loop_vectorise.py
"""
import time

import numba
import numpy as np
from numba import njit, prange

from launch.bench import DEFAULT_SCENE, _fixed, spacing_for
from sphcore.backends.generate import FASTMATH
from sphcore.scene import load_scene
from sphcore.solver import Simulation

FM = set(FASTMATH)


@njit(fastmath=FM, parallel=True, cache=False)
def with_continue(n, x, v, m, rho, p, nbr, counts, H, s_g, alpha, c0, h, a):
    for ii in prange(n):
        i = np.int64(ii)
        ax = np.float32(0.0); ay = np.float32(0.0); az = np.float32(-9.81)
        rho_i = rho[i]; pr_i = p[i] / (rho_i * rho_i)
        for k in range(counts[i]):
            j = nbr[i, k]
            dx = x[i, 0] - x[j, 0]; dy = x[i, 1] - x[j, 1]; dz = x[i, 2] - x[j, 2]
            r2 = dx * dx + dy * dy + dz * dz
            if r2 == 0.0:
                continue
            r = np.sqrt(r2)
            q = r / H
            t = np.float32(1.0) - q
            g = np.float32(-20.0) * s_g / (H * H) * t * t * t
            f = -m[j] * (pr_i + p[j] / (rho[j] * rho[j])) * g
            vdx = (v[i, 0] - v[j, 0]) * dx + (v[i, 1] - v[j, 1]) * dy + (v[i, 2] - v[j, 2]) * dz
            ap = min(vdx, np.float32(0.0))
            f += np.float32(2.0) * m[j] * alpha * c0 * h * ap * g / ((r2 + np.float32(0.01) * h * h) * (rho_i + rho[j]))
            ax += f * dx; ay += f * dy; az += f * dz
        a[i, 0] = ax; a[i, 1] = ay; a[i, 2] = az


@njit(fastmath=FM, parallel=True, cache=False)
def two_phase(n, x, v, m, rho, p, nbr, counts, H, s_g, alpha, c0, h, a):
    cap = nbr.shape[1]
    for ii in prange(n):
        i = np.int64(ii)
        bx = np.empty(cap, np.float32); by = np.empty(cap, np.float32); bz = np.empty(cap, np.float32)
        bm = np.empty(cap, np.float32); br = np.empty(cap, np.float32); bp = np.empty(cap, np.float32)
        bv = np.empty(cap, np.float32)
        rho_i = rho[i]; pr_i = p[i] / (rho_i * rho_i)
        c = counts[i]
        xi0 = x[i, 0]; xi1 = x[i, 1]; xi2 = x[i, 2]
        vi0 = v[i, 0]; vi1 = v[i, 1]; vi2 = v[i, 2]
        for k in range(c):
            j = nbr[i, k]
            dx = xi0 - x[j, 0]; dy = xi1 - x[j, 1]; dz = xi2 - x[j, 2]
            bx[k] = dx; by[k] = dy; bz[k] = dz
            bv[k] = (vi0 - v[j, 0]) * dx + (vi1 - v[j, 1]) * dy + (vi2 - v[j, 2]) * dz
            bm[k] = m[j]; br[k] = rho[j]; bp[k] = p[j]
        ax = np.float32(0.0); ay = np.float32(0.0); az = np.float32(-9.81)
        for k in range(c):
            dx = bx[k]; dy = by[k]; dz = bz[k]
            r2 = dx * dx + dy * dy + dz * dz
            r = np.sqrt(r2)
            q = r / H
            t = np.float32(1.0) - q
            g = np.float32(-20.0) * s_g / (H * H) * t * t * t
            rj = br[k]
            f = -bm[k] * (pr_i + bp[k] / (rj * rj)) * g
            ap = min(bv[k], np.float32(0.0))
            f += np.float32(2.0) * bm[k] * alpha * c0 * h * ap * g / ((r2 + np.float32(0.01) * h * h) * (rho_i + rj))
            f = f if r2 > 0.0 else np.float32(0.0)
            ax += f * dx; ay += f * dy; az += f * dz
        a[i, 0] = ax; a[i, 1] = ay; a[i, 2] = az


@njit(fastmath=FM, parallel=True, cache=False)
def with_select(n, x, v, m, rho, p, nbr, counts, H, s_g, alpha, c0, h, a):
    for ii in prange(n):
        i = np.int64(ii)
        ax = np.float32(0.0); ay = np.float32(0.0); az = np.float32(-9.81)
        rho_i = rho[i]; pr_i = p[i] / (rho_i * rho_i)
        for k in range(counts[i]):
            j = nbr[i, k]
            dx = x[i, 0] - x[j, 0]; dy = x[i, 1] - x[j, 1]; dz = x[i, 2] - x[j, 2]
            r2 = dx * dx + dy * dy + dz * dz
            r = np.sqrt(r2)
            q = r / H
            t = np.float32(1.0) - q
            g = np.float32(-20.0) * s_g / (H * H) * t * t * t
            f = -m[j] * (pr_i + p[j] / (rho[j] * rho[j])) * g
            vdx = (v[i, 0] - v[j, 0]) * dx + (v[i, 1] - v[j, 1]) * dy + (v[i, 2] - v[j, 2]) * dz
            ap = min(vdx, np.float32(0.0))
            f += np.float32(2.0) * m[j] * alpha * c0 * h * ap * g / ((r2 + np.float32(0.01) * h * h) * (rho_i + rho[j]))
            f = f if r2 > 0.0 else np.float32(0.0)
            ax += f * dx; ay += f * dy; az += f * dz
        a[i, 0] = ax; a[i, 1] = ay; a[i, 2] = az


def main():
    numba.set_num_threads(1)
    dx = spacing_for(DEFAULT_SCENE, 49152)
    sim = Simulation(load_scene(DEFAULT_SCENE, _fixed(DEFAULT_SCENE, dx)), "f32")
    for _ in range(20):
        sim.step()
    s, g, n, f32 = sim.state, sim.grid, sim.state.n_owned, np.float32
    args = (n, s.x, s.v, s.m, s.rho, s.p, g.nbr, g.counts, f32(sim.model.H), f32(sim.prm.s_g), f32(0.02),
            f32(sim.prm.c0), f32(sim.prm.h))
    outs = {fn: np.zeros((n, 3), np.float32) for fn in (with_continue, two_phase, with_select)}
    for fn, out in outs.items():
        fn(*args, out)  # compile
    ref = outs[with_continue]
    print(f"{n} rows, {int(g.counts[:n].sum())} pairs; largest difference from with_continue, relative to max |a|: "
          + ", ".join(f"{fn.__name__} {float(np.abs(out - ref).max() / np.abs(ref).max()):.1e}"
                      for fn, out in outs.items() if fn is not with_continue))
    for _ in range(3):
        for fn, out in outs.items():
            t0 = time.perf_counter()
            for _ in range(20):
                fn(*args, out)
            print(f"  {fn.__name__:14s} {(time.perf_counter() - t0) / 20 * 1e3:6.2f} ms")


if __name__ == "__main__":
    main()
