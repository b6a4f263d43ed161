"""Compute backends: thin drivers that loop over particles and call the per-row physics.

The work of one particle in every stage is a row function next to its physics
(``sphcore/physics/*.py``), declared as a stage in ``sphcore/stages.py``. ``generate.py`` writes the
plumbing from those declarations: ``cpu.py`` drives each row with ``numba.njit(parallel=True)`` and
``prange``; ``cuda.py`` drives the same functions from ``cuda.jit`` kernels, one thread per row;
``engine.py`` binds a stage's arguments by name on either. A backend is chosen once at start-up (``Simulation(..., backend=)``);
``cuda`` is imported only when asked for, so the package never needs CUDA to import.
"""


class BackendUnavailable(RuntimeError):
    """The requested backend cannot run here (``--backend cuda`` without a GPU); the message says why
    and what to do instead."""
