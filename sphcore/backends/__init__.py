"""Compute backends: thin drivers that loop over particles and call the per-row physics.

``rows.py`` holds the work of one particle in every stage. ``cpu.py`` drives it with
``numba.njit(parallel=True)`` and ``prange``; ``cuda.py`` drives the same functions from ``cuda.jit``
kernels, one thread per row. A backend is chosen once at start-up (``Simulation(..., backend=)``);
``cuda`` is imported only when asked for, so the package never needs CUDA to import.
"""


class BackendUnavailable(RuntimeError):
    """The requested backend cannot run here (``--backend cuda`` without a GPU); the message says why
    and what to do instead."""
