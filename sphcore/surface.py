"""The fluid surface: a colour field sampled on a grid, and its 0.5 iso-surface (marching cubes).

    c(x) = sum_j V_j W(|x - x_j|, H),   V_j = m_j / rho_j

is about 1 inside the fluid and falls to 0 across the free surface over one support radius; its
0.5 level set is the surface (the colour-field surface of Müller et al. 2003, seeds 001 and 002).
The field is sampled with a numba kernel that gathers, for every grid node, the particles of the
27 cells around it (its own small counting sort, so it works on any set of rows: a peer's owned
particles and ghosts). Nodes lie on a lattice aligned with the global grid's cells, so the pieces
that peers extract over their own blocks meet on the cut planes. PyVista's ``contour`` (VTK's
flying edges) extracts the triangles.

Arrays: x (n, 3) m, vol (n,) m^3; the field (nx, ny, nz) on nodes origin + (i, j, k) * step.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from sphcore.physics.kernels import kernel_constants, w


@njit(cache=True)
def _cell_sort(x, origin, inv_cell, ncell):
    """Rows sorted by cell: (start (ncells + 1,), order (n,))."""
    nx, ny, nz = ncell[0], ncell[1], ncell[2]
    n = x.shape[0]
    key = np.empty(n, dtype=np.int64)
    start = np.zeros(nx * ny * nz + 1, dtype=np.int64)
    for i in range(n):
        ix = min(max(int(math.floor((x[i, 0] - origin[0]) * inv_cell)), 0), nx - 1)
        iy = min(max(int(math.floor((x[i, 1] - origin[1]) * inv_cell)), 0), ny - 1)
        iz = min(max(int(math.floor((x[i, 2] - origin[2]) * inv_cell)), 0), nz - 1)
        key[i] = (iz * ny + iy) * nx + ix
        start[key[i] + 1] += 1
    for c in range(nx * ny * nz):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    order = np.empty(n, dtype=np.int64)
    for i in range(n):
        order[fill[key[i]]] = i
        fill[key[i]] += 1
    return start, order


@njit(cache=True, parallel=True)
def _colour_field(node_origin, step, shape, x, vol, start, order, origin, inv_cell, ncell, kernel, H, s_w, out):
    nx, ny, nz = ncell[0], ncell[1], ncell[2]
    H2 = H * H
    for k in prange(shape[2]):
        for j in range(shape[1]):
            for i in range(shape[0]):
                px = node_origin[0] + i * step
                py = node_origin[1] + j * step
                pz = node_origin[2] + k * step
                cx = int(math.floor((px - origin[0]) * inv_cell))
                cy = int(math.floor((py - origin[1]) * inv_cell))
                cz = int(math.floor((pz - origin[2]) * inv_cell))
                total = 0.0
                for zz in range(max(cz - 1, 0), min(cz + 2, nz)):
                    for yy in range(max(cy - 1, 0), min(cy + 2, ny)):
                        for xx in range(max(cx - 1, 0), min(cx + 2, nx)):
                            c = (zz * ny + yy) * nx + xx
                            for q in range(start[c], start[c + 1]):
                                r = order[q]
                                dx = px - x[r, 0]
                                dy = py - x[r, 1]
                                dz = pz - x[r, 2]
                                d2 = dx * dx + dy * dy + dz * dz
                                if d2 < H2:
                                    total += vol[r] * w(kernel, math.sqrt(d2), H, s_w)
                out[i, j, k] = total


def colour_field(x, vol, lo, hi, step: float, kernel: int, H: float, dim: int = 3):
    """Sample c on the nodes lo + (i, j, k) * step covering [lo, hi]; returns (field, origin)."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    shape = np.maximum(np.floor((hi - lo) / step + 1e-9).astype(np.int64) + 1, 1)
    if dim == 2:
        shape[2] = 1
    s_w = kernel_constants(kernel, dim, H)[0]
    pad_lo, pad_hi = lo - H, hi + H
    ncell = np.maximum(np.ceil((pad_hi - pad_lo) / H).astype(np.int64), 1)
    x = np.ascontiguousarray(x, dtype=np.float64)
    start, order = _cell_sort(x, pad_lo, 1.0 / H, ncell)
    out = np.zeros(tuple(shape), dtype=np.float64)
    _colour_field(lo, step, shape, x, np.ascontiguousarray(vol, dtype=np.float64), start, order, pad_lo, 1.0 / H,
                  ncell, int(kernel), H, s_w, out)
    return out, lo


def iso_surface(field: np.ndarray, origin, step: float, level: float = 0.5):
    """Triangles of the level set of a node field (PyVista PolyData, possibly empty)."""
    import pyvista as pv
    grid = pv.ImageData(dimensions=field.shape, spacing=(step, step, step), origin=tuple(origin))
    grid.point_data["c"] = field.ravel(order="F")
    return grid.contour([level], scalars="c")
