"""Compute backends: thin drivers that loop over particles and call the physics pair functions.

``cpu`` drives with ``numba.njit(parallel=True)`` and ``prange``; the CUDA backend of a later issue
drives the same functions from ``cuda.jit`` kernels. A backend is chosen once at start-up.
"""
