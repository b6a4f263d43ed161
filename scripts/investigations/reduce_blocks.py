"""A reduction through a table row per particle against one through blocks of rows: the statistics
stage's row (max |v|^2, |a|^2, compression; the count of bad rows) on random float32 data, both forms
as generate.cpu_source writes them (before and since 2026-12-08), checked equal, timed over 200 calls.

    .venv/bin/python scripts/investigations/reduce_blocks.py [THREADS]
"""
import sys
import time

import numba
import numpy as np
from numba import njit, prange

from sphcore.backends.generate import REDUCE_BLOCKS
from sphcore.physics.integration import statistics_row


@njit(parallel=True)
def per_row(n, rows, x, v, a, rho, rho0):
    ints = np.zeros((n, 1), np.int64)
    reals = np.zeros((n, 3), np.float64)
    for k in prange(n):
        i = rows[k] if rows.shape[0] else np.int64(k)
        v0, v1, v2, v3 = statistics_row(i, x, v, a, rho, rho0)
        reals[k, 0] = v0
        reals[k, 1] = v1
        reals[k, 2] = v2
        ints[k, 0] = v3
    r0, r1, r2, r3 = 0.0, 0.0, 0.0, 0
    for k in range(n):
        r0, r1, r2 = max(r0, reals[k, 0]), max(r1, reals[k, 1]), max(r2, reals[k, 2])
        r3 += ints[k, 0]
    return r0, r1, r2, r3


@njit(parallel=True)
def blocked(n, rows, x, v, a, rho, rho0):
    nb = min(n, REDUCE_BLOCKS)
    size = (n + nb - 1) // nb if nb > 0 else 0
    ints = np.zeros((nb, 1), np.int64)
    reals = np.zeros((nb, 3), np.float64)
    for b in prange(nb):
        first = np.int64(b) * size
        r0, r1, r2, r3 = 0.0, 0.0, 0.0, 0
        for k in range(first, min(n, first + size)):
            i = rows[k] if rows.shape[0] else k
            v0, v1, v2, v3 = statistics_row(i, x, v, a, rho, rho0)
            r0, r1, r2 = max(r0, v0), max(r1, v1), max(r2, v2)
            r3 += v3
        reals[b, 0], reals[b, 1], reals[b, 2], ints[b, 0] = r0, r1, r2, r3
    r0, r1, r2, r3 = 0.0, 0.0, 0.0, 0
    for b in range(nb):
        r0, r1, r2 = max(r0, reals[b, 0]), max(r1, reals[b, 1]), max(r2, reals[b, 2])
        r3 += ints[b, 0]
    return r0, r1, r2, r3


def main():
    numba.set_num_threads(int(sys.argv[1]) if len(sys.argv) > 1 else numba.config.NUMBA_NUM_THREADS)
    for n in (49152, 197676):
        rng = np.random.default_rng(0)
        x, v, a = (rng.random((n, 3)).astype(np.float32) for _ in range(3))
        rho = (1000 + rng.random(n)).astype(np.float32)
        args = (n, np.empty(0, np.int64), x, v, a, rho, np.float32(1000.0))
        assert per_row(*args) == blocked(*args)
        for f in (per_row, blocked, per_row, blocked):
            t = time.perf_counter()
            for _ in range(200):
                f(*args)
            print(f"{n:7d} rows, {numba.get_num_threads()} threads, {f.__name__:8s} "
                  f"{(time.perf_counter() - t) / 200 * 1e3:.3f} ms a call")


if __name__ == "__main__":
    main()
