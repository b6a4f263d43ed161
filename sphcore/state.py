"""Particle state as a structure of arrays.

One ``ParticleState`` holds every per-particle quantity as its own numpy array. Rows are particles;
the first ``n_owned`` rows are particles this process integrates (in a distributed run ghost rows
follow them). Vectors always have 3 components; in 2D scenes z = 0.

Fields (float = float32 or float64, the run's precision):

=========  ========  =======  ==========================================================
field      shape     dtype    meaning (unit)
=========  ========  =======  ==========================================================
id         (n,)      int64    stable global particle id, never reused
x          (n, 3)    float    position (m)
v          (n, 3)    float    velocity (m/s); half-step velocity with the leapfrog integrator
a          (n, 3)    float    acceleration of the current step (m/s^2)
m          (n,)      float    mass (kg)
rho        (n,)      float    density (kg/m^3)
p          (n,)      float    pressure (Pa)
=========  ========  =======  ==========================================================

``extra`` holds further per-particle arrays that must follow the particles when rows are
reordered (the grid reorders them with the rest), move with them to another peer and go into
checkpoints: DFSPH's kappa = p / rho^2, its warm start (physics/dfsph.py). Per-step scratch of optional terms (the XSPH
correction, the vorticity) lives in the solver instead, since it is recomputed every step.
"""
from dataclasses import dataclass, field

import numpy as np

@dataclass
class ParticleState:
    id: np.ndarray
    x: np.ndarray
    v: np.ndarray
    m: np.ndarray
    a: np.ndarray
    rho: np.ndarray
    p: np.ndarray
    n_owned: int
    extra: dict = field(default_factory=dict)

    @classmethod
    def create(cls, ids, x, v, m, dtype, extra=None) -> "ParticleState":
        """Build a state from initial arrays; derived fields start at zero; ``extra``: carried arrays."""
        n = len(ids)
        extra = {k: np.ascontiguousarray(a, dtype=dtype).reshape((n,) + np.shape(a)[1:]) for k, a in (extra or {}).items()}
        return cls(
            id=np.ascontiguousarray(ids, dtype=np.int64),
            x=np.ascontiguousarray(x, dtype=dtype).reshape(n, 3),
            v=np.ascontiguousarray(v, dtype=dtype).reshape(n, 3),
            m=np.ascontiguousarray(m, dtype=dtype),
            a=np.zeros((n, 3), dtype=dtype),
            rho=np.zeros(n, dtype=dtype),
            p=np.zeros(n, dtype=dtype),
            n_owned=n,
            extra=extra,
        )

    @property
    def n(self) -> int:
        return self.id.shape[0]

    @property
    def dtype(self):
        return self.x.dtype


def merge_by_id(parts: list[dict], keys) -> dict:
    """Per-particle arrays of several parts (peers, checkpoint files) joined and sorted by id."""
    arrays = {k: np.concatenate([p[k] for p in parts]) for k in keys}
    order = np.argsort(arrays["id"], kind="stable")
    return {k: a[order] for k, a in arrays.items()}
