"""Constants in the run's precision: ``like(x, c)`` is the number c with the type of x.

numba types a Python float literal as float64, and float32 * float64 is float64: ``0.5 * q`` in a
float32 run computes in float64 and everything after it does too (on a GPU, at a fraction of the
float32 rate, with conversions around it). Writing ``like(q, 0.5) * q`` keeps a float32 run in
float32 and changes nothing in a float64 run (the constant is the same float64). Both backends
compile it (``target="generic"``); tests/test_cuda.py counts the float64 instructions left in the
PTX of every float32 kernel.
"""
import numpy as np
from numba.core import types
from numba.extending import overload


def like(x, c):
    """c as the scalar type of x (a float32/float64 scalar, or an array of them)."""
    t = x.dtype.type if isinstance(x, np.ndarray) else type(x)
    return t(c)


# Not inline="always": numba would copy impl's IR into each of the ~150 call sites while typing, and
# that copying was a fifth of compiling a scene's drivers (scripts/investigations/compile_cost.py:
# tiny f64 82.6 -> 77.1 s, f32 91.6 -> 66.4 s, 2026-12-04). LLVM and NVVM inline the one-instruction
# function anyway and fold the constant: the float32 PTX still holds no float64 instruction, and the
# float32 density pass of the 50k dam break ran 4.7 ms against 7.3 ms (sph bench, 2 threads).
@overload(like, target="generic")
def _like(x, c):
    t = x.dtype if isinstance(x, types.Array) else x
    if not isinstance(t, types.Float):
        return None

    def impl(x, c):
        return t(c)
    return impl
