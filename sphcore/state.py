"""Particle state as a structure of arrays.

One ``ParticleState`` holds every per-particle quantity as its own numpy array. Rows are particles;
the first ``n_owned`` rows are particles this process integrates (in a distributed run ghost rows
follow them). Vectors always have 3 components; in 2D scenes z = 0.

Fields (float = float32 or float64, the run's precision):

=========  ========  =======  =============  ============================================================
field      shape     dtype    unit           meaning; why it is carried (CARRIED) or not (DERIVED)
=========  ========  =======  =============  ============================================================
id         (n,)      int64                   stable global particle id, never reused (CARRIED: the
                                             neighbour order and every gather by id rest on it)
x          (n, 3)    float    m              position (CARRIED: integrated)
v          (n, 3)    float    m/s            velocity; half-step velocity with the leapfrog integrator
                                             (CARRIED: integrated)
m          (n,)      float    kg             mass (CARRIED: fixed per particle)
a          (n, 3)    float    m/s^2          acceleration of the current step (DERIVED)
rho        (n,)      float    kg/m^3         density (DERIVED: the summation density every step; the
                                             continuity density is carried in ``extra``)
p          (n,)      float    Pa             pressure (DERIVED: from rho by the equation of state)
=========  ========  =======  =============  ============================================================

``extra`` holds the per-solver arrays that are CARRIED too: a step reads the value the previous
step left, so they must follow their particle when the grid reorders rows, move with it to another
peer (migration, rebalancing, ``take_block``) and go into checkpoints (as ``extra_<name>``). The
solver adds the ones it needs (sphcore/solver.py ``extra_names``; 0 is a cold start):

=========  ========  =======  =============  ============================================================
extra      shape     dtype    unit           meaning; why it is carried
=========  ========  =======  =============  ============================================================
kappa      (n,)      float    m^5/(kg s^2)   DFSPH's kappa = p / rho^2, the next density solve's warm
                                             start (physics/dfsph.py)
density    (n,)      float    kg/m^3         sph.density = "continuity": rho integrated in time by
                                             d rho / dt, not recomputed (physics/continuity.py)
x_ref      (n, 3)    float    m              run.neighbour_skin > 0: the position at the last list
                                             build, which the filtered lists hold until a particle
                                             moves part of the skin from it (grid.py)
=========  ========  =======  =============  ============================================================

Every place that copies, moves or saves particles (the grid's reorder, the halo's migrants and
rebalancing, ``take_block``, checkpoints, the CUDA backend) takes the field names from ``CARRIED`` /
``FIELDS`` and the extras from ``state.extra`` through the helpers below, so a new carried array is
declared once. Per-step scratch of optional terms (the XSPH correction, the vorticity) lives in the
solver instead, since it is recomputed every step.
"""
from dataclasses import dataclass, field

import numpy as np

CARRIED = ("id", "x", "v", "m")   # travel with a particle (with state.extra); the rest is recomputed
DERIVED = ("a", "rho", "p")       # recomputed every step from the carried fields
FIELDS = CARRIED + DERIVED        # every named per-particle field
ROW_SHAPE = {"id": (), "x": (3,), "v": (3,), "m": (), "a": (3,), "rho": (), "p": ()}  # one row of each
EXTRA_PREFIX = "extra_"           # state.extra[name] travels (wire, checkpoints) as "extra_<name>"
EXTRA_ROW_SHAPE = {"x_ref": (3,)}  # one row of an extra array that is not (n,)


def is_carried(name: str) -> bool:
    """Whether ``name`` is the key of a carried array in a message or a checkpoint part."""
    return name in CARRIED or name.startswith(EXTRA_PREFIX)


def carried_layout(n: int, dtype, extra: dict) -> dict:
    """name -> (shape, dtype) of the carried arrays of n particles: what a particle message must
    hold. ``extra``: the state's extra arrays (only their row shapes are used)."""
    layout = {name: ((n,) + ROW_SHAPE[name], np.int64 if name == "id" else dtype) for name in CARRIED}
    layout.update({EXTRA_PREFIX + k: ((n,) + a.shape[1:], dtype) for k, a in extra.items()})
    return layout


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

    @classmethod
    def from_carried(cls, arrays: dict, dtype) -> "ParticleState":
        """The inverse of ``carried_arrays``: a state (all rows owned, derived fields zero) from the
        carried arrays of a message or a checkpoint, extras under "extra_<name>"."""
        extra = {k[len(EXTRA_PREFIX):]: a for k, a in arrays.items() if k.startswith(EXTRA_PREFIX)}
        return cls.create(*(arrays[name] for name in CARRIED), dtype, extra=extra)

    @property
    def n(self) -> int:
        return self.id.shape[0]

    @property
    def dtype(self):
        return self.x.dtype

    def carried_arrays(self, n: int) -> dict:
        """The carried arrays of rows 0..n-1 (views): id, x, v, m, then each extra as "extra_<name>".
        These names are the wire's and the checkpoints' (keep them: old checkpoints must load)."""
        arrays = {name: getattr(self, name)[:n] for name in CARRIED}
        arrays.update({EXTRA_PREFIX + k: a[:n] for k, a in self.extra.items()})
        return arrays

    def per_particle(self) -> dict:
        """Every per-particle array, all rows: the named fields, then each extra as "extra_<name>"."""
        arrays = {name: getattr(self, name) for name in FIELDS}
        arrays.update({EXTRA_PREFIX + k: a for k, a in self.extra.items()})
        return arrays

    def take(self, rows) -> "ParticleState":
        """A new state of the rows ``rows`` (an index array or a boolean mask over all rows), in that
        order: every field, derived ones included (a, rho, p keep their values), and every extra
        array filtered alike, as contiguous copies. The taken rows are all owned (n_owned = their
        count): take whole particle sets (a peer's block, a checkpoint's part), not ghosts."""
        taken = {name: np.ascontiguousarray(getattr(self, name)[rows]) for name in FIELDS}
        extra = {k: np.ascontiguousarray(a[rows]) for k, a in self.extra.items()}
        return ParticleState(**taken, n_owned=taken["id"].shape[0], extra=extra)


def with_new_owned(state: ParticleState, keep, ids, x, v, m: float, rho0: float) -> ParticleState:
    """``state`` with its owned rows filtered by ``keep`` (a boolean mask over them) and new owned rows
    (ids, x, v; mass m, density rho0, pressure and every carried extra 0) after them, the ghost
    rows kept behind them, unchanged (what follows the step, e.g. a frame's surface, still reads
    them; the next step rebuilds them)."""
    n = state.n_owned
    fresh = ParticleState.create(ids, x, v, np.full(len(ids), m), state.dtype,
                                 extra={k: np.zeros((len(ids),) + a.shape[1:]) for k, a in state.extra.items()})
    fresh.rho[:] = rho0
    parts = [state.take(np.nonzero(keep)[0]), fresh, state.take(np.arange(n, state.n))]
    joined = {name: np.concatenate([getattr(p, name) for p in parts]) for name in FIELDS}
    extra = {k: np.concatenate([p.extra[k] for p in parts]) for k in state.extra}
    return ParticleState(**joined, n_owned=parts[0].n + parts[1].n, extra=extra)


def merge_by_id(parts: list[dict], keys) -> dict:
    """Per-particle arrays of several parts (peers, checkpoint files) joined and sorted by id."""
    arrays = {k: np.concatenate([p[k] for p in parts]) for k in keys}
    order = np.argsort(arrays["id"], kind="stable")
    return {k: a[order] for k, a in arrays.items()}
