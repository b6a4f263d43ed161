"""Triangle-mesh obstacles: a mesh file (STL/OBJ/PLY, read by PyVista) turned once into a signed
distance grid that the numba wall code samples (``physics/walls.py``, kind MESH_OUTSIDE).

The mesh is centred on its bounding box, scaled, rotated (the obstacle's rotation matrix) and moved
to the obstacle's centre; VTK's implicit polydata distance (through PyVista) gives the signed distance on
a grid of step = half the particle spacing (thin parts of a mesh need it: the push-out follows the
interpolant's gradient) covering the mesh plus a margin of two support radii
(positive outside = the fluid side). The walls interpolate it trilinearly and take the normal from
the gradient of the interpolant. Grids are cached on disk (``$SPH_CACHE_DIR`` or
``~/.cache/sphfluid``), keyed by the mesh file's bytes and every parameter, so a scene computes its
grid once.

Packed for the walls (one float row, after the 16 standard entries of a wall row):
    [16:19] grid origin (m)   [19] 1 / step   [20:23] node counts nx, ny, nz   [23] step
    [24:]   distances, x fastest: d[(k * ny + j) * nx + i]
"""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np


def cache_dir() -> Path:
    return Path(os.environ.get("SPH_CACHE_DIR", Path.home() / ".cache" / "sphfluid"))


def placed_mesh(path: Path, center, scale: float, R):
    """The mesh as it sits in the scene (PyVista PolyData, triangles, outward normals)."""
    import pyvista as pv
    if not Path(path).is_file():
        raise FileNotFoundError(f"mesh file {str(path)!r} not found")
    mesh = pv.read(str(path))
    if not isinstance(mesh, pv.PolyData):
        mesh = mesh.extract_surface()
    mesh = mesh.triangulate().clean()
    if mesh.n_cells == 0:
        raise ValueError(f"mesh file {str(path)!r} has no triangles")
    b = np.array(mesh.bounds)
    mid = 0.5 * (b[0::2] + b[1::2])
    pts = (np.asarray(mesh.points, dtype=np.float64) - mid) * scale
    mesh.points = pts @ np.asarray(R, dtype=np.float64).T + np.asarray(center, dtype=np.float64)
    return mesh.compute_normals(auto_orient_normals=True, cell_normals=True, point_normals=True)


def signed_distance_grid(path: Path, center, scale: float, R, step: float, margin: float):
    """(origin (3,), step, values (nx, ny, nz)) of the placed mesh, from the cache if computed before."""
    path = Path(path)
    key = hashlib.sha256(path.read_bytes() if path.is_file() else b"")
    key.update(json.dumps([list(map(float, center)), float(scale), np.asarray(R, dtype=float).ravel().tolist(),
                           float(step), float(margin), 1]).encode())
    cached = cache_dir() / f"sdf_{key.hexdigest()[:24]}.npz"
    if cached.is_file():
        try:
            with np.load(cached) as z:
                return z["origin"], float(z["step"]), z["values"]
        except (OSError, ValueError, KeyError):
            pass  # a damaged cache entry is recomputed
    import pyvista as pv
    mesh = placed_mesh(path, center, scale, R)
    b = np.array(mesh.bounds)
    lo, hi = b[0::2] - margin, b[1::2] + margin
    shape = np.ceil((hi - lo) / step).astype(np.int64) + 1
    grid = pv.ImageData(dimensions=tuple(int(n) for n in shape), spacing=(step, step, step), origin=tuple(lo))
    d = np.asarray(grid.compute_implicit_distance(mesh)["implicit_distance"], dtype=np.float64)
    values = d.reshape(tuple(shape), order="F")
    # VTK signs the distance by the mesh normals: check them with a test that does not use them
    # (is the grid node of most negative distance enclosed by the surface?) and flip if needed
    deepest = np.unravel_index(np.argmin(values), values.shape)
    point = pv.PolyData((lo + step * np.array(deepest))[None, :])
    enclosed = bool(point.select_interior_points(mesh, method="cell_locator", check_surface=False)
                    ["selected_points"][0])
    if not enclosed:
        values = -values
    cached.parent.mkdir(parents=True, exist_ok=True)
    tmp = cached.with_name(f".{cached.name}.{os.getpid()}.tmp.npz")
    np.savez(tmp, origin=lo, step=step, values=values)
    os.replace(tmp, cached)
    return lo, step, values


def pack(origin, step: float, values: np.ndarray) -> np.ndarray:
    """The wall-row tail: header + distances (x fastest)."""
    nx, ny, nz = values.shape
    header = np.array([*origin, 1.0 / step, nx, ny, nz, step], dtype=np.float64)
    return np.concatenate([header, values.ravel(order="F")])
