"""Uniform-grid neighbour search with a deterministic neighbour order.

The grid is global: the same ``origin`` and ``cell`` sizes on every process, so a cell means the same
box of space everywhere. Cells are at least H / R wide, where H is the support radius and R the
grid's *reach* (``run.cells_per_support``, 1 or 2), so all neighbours of a particle lie in its own
cell and the R cells on each side of it: (2R + 1)^dim cells. Halving the cells (R = 2) halves the
candidates a search tests (about 225 -> 118 per particle on the 3D dam break: the 5^3 cells, less
those farther than H, cover 10.5 H^3 against 20.6 H^3 for 3^3 cells of H, around a support sphere
of 4.2 H^3) for 8x the cells (docs/BENCHMARKS.md).

Each step (``Grid.bin``):

1. cell key of every particle, ``key = (iz * ny + iy) * nx + ix``;
2. counting sort by key (histogram, prefix sum, stable scatter), then within each cell an insertion
   sort by global ``id`` — rows end up ordered by (cell, id), whatever order they came in;
3. all persistent particle arrays are reordered to that order (locality for the passes);
4. with neighbour lists (``NEIGHBOUR_LISTS``), the list of every owned particle is built by scanning
   neighbour cells in a fixed order (z, then y, then x; the x-neighbours of a row are contiguous
   in memory). With the cell walk (``CELL_WALK``) nothing is built: every neighbour pass visits the
   same cells in the same order itself (``home_cell``, ``cell_span``), reading ``cell_begin`` and
   ``cell_end``, so its candidates arrive in the order the list would hold them.

Summing in this order is what makes a run reproducible bit for bit, and what lets a distributed
run (ghost rows included) reproduce a single-process run exactly.

With a skin (``run.neighbour_skin`` = s > 0, lists on the CPU), steps 1-4 run only when needed (a
Verlet list): step 4 lists every row within H (1 + s) (the *candidates*, cells sized for that
radius) at the rows' reference positions (``state.extra["x_ref"]``, carried: checkpoints hold it),
which a build sets to x, and which place the rows in cells. Each step then filters every row's
candidates to those within H, in their order, which costs about a quarter of a build; a new build
comes once some particle has moved ``REUSE_SHARE`` s H from its reference position (two particles
that were farther apart than H (1 + s) then cannot have come within H of each other: the triangle
inequality, with a margin over rounding). The sums run in the candidates' order of the last build,
so a resumed run sorts and lists by the saved reference positions, and reproduces the continuous
run bit for bit. ``Simulation._reuse_lists`` decides, alike on every peer.

Periodic axes wrap cell indices and use minimum-image distances; along them the cell size is
stretched to L / (R floor(L / H)) so the cells tile the period exactly (the period must hold at
least 3 support radii).
"""
import math
from typing import NamedTuple

import numpy as np
from numba import literally, njit, prange

from sphcore.backends.literal import literal_dispatch
from sphcore.physics.real import like
from sphcore.simd import AVX512, append_listed, append_range, lanes
from sphcore.state import CARRIED


# How a neighbour pass finds its neighbours (the compile-time choice ``neighbours``, stages.CHOICES)
NEIGHBOUR_LISTS = 0  # read the list Grid.build_neighbours wrote (nbr, counts)
CELL_WALK = 1        # walk the cells around the row (cells, cell_begin, cell_end); no list is stored
REACHES = (1, 2)     # grid cells per support radius along an axis (run.cells_per_support)
# With a skin s: a build comes once some particle has moved this share of s H since the last one. Half
# would be exact in real numbers (|dx_i| + |dx_j| < s H); 0.45 leaves 5 % of the skin for rounding
# (float32 positions carry ~1e-7 relative error; the skin is ~1e-3 of H at least).
REUSE_SHARE = 0.45


class Cells(NamedTuple):
    """The grid as the cell walk reads it, a row of scalars passed by value (lengths in the run's
    precision, the same values the list builder reads from the Grid's arrays)."""
    ox: float    # origin (m)
    oy: float
    oz: float
    sx: float    # cell size (m)
    sy: float
    sz: float
    ux: float    # 1 / cell size (1/m)
    uy: float
    uz: float
    nx: int      # cells per axis
    ny: int
    nz: int
    px: bool     # periodic along the axis
    py: bool
    pz: bool
    H2: float    # squared support radius (m^2), as Grid.H2
    rx: int      # cells the walk visits on each side of the home cell along the axis: the reach R,
    ry: int      # or 0 along an axis of one cell that is not periodic (the z axis of a 2D scene)
    rz: int
    spans: int   # cells the walk visits: (2 rx + 1)(2 ry + 1)(2 rz + 1)


@njit(inline="always")
def cell_index(x, i, d, origin, inv_cell, ncell):
    """Cell coordinate of row i along axis d, clamped to the grid (the one definition of "the cell
    of a particle": the grid and the decomposition's owners both use it). int() truncates toward
    zero, which after the clamp to >= 0 is the floor; math.floor would compute in float64 on a GPU."""
    return min(max(int((x[i, d] - origin[d]) * inv_cell[d]), 0), ncell[d] - 1)


@njit(cache=True, inline="always")
def minimum_image(d, L):
    """d (a coordinate difference) mapped to [-L/2, L/2] on a periodic axis of length L. Positions
    are wrapped into the period every step, so |d| < L and one shift suffices. (A branch, not
    d - L rint(d / L): numba-cuda has no rint, and math.floor would promote float32 to float64.)"""
    half = like(L, 0.5) * L
    if d > half:
        return d - L
    if d < -half:
        return d + L
    return d


@njit(cache=True, inline="always")
def wrapped(periodic, dx, dy, dz, period):
    """(dx, dy, dz) with the minimum image on the periodic axes: the one separation of the
    list builder, the candidate filter and the displacement check."""
    if periodic:
        if period[0] > 0.0:
            dx = minimum_image(dx, period[0])
        if period[1] > 0.0:
            dy = minimum_image(dy, period[1])
        if period[2] > 0.0:
            dz = minimum_image(dz, period[2])
    return dx, dy, dz


@njit(cache=True, parallel=True)
def compute_cell_keys(x, n_owned, origin, inv_cell, ncell, keys):
    """keys[i] = cell key of row i, plus ncells for ghost rows (i >= n_owned): sorting by key puts
    owned rows first and ghost rows after, each in (cell, id) order."""
    nx, ny, nz = ncell[0], ncell[1], ncell[2]
    ncells = nx * ny * nz
    for i in prange(x.shape[0]):
        ix = cell_index(x, i, 0, origin, inv_cell, ncell)
        iy = cell_index(x, i, 1, origin, inv_cell, ncell)
        iz = cell_index(x, i, 2, origin, inv_cell, ncell)
        keys[i] = (iz * ny + iy) * nx + ix + (ncells if i >= n_owned else 0)


@njit(cache=True, parallel=True)
def compute_cell_coords(x, origin, inv_cell, ncell, out):
    """out[i] = (ix, iy, iz) of every row of x."""
    for i in prange(x.shape[0]):
        for d in range(3):
            out[i, d] = cell_index(x, i, d, origin, inv_cell, ncell)


@njit(cache=True)
def _scatter_by_key(keys, cell_start, perm):
    """Histogram, exclusive prefix sum and stable scatter (serial, memory-bound). The passes over
    the bins stop at the largest key (the bins after it start at n): an owned-rows sort leaves the
    ghost half of the bins, as many as the cells, to a fill. The scatter advances each bin's start
    to its end, the next bin's start, and one pass shifts them back: no copy of the bins."""
    n = keys.shape[0]
    top = 0  # bins [0, top) hold rows
    for i in range(n):
        if keys[i] >= top:
            top = keys[i] + 1
    cell_start[:top + 1] = 0
    for i in range(n):
        cell_start[keys[i] + 1] += 1
    for c in range(top):
        cell_start[c + 1] += cell_start[c]
    for i in range(n):
        k = keys[i]
        perm[cell_start[k]] = i
        cell_start[k] += 1
    for c in range(top, 0, -1):
        cell_start[c] = cell_start[c - 1]
    cell_start[0] = 0
    cell_start[top + 1:] = n


@njit(cache=True)
def _scatter_ghosts(keys, n_owned, ncells, bin_start, perm):
    """The ghost rows' bins [ncells, 2 ncells) and their stable order in perm[n_owned:], after a sort
    of the owned rows alone (which leaves every ghost bin starting at n_owned; perm[:n_owned] is the
    identity). The ghosts are few and their cells fewer: they are ordered by a stable sort of their
    keys, and the ghost bins are rewritten as the runs of one start value between the ghosts' cells,
    from the first ghost's cell on: no histogram, prefix sum or copy over every cell (a peer's grid
    is the global one; docs/BENCHMARKS.md). The same perm and bin_start as the counting scatter."""
    n = keys.shape[0]
    for i in range(n_owned):
        perm[i] = i
    order = np.argsort(keys[n_owned:], kind="mergesort")  # stable: a cell's rows keep their order
    b = ncells + 1  # bins up to the first ghost's keep their start, n_owned
    if n > n_owned:
        b = keys[n_owned + order[0]] + 1
    for t in range(n - n_owned):
        i = n_owned + order[t]
        perm[n_owned + t] = i
        while b <= keys[i]:  # bins before row i's own, after the previous row's: t ghosts precede them
            bin_start[b] = n_owned + t
            b += 1
    while b <= 2 * ncells:
        bin_start[b] = n
        b += 1


@njit(cache=True)
def _ghost_cell_ranges(keys, n_owned, ncells, bin_start, perm, cell_begin, cell_end):
    """After ``_cell_ranges`` of the owned rows alone and ``_scatter_ghosts``: the ranges of the
    cells holding ghost rows (the others keep theirs); returns how many also hold owned rows."""
    mixed = 0
    for k in range(n_owned, perm.shape[0]):
        c = keys[perm[k]]
        if k == n_owned or keys[perm[k - 1]] != c:
            mixed += cell_range_row(c - ncells, bin_start, ncells, cell_begin, cell_end)
    return mixed


@njit(cache=True, parallel=True)
def _sort_bins_by_id(first, keys, bin_start, perm, ids):
    """sort_bin_row of every non-empty bin holding rows perm[first:]: each bin is sorted by the
    row that starts it (its key differs from the row before), so the work is O(rows), not O(bins)
    (most bins are empty, the more so with cells of H / 2 and in a peer's global grid)."""
    for k in prange(first, perm.shape[0]):
        c = keys[perm[k]]
        if k == first or keys[perm[k - 1]] != c:
            sort_bin_row(c, bin_start, perm, ids)


@njit(cache=True, inline="always")
def sort_bin_row(c, bin_start, perm, ids):
    """Insertion sort of bin c's slice of ``perm`` by id; cheap because slices are short and nearly
    sorted from the previous step (shared by the CPU driver below and the CUDA kernel)."""
    lo, hi = bin_start[c], bin_start[c + 1]
    for k in range(lo + 1, hi):
        pk = perm[k]
        idk = ids[pk]
        j = k - 1
        while j >= lo and ids[perm[j]] > idk:
            perm[j + 1] = perm[j]
            j -= 1
        perm[j + 1] = pk


def counting_sort(keys, ids, bin_start, perm):
    """Permutation ordering rows by (key, id); fills ``bin_start`` (nbins + 1)."""
    _scatter_by_key(keys, bin_start, perm)
    _sort_bins_by_id(0, keys, bin_start, perm, ids)


@njit(cache=True, inline="always")
def cell_range_row(c, bin_start, ncells, cell_begin, cell_end):
    """Row range of cell c from the owned bins [0, ncells) or the ghost bins [ncells, 2 ncells).
    A cell holds owned or ghost rows, never both (cuts lie on cell faces); returns 1 if cell c
    breaks that rule (a missed migration), else 0."""
    own_lo, own_hi = bin_start[c], bin_start[c + 1]
    gh_lo, gh_hi = bin_start[ncells + c], bin_start[ncells + c + 1]
    if gh_hi > gh_lo:
        cell_begin[c] = gh_lo
        cell_end[c] = gh_hi
        return 1 if own_hi > own_lo else 0
    # owned or empty: empty cells keep their place in the owned sequence (contiguous rows)
    cell_begin[c] = own_lo
    cell_end[c] = own_hi
    return 0


@njit(cache=True, parallel=True)
def _cell_ranges(bin_start, ncells, cell_begin, cell_end):
    """cell_begin/cell_end of every cell; returns the number of cells holding both owned and ghost
    rows (0 unless a migration was missed)."""
    mixed = 0
    for c in prange(ncells):
        mixed += cell_range_row(c, bin_start, ncells, cell_begin, cell_end)
    return mixed


@njit(cache=True, parallel=True)
def gather_rows_2d(src, perm, dst):
    for k in prange(perm.shape[0]):
        i = perm[k]
        for c in range(src.shape[1]):
            dst[k, c] = src[i, c]


@njit(cache=True, parallel=True)
def gather_rows_1d(src, perm, dst):
    for k in prange(perm.shape[0]):
        dst[k] = src[perm[k]]


@njit(cache=True, inline="always")
def _scan_range(store_all, i, lo, hi, x, xi, yi, zi, H2, period, periodic, nbr, count, cap):
    """Append to row i of ``nbr`` every j != i in [lo, hi) within the support; count past the
    capacity so the caller can grow it and rebuild. Row i itself lies in one range only (its own
    cell's), which is scanned on either side of it: no candidate is compared with i. (Two call
    sites of _scan_span, each a copy of its body: a loop over the spans with one call compiled
    faster but built the 49k dam break's list 10 % slower.)"""
    if lo <= i < hi:
        count = _scan_span(store_all, i, lo, i, x, xi, yi, zi, H2, period, periodic, nbr, count, cap)
        return _scan_span(store_all, i, i + 1, hi, x, xi, yi, zi, H2, period, periodic, nbr, count, cap)
    return _scan_span(store_all, i, lo, hi, x, xi, yi, zi, H2, period, periodic, nbr, count, cap)


@njit(cache=True, inline="always")
def _scan_span(store_all, i, lo, hi, x, xi, yi, zi, H2, period, periodic, nbr, count, cap):
    """Append to row i of ``nbr`` every j in [lo, hi) (which excludes i) within the support. With
    ``store_all`` (the CPU) it is branch-free: every candidate is stored at the next free column
    (column ``cap``, a spare, once the list is full) and the count advances only for a neighbour;
    about a third of the candidates are accepted, in no pattern a branch predictor could learn, so a
    branch here mispredicts on most particles' every few candidates. On a CPU with AVX-512 the range
    goes through in chunks of simd.lanes candidates (16 in float32), one compress-store each
    (simd.py), while a whole chunk fits below the capacity; the scalar loop takes the rest. On a
    GPU (``store_all`` false) only neighbours are stored: there a store per candidate is a scattered
    write for every lane of a warp, about four times the list's own writes. The lists are the same
    every way."""
    j0 = lo
    if store_all and AVX512 and not periodic:
        chunk = lanes(x)
        while j0 < hi and count + chunk <= cap:
            count = append_range(x, j0, min(chunk, hi - j0), xi, yi, zi, H2, nbr, i, count)
            j0 += chunk
    for j in range(j0, hi):
        dx, dy, dz = wrapped(periodic, xi - x[j, 0], yi - x[j, 1], zi - x[j, 2], period)
        inside = dx * dx + dy * dy + dz * dz < H2
        if store_all:
            nbr[i, min(count, cap)] = j
            count += 1 if inside else 0
        elif inside:
            nbr[i, min(count, cap)] = j
            count += 1
    return count


@njit(cache=True, inline="always")
def _face_gap2(offset, xi, lo_face, size):
    """Squared distance from coordinate xi to the cell ``offset`` cells away from its own (whose
    lower face is at lo_face, cells ``size`` wide) along one axis; 0 for the own cell. It grows with
    |offset| (rounding is monotone), so a run of cells can stop at the first one out of reach."""
    zero = like(xi, 0.0)
    if offset < 0:
        g = max(xi - (lo_face + like(xi, offset + 1) * size), zero)
    elif offset > 0:
        g = max(lo_face + like(xi, offset) * size - xi, zero)
    else:
        return zero
    return g * g


@njit(cache=True, inline="always")
def neighbour_row(periodic, store_all, i, x, contiguous, cell_begin, cell_end, origin, cell, inv_cell, ncell, reach,
                  period, H2, nbr, counts):
    """Neighbour list of row i (shared by the CPU driver below and the CUDA kernel). The cells within
    ``reach`` of row i's own are visited in a fixed order (z, y, x); a cell (or a whole row of cells)
    farther than H from the particle is skipped, which removes about a quarter of the candidates
    with cells of H and half with cells of H / 2. ``store_all``: how _scan_range stores (true on the
    CPU, false on a GPU)."""
    nx, ny, nz = ncell[0], ncell[1], ncell[2]
    px, py, pz = period[0] > 0.0, period[1] > 0.0, period[2] > 0.0
    cap = nbr.shape[1] - 1  # the last column is the spare of _scan_range
    xi, yi, zi = x[i, 0], x[i, 1], x[i, 2]
    ix = min(max(int((xi - origin[0]) * inv_cell[0]), 0), nx - 1)
    iy = min(max(int((yi - origin[1]) * inv_cell[1]), 0), ny - 1)
    iz = min(max(int((zi - origin[2]) * inv_cell[2]), 0), nz - 1)
    x_lo = origin[0] + like(xi, ix) * cell[0]
    y_lo = origin[1] + like(yi, iy) * cell[1]
    z_lo = origin[2] + like(zi, iz) * cell[2]
    count = 0
    for dz in range(-reach, reach + 1):
        cz = iz + dz
        if cz < 0 or cz >= nz:
            if not pz:
                continue
            cz = (cz + nz) % nz
        gz = _face_gap2(dz, zi, z_lo, cell[2])
        if gz >= H2:
            continue
        for dy in range(-reach, reach + 1):
            cy = iy + dy
            if cy < 0 or cy >= ny:
                if not py:
                    continue
                cy = (cy + ny) % ny
            gyz = gz + _face_gap2(dy, yi, y_lo, cell[1])
            if gyz >= H2:
                continue
            row = (cz * ny + cy) * nx
            left = 0  # cells of the row within reach on each side
            while left < reach and gyz + _face_gap2(-(left + 1), xi, x_lo, cell[0]) < H2:
                left += 1
            right = 0
            while right < reach and gyz + _face_gap2(right + 1, xi, x_lo, cell[0]) < H2:
                right += 1
            # The cells -left..right of the row as ranges of rows, each scanned once, in order: where
            # the row's cells are stored one after another (and no periodic wrap splits them), one
            # range; otherwise cell by cell, but cells whose rows follow one another in memory (a
            # peer's owned cells of the row, or its ghost cells: each kind is stored in cell order)
            # make one range. The same rows in the same order as cell by cell, in fewer, longer
            # scans, through one call site of _scan_range: numba copies an inlined body into each
            # call site, and with three (one per case, one for the last range) the list builder
            # compiled in 18.8 s instead of 7.2 s, to the same speed.
            one_range = contiguous and (not px or (ix >= reach and ix + reach < nx))
            k = -left  # the next cell of the row to look at
            while k <= right:
                if one_range:
                    run_lo = cell_begin[row + max(ix - left, 0)]
                    run_hi = cell_end[row + min(ix + right, nx - 1)]
                    k = right + 1
                else:
                    run_lo = -1
                    run_hi = -1
                    while k <= right:
                        cx = ix + k
                        if cx < 0 or cx >= nx:
                            if not px:
                                k += 1
                                continue
                            cx = (cx + nx) % nx
                        begin = cell_begin[row + cx]
                        if run_lo >= 0 and begin != run_hi:
                            break  # cell k starts the next range
                        if run_lo < 0:
                            run_lo = begin
                        run_hi = cell_end[row + cx]
                        k += 1
                    if run_lo < 0:
                        break  # the rest of the row lies outside the grid
                count = _scan_range(store_all, i, run_lo, run_hi, x, xi, yi, zi, H2, period, periodic, nbr, count,
                                    cap)
    counts[i] = count


@njit(cache=True, inline="always")
def home_cell(x, i, c):
    """(ix, iy, iz, xi, yi, zi, lower x, y, z faces) of row i's cell: where the walk starts. The same
    cell and faces as neighbour_row computes, so the walk visits what the list holds."""
    xi, yi, zi = x[i, 0], x[i, 1], x[i, 2]
    ix = min(max(int((xi - c.ox) * c.ux), 0), c.nx - 1)
    iy = min(max(int((yi - c.oy) * c.uy), 0), c.ny - 1)
    iz = min(max(int((zi - c.oz) * c.uz), 0), c.nz - 1)
    return (ix, iy, iz, xi, yi, zi,
            c.ox + like(xi, ix) * c.sx, c.oy + like(yi, iy) * c.sy, c.oz + like(zi, iz) * c.sz)


@njit(cache=True, inline="always")
def _wrap(ci, n, periodic):
    """Cell coordinate ci on an axis of n cells: wrapped on a periodic axis, -1 outside otherwise."""
    if ci < 0 or ci >= n:
        if not periodic:
            return -1
        return (ci + n) % n
    return ci


@njit(cache=True, inline="always")
def cell_span(s, home, c, cell_begin, cell_end):
    """Rows [lo, hi) of the walk's s-th cell (s = 0 .. c.spans - 1: z, then y, then x offsets from
    -r to +r around the home cell), or an empty span when that cell lies outside the grid or farther
    than H from the particle (the pruning of neighbour_row: the same gap sums in the same order; a
    row that neighbour_row skips has a gap sum at least as large in every cell of it)."""
    ix, iy, iz, xi, yi, zi, x_lo, y_lo, z_lo = home
    wx = 2 * c.rx + 1
    wy = 2 * c.ry + 1
    dz = s // (wx * wy) - c.rz
    dy = (s // wx) % wy - c.ry
    dx = s % wx - c.rx
    g = _face_gap2(dz, zi, z_lo, c.sz) + _face_gap2(dy, yi, y_lo, c.sy)
    if dx != 0:
        g = g + _face_gap2(dx, xi, x_lo, c.sx)
    if g >= c.H2:
        return 0, 0
    cz = _wrap(iz + dz, c.nz, c.pz)
    cy = _wrap(iy + dy, c.ny, c.py)
    cx = _wrap(ix + dx, c.nx, c.px)
    if cz < 0 or cy < 0 or cx < 0:
        return 0, 0
    cell = (cz * c.ny + cy) * c.nx + cx
    return cell_begin[cell], cell_end[cell]


@literal_dispatch(1)
@njit(cache=True, parallel=True)
def _build_neighbours(periodic, x, n_query, contiguous, cell_begin, cell_end, origin, cell, inv_cell, ncell, reach,
                      period, H2, nbr, counts):
    """Neighbour lists of rows 0..n_query-1 (neighbour_row)."""
    literally(periodic)
    for i in prange(n_query):
        # np.int64: numba types a prange index as uint64, and uint64 with int64 is float64 arithmetic
        neighbour_row(periodic, True, np.int64(i), x, contiguous, cell_begin, cell_end, origin, cell, inv_cell, ncell,
                      reach, period, H2, nbr, counts)


@literal_dispatch(1)
@njit(cache=True, parallel=True)
def _build_neighbour_rows(periodic, x, rows, contiguous, cell_begin, cell_end, origin, cell, inv_cell, ncell, reach,
                          period, H2, nbr, counts):
    """Neighbour lists of the rows ``rows`` only (neighbour_row); the other rows' lists are left as
    they are (a peer lists its interior rows while the ghosts travel, the boundary rows after)."""
    literally(periodic)
    for k in prange(rows.shape[0]):
        neighbour_row(periodic, True, rows[k], x, contiguous, cell_begin, cell_end, origin, cell, inv_cell, ncell,
                      reach, period, H2, nbr, counts)


@njit(cache=True, inline="always")
def filter_row(periodic, i, x, cand, cand_counts, period, H2, nbr, counts):
    """Row i's neighbour list from its candidate list (a skin's Verlet list): every candidate j within
    H of row i now (the separation as neighbour_row computes it), in the candidates' order.
    Branch-free stores, as _scan_span's (the last column of ``nbr`` is the spare); with AVX-512 in
    compress-stored chunks while a whole chunk fits below the capacity (simd.py)."""
    cap = nbr.shape[1] - 1
    xi, yi, zi = x[i, 0], x[i, 1], x[i, 2]
    count = 0
    m = cand_counts[i]
    k0 = 0
    if AVX512 and not periodic:
        chunk = lanes(x)
        while k0 < m and count + chunk <= cap:
            count = append_listed(x, cand, i, k0, min(chunk, m - k0), xi, yi, zi, H2, nbr, count)
            k0 += chunk
    for k in range(k0, m):
        j = cand[i, k]
        dx, dy, dz = wrapped(periodic, xi - x[j, 0], yi - x[j, 1], zi - x[j, 2], period)
        inside = dx * dx + dy * dy + dz * dz < H2
        nbr[i, min(count, cap)] = j
        count += 1 if inside else 0
    counts[i] = count


@literal_dispatch(1)
@njit(cache=True, parallel=True)
def _filter_neighbours(periodic, x, n_query, cand, cand_counts, period, H2, nbr, counts):
    """Neighbour lists of rows 0..n_query-1 from their candidates (filter_row)."""
    literally(periodic)
    for i in prange(n_query):
        # np.int64: as in _build_neighbours, no float64 index arithmetic
        filter_row(periodic, np.int64(i), x, cand, cand_counts, period, H2, nbr, counts)


@literal_dispatch(1)
@njit(cache=True, parallel=True)
def _filter_neighbour_rows(periodic, x, rows, cand, cand_counts, period, H2, nbr, counts):
    """Neighbour lists of the rows ``rows`` only (a peer's interior rows, then its boundary rows)."""
    literally(periodic)
    for k in prange(rows.shape[0]):
        filter_row(periodic, rows[k], x, cand, cand_counts, period, H2, nbr, counts)


@literal_dispatch(1)
@njit(cache=True, parallel=True)
def _max_displacement2(periodic, x, x_ref, n, period, chunks):
    """The largest |x_i - x_ref_i|^2 over rows 0..n-1 (minimum image on periodic axes), as float64;
    ``chunks`` (k,) float64 scratch, one maximum per chunk of rows."""
    literally(periodic)
    k = chunks.shape[0]
    for c in prange(k):
        lo = c * n // k
        hi = (c + 1) * n // k
        most = 0.0
        for i in range(lo, hi):
            dx, dy, dz = wrapped(periodic, x[i, 0] - x_ref[i, 0], x[i, 1] - x_ref[i, 1], x[i, 2] - x_ref[i, 2],
                                 period)
            d2 = np.float64(dx) * dx + np.float64(dy) * dy + np.float64(dz) * dz
            if d2 > most:
                most = d2
            elif d2 != d2:  # a NaN position: build anew (the health check then names the cause)
                most = np.inf
        chunks[c] = most
    return chunks.max() if k else 0.0


class Grid:
    """Global uniform grid plus the per-step sort and neighbour list of one process.

    origin (3,) m and cell (3,) m define the cells, H / reach wide (``reach``: grid.REACHES, cells per
    support radius along an axis); ncell (3,) their number per axis; period (3,) is
    the period length along periodic axes and 0 elsewhere. After ``bin``, ``cell_begin`` and
    ``cell_end`` (ncells,) int64 hold the rows of every cell: owned rows (the first n_owned) and
    ghost rows (after them) are each sorted by (cell, id); ``nbr`` (n, capacity + 1) int32 (a spare column) and ``counts`` (n,)
    int32 the neighbour list (self excluded), grown automatically when a particle has more
    neighbours than the capacity.
    """

    def __init__(self, lo, hi, H, periodic, dtype, *, reach, capacity=64, skin=0.0):
        if reach not in REACHES:
            raise ValueError(f"grid reach must be one of {REACHES} cells per support radius, got {reach!r}")
        support = H
        H = support * (1.0 + skin)  # the lists' radius: the cells are sized for it
        lo = np.asarray(lo, dtype=np.float64)
        hi = np.asarray(hi, dtype=np.float64)
        ncell = np.ones(3, dtype=np.int64)
        cell = np.empty(3)
        period = np.zeros(3)
        for d in range(3):
            L = hi[d] - lo[d]
            if periodic[d]:
                if math.floor(L / H) < 3:
                    raise ValueError(f"periodic axis {'xyz'[d]} is {L:g} m long: it must hold at least 3 "
                                     f"support radii ({3 * H:g} m"
                                     f"{f', with run.neighbour_skin = {skin:g}' if skin else ''})")
                ncell[d] = reach * int(math.floor(L / H))
                cell[d] = L / ncell[d]
                period[d] = L
            else:
                # cells of exactly H / reach; one more cell so that hi itself is covered
                ncell[d] = max(int(math.floor(reach * L / H)) + 1, 1)
                cell[d] = H / reach
        self.dtype = np.dtype(dtype)
        self.origin = lo.astype(self.dtype)
        self.cell = cell.astype(self.dtype)
        self.inv_cell = (1.0 / cell).astype(self.dtype)
        self.ncell = ncell.astype(np.int64)
        self.period = period.astype(self.dtype)
        self.periodic = bool(np.any(period > 0))
        self.H2 = self.dtype.type(support * support)  # a neighbour is closer than H
        self.H2_list = self.dtype.type(H * H)          # a candidate closer than H (1 + skin)
        self.skin = float(skin)                        # run.neighbour_skin (0: a list a step)
        self.reuse_limit2 = (REUSE_SHARE * skin * support) ** 2  # m^2: build anew at this displacement
        self.reach = int(reach)
        f = self.dtype.type
        r = [0 if self.ncell[d] == 1 and period[d] == 0 else self.reach for d in range(3)]
        self.cells = Cells(*(f(v) for v in self.origin), *(f(v) for v in self.cell), *(f(v) for v in self.inv_cell),
                           *(int(n) for n in self.ncell), *(bool(p > 0) for p in self.period), self.H2,
                           *r, math.prod(2 * a + 1 for a in r))
        self.ncells = int(np.prod(self.ncell))
        self.bin_start = np.zeros(2 * self.ncells + 1, dtype=np.int64)
        self.cell_begin = np.zeros(self.ncells, dtype=np.int64)
        self.cell_end = np.zeros(self.ncells, dtype=np.int64)
        self.contiguous = True
        self.capacity = capacity
        self.nbr = np.zeros((0, capacity + 1), dtype=np.int32)  # + the builder's spare column
        self.counts = np.zeros(0, dtype=np.int32)
        self._keys = np.zeros(0, dtype=np.int64)
        self._perm = np.zeros(0, dtype=np.int64)
        self._scratch = {}
        # with a skin: the candidate lists (n, capacity + 1) int32 and their lengths (n,) int32, the
        # positions array they were built for (its identity: a replaced state is listed anew), the
        # builds and reuses so far, and whether the next build sorts and lists by the state's saved
        # reference positions (a resumed run)
        self.cand = np.zeros((0, capacity + 1), dtype=np.int32)
        self.cand_counts = np.zeros(0, dtype=np.int32)
        self._listed_x = None
        self._listed_rows = (0, 0)
        self.reusing = False    # this step filters the candidates it holds (Simulation._reuse_lists)
        self.restoring = False  # ... after building them again from the reference positions
        self.builds = 0
        self.reuses = 0
        self.from_reference = False
        self._chunks = np.zeros(64, dtype=np.float64)

    def _ensure(self, n):
        if self._keys.shape[0] != n:
            self._keys = np.empty(n, dtype=np.int64)
            self._perm = np.empty(n, dtype=np.int64)

    def sort(self, state, by=None):
        """Reorder the rows of ``state`` by (cell, id): owned rows first, then ghost rows, each
        sorted. The carried fields (sphcore.state.CARRIED) and state.extra follow their rows; the derived
        ones are left as they are (the step recomputes them after the sort). ``by``: the (n, 3)
        positions that give the cells (default state.x; a resumed skin run's reference positions)."""
        n = state.n
        self._ensure(n)
        compute_cell_keys(state.x if by is None else by, state.n_owned, self.origin, self.inv_cell, self.ncell,
                          self._keys)
        counting_sort(self._keys, state.id, self.bin_start, self._perm)
        mixed = _cell_ranges(self.bin_start, self.ncells, self.cell_begin, self.cell_end)
        if mixed:
            raise RuntimeError(f"{mixed} grid cells hold both owned and ghost particles: a migration was missed")
        self.contiguous = state.n_owned == n
        self.last_permutation = self._perm[:n]  # row k of the sorted state came from row perm[k]
        for name in CARRIED:
            setattr(state, name, self._gather(name, getattr(state, name)))
        for name, arr in state.extra.items():
            state.extra[name] = self._gather("extra:" + name, arr)

    def sort_ghosts(self, state, by=None):
        """After ``sort`` of the owned rows alone and the ghost rows' append: the ghost rows in (cell,
        id) order after the owned rows, which stay where they are (the order, bins and cell ranges
        one ``sort`` of every row gives, without sorting the owned rows again). ``by`` as in sort."""
        n, n_owned = state.n, state.n_owned
        if self.bin_start[self.ncells] != n_owned or self.bin_start[2 * self.ncells] != n_owned:
            raise RuntimeError("sort_ghosts: the owned rows were not sorted alone first")
        self._ensure(n)
        compute_cell_keys(state.x if by is None else by, n_owned, self.origin, self.inv_cell, self.ncell,
                          self._keys)
        _scatter_ghosts(self._keys, n_owned, self.ncells, self.bin_start, self._perm)
        _sort_bins_by_id(n_owned, self._keys, self.bin_start, self._perm, state.id)
        mixed = _ghost_cell_ranges(self._keys, n_owned, self.ncells, self.bin_start, self._perm, self.cell_begin,
                                   self.cell_end)
        if mixed:
            raise RuntimeError(f"{mixed} grid cells hold both owned and ghost particles: a migration was missed")
        self.contiguous = n_owned == n
        self.last_permutation = self._perm[:n]
        ghosts = self._perm[n_owned:n]
        for name in CARRIED:  # only the ghost rows move
            a = getattr(state, name)
            a[n_owned:] = a[ghosts]
        for a in state.extra.values():
            a[n_owned:] = a[ghosts]

    def _gather(self, key, src):
        dst = self._scratch.get(key)
        if dst is None or dst.shape != src.shape or dst.dtype != src.dtype:
            dst = np.empty_like(src)
        if src.ndim == 2:
            gather_rows_2d(src, self._perm, dst)
        else:
            gather_rows_1d(src, self._perm, dst)
        self._scratch[key] = src  # the old array becomes next step's scratch buffer
        return dst

    def build_neighbours(self, x, n_query, rows=None):
        """Neighbour list of rows 0..n_query-1 against all rows of x (which must be sorted); with
        ``rows`` (int64, a subset of them), of those rows only: the lists of the others are kept, also
        when the capacity grows (a peer builds its interior rows' lists, then its boundary rows')."""
        def build(nbr, counts):
            args = (self.contiguous, self.cell_begin, self.cell_end, self.origin, self.cell, self.inv_cell,
                    self.ncell, self.reach, self.period, self.H2, nbr, counts)
            if rows is None:
                _build_neighbours(int(self.periodic), x, n_query, *args)
            else:
                _build_neighbour_rows(int(self.periodic), x, rows, *args)
        return self._fill("nbr", "counts", n_query, rows, build)

    def _fill(self, lists, lengths, n_query, rows, build):
        """Run ``build(lists, lengths)`` into the arrays named ``lists`` (n, capacity + 1) and ``lengths``
        (n,) of this grid, growing their capacity and building again until every list fits; returns the
        longest list. The lists of rows outside ``rows`` (None: rows 0..n_query-1) are kept, also when
        the capacity grows."""
        capacity = getattr(self, lists).shape[1] - 1
        if getattr(self, lists).shape[0] < n_query:
            setattr(self, lists, np.empty((n_query, capacity + 1), dtype=np.int32))
            setattr(self, lengths, np.empty(n_query, dtype=np.int32))
        while True:
            build(getattr(self, lists), getattr(self, lengths))
            counted = getattr(self, lengths)
            if rows is None:
                most = int(counted[:n_query].max()) if n_query else 0
            else:
                most = int(counted[rows].max()) if rows.shape[0] else 0
            if most <= capacity:
                if lists == "nbr":
                    self.capacity = capacity
                return most
            old = getattr(self, lists)
            capacity = int(most * 1.25) + 8
            setattr(self, lists, np.empty((max(n_query, old.shape[0]), capacity + 1), dtype=np.int32))
            getattr(self, lists)[:old.shape[0], :old.shape[1] - 1] = old[:, :-1]  # the lists already built stay

    # -- a skin's Verlet lists ----------------------------------------------------------------
    def listed(self, state) -> bool:
        """Whether the candidate lists were built for this state's rows (the same positions array and
        row counts: a state replaced by a resume, an inlet, an outlet or a rebalance is listed anew)."""
        return self._listed_x is state.x and self._listed_rows == (state.n, state.n_owned)

    def displacement2(self, state) -> float:
        """m^2: the largest squared distance of an owned row from its reference position."""
        return _max_displacement2(int(self.periodic), state.x, state.extra["x_ref"], state.n_owned, self.period,
                                  self._chunks)

    def build_candidates(self, positions, n_query, rows=None):
        """The candidate lists (every row within H (1 + skin)) of rows 0..n_query-1, or of ``rows``,
        at ``positions`` (the reference positions, by which the rows are sorted)."""
        def build(cand, cand_counts):
            args = (self.contiguous, self.cell_begin, self.cell_end, self.origin, self.cell, self.inv_cell,
                    self.ncell, self.reach, self.period, self.H2_list, cand, cand_counts)
            if rows is None:
                _build_neighbours(int(self.periodic), positions, n_query, *args)
            else:
                _build_neighbour_rows(int(self.periodic), positions, rows, *args)
        self._fill("cand", "cand_counts", n_query, rows, build)

    def filter_neighbours(self, x, n_query, rows=None):
        """The neighbour lists of rows 0..n_query-1, or of ``rows``, from their candidates
        (_filter_neighbours); returns the longest."""
        def build(nbr, counts):
            if rows is None:
                _filter_neighbours(int(self.periodic), x, n_query, self.cand, self.cand_counts, self.period,
                                   self.H2, nbr, counts)
            else:
                _filter_neighbour_rows(int(self.periodic), x, rows, self.cand, self.cand_counts, self.period,
                                       self.H2, nbr, counts)
        return self._fill("nbr", "counts", n_query, rows, build)

    def lists_done(self, state):
        """The step's lists are complete: remember the state they belong to, count a build (new
        reference positions) or a reuse (the last build's lists, filtered, also when they were built
        again from its reference positions)."""
        self._listed_x = state.x
        self._listed_rows = (state.n, state.n_owned)
        if self.reusing:
            self.reuses += 1
        else:
            self.builds += 1
        self.restoring = False

    def cells_of(self, x):
        """(n, 3) int64 cell coordinates of positions x (n, 3)."""
        out = np.empty((len(x), 3), dtype=np.int64)
        compute_cell_coords(x, self.origin, self.inv_cell, self.ncell, out)
        return out

    def bin(self, state):
        """Sort the state by cell and rebuild the neighbour list of the owned particles."""
        self.sort(state)
        return self.build_neighbours(state.x, state.n_owned)


def brute_force_neighbours(x, H, period=(0.0, 0.0, 0.0)):
    """Test oracle: for every row i, the sorted array of rows j != i with |x_i - x_j| < H (O(n^2))."""
    x = np.asarray(x, dtype=np.float64)
    period = np.asarray(period, dtype=np.float64)
    out = []
    for i in range(x.shape[0]):
        d = x[i] - x
        for ax in range(3):
            if period[ax] > 0:
                d[:, ax] -= period[ax] * np.floor(d[:, ax] / period[ax] + 0.5)
        r2 = np.einsum("ij,ij->i", d, d)
        js = np.nonzero(r2 < H * H)[0]
        out.append(js[js != i])
    return out
