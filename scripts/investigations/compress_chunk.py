"""The list filter's AVX-512 chunk (sphcore/simd.py append_range) against the scalar loop, in a toy
loop: 20,000 rows sorted along x, 128 candidates each, float32. Prints the vpcompressd form the chunk
compiled to (a memory operand or a register) and the best of five timings of each loop
(docs/BENCHMARKS.md, "2026-12-07 (evening): on AMD's Zen 4, pack in a register"). Run it in a
worktree of 8c8d5b4 for the compress-store to memory that came before.

    .venv/bin/python scripts/investigations/compress_chunk.py
"""
import time

import numpy as np
from numba import njit

from sphcore.simd import AVX512, append_range, lanes

REACH = 64  # candidates on each side of a row


@njit(cache=False)
def chunked(x, H2, nbr, reps):
    n = x.shape[0]
    total = 0
    for _ in range(reps):
        for i in range(n):
            count = 0
            lo, hi = max(0, i - REACH), min(n, i + REACH)
            j0 = lo
            while j0 < hi:
                count = append_range(x, j0, min(lanes(x), hi - j0), x[i, 0], x[i, 1], x[i, 2], H2, nbr, i, count)
                j0 += lanes(x)
            total += count
    return total


@njit(cache=False)
def scalar(x, H2, nbr, reps):
    n = x.shape[0]
    total = 0
    for _ in range(reps):
        for i in range(n):
            count = 0
            for j in range(max(0, i - REACH), min(n, i + REACH)):
                dx, dy, dz = x[i, 0] - x[j, 0], x[i, 1] - x[j, 1], x[i, 2] - x[j, 2]
                nbr[i, count] = j
                count += 1 if dx * dx + dy * dy + dz * dz < H2 else 0
            total += count
    return total


def main():
    if not AVX512:
        print("this CPU (or numba's target) has no AVX-512: append_range is not the chunk here")
    rng = np.random.default_rng(0)
    n = 20_000
    x = rng.random((n, 3)).astype(np.float32)
    x[:, 0] = np.sort(x[:, 0]) * np.float32(10.0)
    x[:, 1:] *= np.float32(0.3)
    H2 = np.float32(0.04)
    lists = {}
    for f in (chunked, scalar):
        nbr = np.zeros((n, 2 * REACH + 16), dtype=np.int32)
        count = f(x, H2, nbr, 1)
        lists[f.__name__] = (count, nbr)
        best = min(_timed(f, x, H2, nbr) for _ in range(5))
        print(f"{f.__name__:8s} {count} entries, best of 5: {best:.4f} s")
    (c1, a), (c2, b) = lists["chunked"], lists["scalar"]
    counts_equal = c1 == c2
    print("the same entries:", counts_equal and all(np.array_equal(a[i, :k], b[i, :k]) for i, k in _counts(x, H2)))
    asm = next(iter(chunked.inspect_asm().values()))
    print("vpcompressd as compiled:", sorted({line.strip() for line in asm.splitlines() if "vpcompress" in line}))


def _timed(f, x, H2, nbr):
    started = time.perf_counter()
    f(x, H2, nbr, 5)
    return time.perf_counter() - started


def _counts(x, H2):
    n = x.shape[0]
    for i in range(n):
        lo, hi = max(0, i - REACH), min(n, i + REACH)
        d = x[lo:hi] - x[i]
        yield i, int(((d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) + d[:, 2] * d[:, 2] < H2).sum())


if __name__ == "__main__":
    main()
