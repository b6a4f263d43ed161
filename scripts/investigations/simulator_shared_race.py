"""Does numba's CUDA simulator give two threads of a block two shared arrays? Runs CUDA parity cases
(tests/cuda_parity.py) under the simulator with the simulator's own ``cuda.shared.array`` put back
(not sphcore's locked one), counting each array it creates and each second array for a call site
that already had one (docs/BENCHMARKS.md, "Test suite", 2026-12-07 evening: one second array in 343
allocations over two runs of two cases each).

    .venv/bin/python scripts/investigations/simulator_shared_race.py dfsph_peers_2d_f64 open_f64
"""
import importlib
import os
import runpy
import sys
import traceback

os.environ["NUMBA_ENABLE_CUDASIM"] = "1"  # before numba is imported

import numpy as np  # noqa: E402
from numba.core import types  # noqa: E402
from numba.cuda.simulator import kernelapi  # noqa: E402
from numba.np import numpy_support  # noqa: E402

importlib.import_module("sphcore.backends.cuda")  # installs the locked allocation, replaced below

counts = {"arrays": 0, "second arrays": 0}


def unlocked_array(self, shape, dtype, alignment=None):
    """The simulator's allocation (numba-cuda 0.30), counting."""
    if isinstance(dtype, types.Type):
        dtype = numpy_support.as_dtype(dtype)
    caller = traceback.extract_stack(sys._getframe())[-2][0:2]
    found = self._allocations.get(caller)
    if found is None:
        found = np.empty(shape, dtype)
        if caller in self._allocations:  # another thread inserted one since our lookup
            counts["second arrays"] += 1
        self._allocations[caller] = found
        counts["arrays"] += 1
    return found


kernelapi.FakeCUDAShared.array = unlocked_array
sys.argv = ["tests/cuda_parity.py", *sys.argv[1:]]
try:
    runpy.run_path("tests/cuda_parity.py", run_name="__main__")
finally:
    print(counts, file=sys.stderr)
