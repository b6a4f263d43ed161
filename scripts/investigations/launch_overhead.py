"""What one kernel launch costs the host with numba-cuda, by the arguments it takes: an empty kernel
with k device arrays, and with the run's Params (a NamedTuple of ~45 scalars), each launched 2000
times back to back and then with a synchronisation after each (as the stage timers do); and zeroing
64 bytes by an upload of zeros against a driver memset (``zero``, sphcore/backends/cuda.py).

    python scripts/investigations/launch_overhead.py          (needs a GPU)

At 100 k particles the stages of a GPU step take about their launch cost (docs/BENCHMARKS.md, GPU):
this separates the host's share from the kernels' own.
"""
import time

import numpy as np
from numba import cuda

from sphcore.backends.cuda import example_params, zero

REPEAT = 2000


def kernel_with(k: int, params: bool):
    names = [f"a{i}" for i in range(k)] + (["prm"] if params else [])
    source = f"def kern(n, {', '.join(names)}):\n    i = cuda.grid(1)\n    if i < 0:\n        n += 1\n"
    namespace = {"cuda": cuda}
    exec(compile(source, "<launch_overhead>", "exec"), namespace)  # noqa: S102
    return cuda.jit(namespace["kern"])


def timed(fn, sync_each: bool) -> float:
    fn()
    cuda.synchronize()
    t0 = time.perf_counter()
    for _ in range(REPEAT):
        fn()
        if sync_each:
            cuda.synchronize()
    cuda.synchronize()
    return (time.perf_counter() - t0) / REPEAT * 1e6


def main():
    arrays = [cuda.device_array(1000, dtype=np.float32) for _ in range(40)]
    prm = example_params("f32")
    print(f"{'arguments':>28} {'us per launch':>14} {'with a sync each':>17}")
    for k, params in ((0, False), (5, False), (20, False), (40, False), (0, True), (20, True)):
        kern = kernel_with(k, params)
        args = [np.int64(10)] + arrays[:k] + ([prm] if params else [])

        def launch():
            kern[1, 128](*args)

        label = f"{k} arrays" + (" + Params" if params else "")
        print(f"{label:>28} {timed(launch, False):14.1f} {timed(launch, True):17.1f}")
    small = cuda.device_array(8, dtype=np.int64)
    host = np.zeros(8, dtype=np.int64)
    t0 = time.perf_counter()
    for _ in range(REPEAT):
        small.copy_to_device(host)
    print(f"{'copy 64 B host -> device':>28} {(time.perf_counter() - t0) / REPEAT * 1e6:14.1f}")
    t0 = time.perf_counter()
    for _ in range(REPEAT):
        small.copy_to_host()
    print(f"{'copy 64 B device -> host':>28} {(time.perf_counter() - t0) / REPEAT * 1e6:14.1f}")
    t0 = time.perf_counter()
    for _ in range(REPEAT):
        zero(small)
    print(f"{'memset 64 B (zero)':>28} {(time.perf_counter() - t0) / REPEAT * 1e6:14.1f}")


if __name__ == "__main__":
    main()
