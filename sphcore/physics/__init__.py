"""Physical terms of SPH, one module per term, each citing its method.

Every function here is a small scalar/pair function compiled with ``numba.njit``; the CPU drivers in
``sphcore.backends.cpu`` (and the CUDA drivers of a later issue) call the same functions, so the
physics is written once. Choices (which kernel, which EOS...) arrive as integer codes from the
registries in ``sphcore.choices``; the generated drivers hold them as constants, so a scene compiles and runs
only the branches it uses.
"""
