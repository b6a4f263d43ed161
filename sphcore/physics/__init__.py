"""Physical terms of SPH, one module per term, each citing its method.

Every function here is a small scalar/pair function compiled with ``numba.njit``; the CPU drivers in
``sphcore.backends.cpu`` (and the CUDA drivers of a later issue) call the same functions, so the
physics is written once. Choices (which kernel, which EOS...) arrive as integer codes from the
registries in ``sphcore.choices``; drivers pass them as compile-time literals, so a scene pays only
for the branches it uses.
"""
