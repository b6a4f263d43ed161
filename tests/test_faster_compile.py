"""sphcore/faster_compile.py: numba's inliner and copy propagation copy in linear time, and the code
they compile is the same: the same function compiled with and without it, in two processes, gives
the same machine code (CPU) and PTX (CUDA), up to the names numba draws from addresses and the order
of PTX's global declarations."""
import json
import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# A parallel loop over the walls' signed distance (inlined, and _mesh_distance inlined into it: the
# nested inlining of branchy row functions that the drivers do), through prange (copy propagation)
CPU_PROBE = """
import json, sys
import numpy as np
import sphcore  # applies sphcore.faster_compile
from numba import njit, prange
from numba.core import inline_closurecall, ir_utils
from sphcore import faster_compile
from sphcore.physics.walls import signed_distance

@njit(parallel=True)
def nearest_wall(kinds, data, x, out):
    for i in prange(x.shape[0]):
        best = 1.0e300
        for q in range(kinds.shape[0]):
            d, nx, ny, nz = signed_distance(kinds[q], data[q], x[i, 0], x[i, 1], x[i, 2])
            best = min(best, d + 0.5 * (nx + ny + nz))
        out[i] = best

x = np.array([[0.0, 0.5, 0.0], [0.0, 2.0, 0.0]])
out = np.zeros(2)
data = np.zeros((1, 16))
data[0, 4] = 1.0  # the floor y = 0, normal +y
nearest_wall(np.zeros(1, np.int64), data, x, out)
patched = [isinstance(m.copy, faster_compile._Copies) for m in (inline_closurecall, ir_utils)]
print(json.dumps({"patched": patched, "out": out.tolist(), "asm": "\\n".join(nearest_wall.inspect_asm().values())}))
"""

PTX_PROBE = """
import json
from numba.cuda.core import inline_closurecall, ir_utils
from sphcore import faster_compile, stages
from sphcore.backends import cuda
stage = [s for s in stages.STAGES if s.name == "density"]
ptx = cuda.compile_all(dtype="f32", stages=stage, binning=False, combinations=lambda s: stages.covering_choices(s)[:1])
patched = [isinstance(m.copy, faster_compile._Copies) for m in (inline_closurecall, ir_utils)]
print(json.dumps({"patched": patched, "ptx": ptx}))
"""


def _run(code: str, faster: bool) -> dict:
    env = dict(os.environ, SPH_FASTER_COMPILE="1" if faster else "0", NUMBA_DISABLE_CACHE="1")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def _names_from_addresses(text: str) -> str:
    """numba names parallel loops' functions after an object's address (``gufunc_0x7f...``)."""
    return re.sub(r"0x[0-9a-f]+", "0x?", text)


def test_cpu_machine_code_is_the_same_with_and_without_the_faster_copies():
    plain, faster = _run(CPU_PROBE, False), _run(CPU_PROBE, True)
    assert plain["patched"] == [False, False] and faster["patched"] == [True, True]
    assert faster["out"] == plain["out"] == [1.0, 2.5]
    assert len(faster["asm"]) > 10_000  # the whole inlined body is there
    assert _names_from_addresses(faster["asm"]) == _names_from_addresses(plain["asm"])


def test_ptx_is_the_same_with_and_without_the_faster_copies():
    plain, faster = _run(PTX_PROBE, False), _run(PTX_PROBE, True)
    assert plain["patched"] == [False, False] and faster["patched"] == [True, True]
    assert plain["ptx"].keys() == faster["ptx"].keys() and len(plain["ptx"]) == 1
    for label, text in faster["ptx"].items():
        # the order in which the module declares its environment globals (.common) follows the order
        # the inliner met them in; every other line, in order, is the same
        body = [line for line in text.splitlines() if not line.startswith(".common")]
        assert body == [line for line in plain["ptx"][label].splitlines() if not line.startswith(".common")], label
        assert sorted(text.splitlines()) == sorted(plain["ptx"][label].splitlines()), label
        assert ".entry" in text


def test_anything_else_is_copied_as_copy_deepcopy_copies_it():
    from sphcore.faster_compile import _Copies
    copies = _Copies()
    table = {1: {("a", "b"), ("c", "d")}, 2: set()}
    copied = copies.deepcopy(table)
    assert copied == table and copied[1] is not table[1]
    # sets of mutable things, or anything but a dict of sets, go through copy.deepcopy
    nested = {1: [[1, 2]]}
    other = copies.deepcopy(nested)
    assert other == nested and other[1][0] is not nested[1][0]
    frozen = {1: {frozenset({"a"})}}
    assert copies.deepcopy(frozen) == frozen
