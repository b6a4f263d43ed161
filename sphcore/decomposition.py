"""Domain decomposition on the global grid: blocks of cells, one per peer (seed 000, chapter 3).

The domain's global grid (``sphcore.grid.Grid``: same origin and cell size everywhere) is cut into
``dims = (px, py, pz)`` blocks along cell boundaries, so every cell belongs to exactly one peer.
Cells are at least H / R wide (H the support radius, R the grid's ``reach``: 1 or 2 cells per
support radius), so for a peer r:

* its *calculation area* is its block of cells;
* the *incoming zone* (ghosts) is the ring of cells R cells deep around the block — everything a
  particle of the block can interact with;
* its *outgoing zone towards peer q* is the set of its own cells inside q's incoming zone
  (diagonal neighbours included).

Because whole cells are exchanged, a peer's grid holds every cell that any of its particles
scans, with the same particles in the same (cell, id) order as a single-process run: the sums,
and so the results, are identical. No networking here: ``nodes/`` moves the bytes.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange


def choose_dims(n_peers: int, ncell, dim: int, layout: str = "auto", *, reach: int, cells=None,
                periodic=(False, False, False), vertical: int | None = None) -> tuple[int, int, int]:
    """Peers per axis. ``slabs``: all along the axis with the most cells. ``auto``: of the
    factorisations of n_peers into dim factors with at least 2 support radii (2 ``reach`` cells) per
    block along each cut axis,

    1. one that leaves the ``vertical`` axis (gravity's) uncut, if any does: water falls, so a cut
       across gravity leaves the upper blocks less and less to do while the cuts stay put;
    2. then, given the particles' (n, 3) integer ``cells``, the least work for the busiest peer with
       the cuts balanced (``Decomposition.balanced``): the largest block's particles plus the halo's
       share of one peer (``halo_particles`` / n_peers, the rows the peers hold and send as ghosts
       every step). Balancing cuts along each axis apart leaves blocks empty where the particles
       fill only part of an axis, and a step takes as long as its busiest peer;
    3. then the smallest block surface per cell."""
    ncell = np.asarray(ncell, dtype=np.int64)
    if n_peers < 1:
        raise ValueError(f"need at least one peer, got {n_peers}")
    axes = list(range(dim))
    candidates = []
    if layout == "slabs":
        axis = max(axes, key=lambda a: ncell[a])
        dims = [1, 1, 1]
        dims[axis] = n_peers
        candidates = [tuple(dims)]
    elif layout == "auto":
        divisors = [d for d in range(1, n_peers + 1) if n_peers % d == 0]
        for px in divisors:
            for py in divisors if dim == 3 else [n_peers // px]:
                if (n_peers // px) % py == 0:
                    candidates.append((px, py, n_peers // (px * py)) if dim == 3 else (px, py, 1))
    else:
        raise ValueError(f"layout must be 'auto' or 'slabs', got {layout!r}")
    histograms = None if cells is None else [np.bincount(cells[:, a], minlength=ncell[a]) for a in range(3)]
    best, best_cost = None, (math.inf, math.inf, math.inf)
    for dims in candidates:
        if any(ncell[a] < 2 * reach * dims[a] for a in range(3) if dims[a] > 1):
            continue
        size = ncell / np.asarray(dims)
        surface = sum(2 * math.prod(size[b] for b in range(dim) if b != a) for a in range(dim) if dims[a] > 1)
        surface += 1e-6 * max(dims)  # ties: prefer the more even split (smaller halo per block)
        work = 0.0
        if cells is not None:
            dec = Decomposition.from_histograms(tuple(int(n) for n in ncell), dims, histograms, periodic, reach=reach)
            largest = int(np.bincount(dec.owner(cells), minlength=n_peers).max()) if len(cells) else 0
            work = largest + halo_particles(dec, histograms) / n_peers
        cost = (int(vertical is not None and dims[vertical] > 1), work, surface)
        if cost < best_cost:
            best, best_cost = dims, cost
    if best is None:
        raise ValueError(f"{n_peers} peers do not fit a grid of {ncell.tolist()} cells "
                         f"(each block needs at least {2 * reach} cells, 2 support radii, along every cut axis)")
    return best


def halo_particles(dec: "Decomposition", histograms) -> float:
    """Particles within ``reach`` cells (one support radius) of a cut plane of ``dec``, both sides,
    summed over its cut planes (a periodic axis cut into blocks also has the plane where it wraps);
    ``histograms[a]`` (ncell[a],) the particle counts per cell layer along axis a. These are the rows
    the peers send each other as ghosts every step: a particle near two cut planes counts twice."""
    total = 0.0
    for a in range(3):
        if dec.dims[a] == 1:
            continue
        h = np.asarray(histograms[a], dtype=np.float64)
        planes = list(dec.cuts[a][1:-1]) + ([0] if dec.periodic[a] else [])
        for c in planes:
            total += float(h[np.arange(c - dec.reach, c + dec.reach) % len(h)].sum())
    return total


@dataclass(frozen=True)
class Decomposition:
    """Blocks of grid cells. ``cuts[a]`` (dims[a] + 1,) are the cell indices where blocks start along
    axis a (cuts[a][0] = 0, cuts[a][-1] = ncell[a]); ``periodic[a]`` wraps the halo across the
    domain boundary; ``reach`` is the grid's cells per support radius, the incoming zone's depth
    in cells (Grid.reach)."""

    ncell: tuple
    dims: tuple
    cuts: tuple
    periodic: tuple
    reach: int

    @classmethod
    def uniform(cls, ncell, dims, periodic=(False, False, False), *, reach) -> "Decomposition":
        cuts = tuple(tuple(int(round(k * ncell[a] / dims[a])) for k in range(dims[a] + 1)) for a in range(3))
        return cls(tuple(int(n) for n in ncell), tuple(dims), cuts, tuple(bool(p) for p in periodic), int(reach))

    @classmethod
    def balanced(cls, ncell, dims, cell_index, periodic=(False, False, False), *, reach) -> "Decomposition":
        """Cuts that give each block row about the same number of particles (cell_index: (n, 3)
        integer cell coordinates of the particles), axis by axis."""
        histograms = [np.bincount(cell_index[:, a], minlength=ncell[a]) for a in range(3)]
        return cls.from_histograms(ncell, dims, histograms, periodic, reach=reach)

    @classmethod
    def from_histograms(cls, ncell, dims, histograms, periodic=(False, False, False), *, reach) -> "Decomposition":
        """Balanced cuts from per-axis particle counts per cell layer (``histograms[a]``: (ncell[a],)),
        which peers can sum over the network; every block keeps at least 2 support radii (2 reach
        cells) along a cut axis."""
        cuts = []
        for a in range(3):
            cum = np.concatenate([[0.0], np.cumsum(np.asarray(histograms[a], dtype=np.float64))])
            c = [0]
            for k in range(1, dims[a]):
                target = cum[-1] * k / dims[a]
                cut = int(np.searchsorted(cum, target))  # first layer boundary at or past the target,
                if cut > 0 and target - cum[cut - 1] < cum[min(cut, len(cum) - 1)] - target:
                    cut -= 1                             # or the one before it if that is closer
                cut = min(max(cut, c[-1] + 2 * reach), ncell[a] - 2 * reach * (dims[a] - k))
                c.append(cut)
            c.append(int(ncell[a]))
            cuts.append(tuple(c))
        return cls(tuple(int(n) for n in ncell), tuple(dims), tuple(cuts), tuple(bool(p) for p in periodic),
                   int(reach))

    @property
    def n_peers(self) -> int:
        return math.prod(self.dims)

    def block_of(self, rank: int) -> tuple[int, int, int]:
        px, py, _ = self.dims
        return rank % px, (rank // px) % py, rank // (px * py)

    def rank_of(self, bx: int, by: int, bz: int) -> int:
        px, py, _ = self.dims
        return (bz * py + by) * px + bx

    def cell_box(self, rank: int) -> tuple[np.ndarray, np.ndarray]:
        """[lo, hi) cell indices of the block of ``rank``."""
        b = self.block_of(rank)
        lo = np.array([self.cuts[a][b[a]] for a in range(3)])
        hi = np.array([self.cuts[a][b[a] + 1] for a in range(3)])
        return lo, hi

    def owner(self, cell_index: np.ndarray) -> np.ndarray:
        """Rank owning each cell, for (n, 3) integer cell coordinates."""
        block = [np.searchsorted(np.asarray(self.cuts[a]), cell_index[:, a], side="right") - 1 for a in range(3)]
        px, py, _ = self.dims
        return (block[2] * py + block[1]) * px + block[0]

    def _gap(self, cells: np.ndarray, rank: int) -> np.ndarray:
        """Chebyshev distance in cells from each cell to the block of ``rank`` (0 inside), with
        periodic wrap."""
        lo, hi = self.cell_box(rank)
        gap = np.zeros(len(cells), dtype=np.int64)
        for a in range(3):
            c = cells[:, a]
            d = np.maximum(lo[a] - c, 0) + np.maximum(c - (hi[a] - 1), 0)
            if self.periodic[a]:
                n = self.ncell[a]
                d = np.minimum(d, np.maximum(lo[a] - (c - n), 0) + np.maximum((c - n) - (hi[a] - 1), 0))
                d = np.minimum(d, np.maximum(lo[a] - (c + n), 0) + np.maximum((c + n) - (hi[a] - 1), 0))
            gap = np.maximum(gap, d)
        return gap

    def in_halo(self, cells: np.ndarray, rank: int) -> np.ndarray:
        """Mask of cells in the incoming zone of ``rank`` (``reach`` cells around its block, not inside)."""
        gap = self._gap(cells, rank)
        return (gap >= 1) & (gap <= self.reach)

    def neighbours(self, rank: int) -> list[int]:
        """Peers whose blocks touch the incoming zone of ``rank`` (diagonals included), ascending."""
        out = []
        lo, hi = self.cell_box(rank)
        for q in range(self.n_peers):
            if q == rank:
                continue
            qlo, qhi = self.cell_box(q)
            # q's block corners are enough to test the Chebyshev gap between two boxes
            touch = True
            for a in range(3):
                d = max(lo[a] - qhi[a] + 1, qlo[a] - hi[a] + 1, 0)
                if self.periodic[a]:
                    n = self.ncell[a]
                    d = min(d, max(lo[a] - (qhi[a] - n) + 1, (qlo[a] - n) - hi[a] + 1, 0),
                            max(lo[a] - (qhi[a] + n) + 1, (qlo[a] + n) - hi[a] + 1, 0))
                if d > self.reach:
                    touch = False
            if touch:
                out.append(q)
        return out

    def outgoing(self, cells: np.ndarray, rank: int, to: int) -> np.ndarray:
        """Mask of the particles of ``rank`` (their (n, 3) cells) that peer ``to`` needs as ghosts."""
        return self.in_halo(cells, to)


# -- what exchange 1 asks of every owned particle, on the host or on a GPU (Engine.zone_rows) ------

def zone_tables(dec: Decomposition, rank: int, neighbours) -> tuple:
    """The decomposition as ``zone_code`` reads it: cuts (3, max dims + 1) int64 (padded with the
    axis's cell count), dims (3,), the neighbours' blocks (k, 6) [lo (3), hi (3)] int64, ncell (3,),
    periodic (3,) int64 and the reach (an int: the incoming zone's depth in cells)."""
    width = max(dec.dims) + 1
    cuts = np.array([list(c) + [c[-1]] * (width - len(c)) for c in dec.cuts], dtype=np.int64)
    boxes = np.array([np.concatenate(dec.cell_box(q)) for q in neighbours], dtype=np.int64).reshape(-1, 6)
    return (cuts, np.array(dec.dims, dtype=np.int64), boxes, np.array(dec.ncell, dtype=np.int64),
            np.array(dec.periodic, dtype=np.int64), int(dec.reach))


@njit(cache=True, inline="always")
def zone_code(c0, c1, c2, cuts, dims, boxes, ncell, periodic, reach):
    """(owner, mask) of a particle in cell (c0, c1, c2): the rank owning the cell (as
    ``Decomposition.owner``) and bit b set when the cell lies in the incoming zone of neighbour b
    (``Decomposition.outgoing`` to the b-th row of ``boxes``, periodic wrap included)."""
    block0 = 0
    block1 = 0
    block2 = 0
    for j in range(1, dims[0]):
        if c0 >= cuts[0, j]:
            block0 = j
    for j in range(1, dims[1]):
        if c1 >= cuts[1, j]:
            block1 = j
    for j in range(1, dims[2]):
        if c2 >= cuts[2, j]:
            block2 = j
    owner = (block2 * dims[1] + block1) * dims[0] + block0
    mask = 0
    for b in range(boxes.shape[0]):
        gap = 0
        for a in range(3):
            c = c0 if a == 0 else (c1 if a == 1 else c2)
            lo = boxes[b, a]
            hi = boxes[b, 3 + a]
            d = max(lo - c, 0) + max(c - (hi - 1), 0)
            if periodic[a]:
                n = ncell[a]
                d = min(d, max(lo - (c - n), 0) + max((c - n) - (hi - 1), 0))
                d = min(d, max(lo - (c + n), 0) + max((c + n) - (hi - 1), 0))
            gap = max(gap, d)
        if gap >= 1 and gap <= reach:
            mask |= 1 << b
    return owner, mask


@njit(cache=True, parallel=True)
def zone_codes(cells, cuts, dims, boxes, ncell, periodic, reach, owner, mask):
    """zone_code of every row of ``cells`` (n, 3) into owner (n,) and mask (n,)."""
    for i in prange(cells.shape[0]):
        owner[i], mask[i] = zone_code(cells[i, 0], cells[i, 1], cells[i, 2], cuts, dims, boxes, ncell, periodic,
                                      reach)
