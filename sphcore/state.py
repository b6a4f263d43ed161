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

Optional terms add their own arrays (``extra``) only when the scene enables them, e.g.
``xsph_dv`` (n, 3) for XSPH or ``omega`` (n, 3) for vorticity confinement.
"""
from dataclasses import dataclass, field

import numpy as np

#: fields that persist from step to step and follow particles when rows are reordered
PERSISTENT = ("id", "x", "v", "m")


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
    def create(cls, ids, x, v, m, dtype) -> "ParticleState":
        """Build a state from initial arrays; derived fields start at zero."""
        n = len(ids)
        return cls(
            id=np.ascontiguousarray(ids, dtype=np.int64),
            x=np.ascontiguousarray(x, dtype=dtype).reshape(n, 3),
            v=np.ascontiguousarray(v, dtype=dtype).reshape(n, 3),
            m=np.ascontiguousarray(m, dtype=dtype),
            a=np.zeros((n, 3), dtype=dtype),
            rho=np.zeros(n, dtype=dtype),
            p=np.zeros(n, dtype=dtype),
            n_owned=n,
        )

    @property
    def n(self) -> int:
        return self.id.shape[0]

    @property
    def dtype(self):
        return self.x.dtype

    def add_extra(self, name: str, shape_tail=(), dtype=None) -> np.ndarray:
        """Allocate (once) a per-particle array for an optional term."""
        if name not in self.extra:
            self.extra[name] = np.zeros((self.n, *shape_tail), dtype=dtype or self.dtype)
        return self.extra[name]

    def sorted_by_id(self) -> dict:
        """Owned rows as a dict of arrays sorted by id (the final.npz contract)."""
        k = self.n_owned
        order = np.argsort(self.id[:k], kind="stable")
        return {
            "id": self.id[:k][order],
            "x": self.x[:k][order],
            "v": self.v[:k][order],
            "rho": self.rho[:k][order],
        }
