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

Size limits (checked before anything large is allocated; MeshCheckError, which the scene's loader
reports as a SceneError naming the keys, so ``sph`` prints one line and exits 2): the grid's node
count grows with (mesh size x scale / particle spacing)^3, so a placed mesh whose grid would exceed
``MAX_GRID_NODES`` is refused, and so is a mesh smaller than one particle spacing (the particles would not see it).
``check_mesh_obstacle`` checks a scene's obstacle when the scene loads (naming its keys);
``signed_distance_grid`` checks again before computing, for any caller.

Packed for the walls (one float row, after the 16 standard entries of a wall row):
    [16:19] grid origin (m)   [19] 1 / step   [20:23] node counts nx, ny, nz   [23] step
    [24:]   distances, x fastest: d[(k * ny + j) * nx + i]
"""
from __future__ import annotations

import hashlib
import json
import logging
import math
import os
from pathlib import Path

import numpy as np

log = logging.getLogger("sph.mesh")


# The largest distance grid built, in nodes. Memory per node, measured (torus, 2-5 M nodes): ~75 B at
# the peak of the VTK call (PyVista materialises the nodes' float64 coordinates, 24 B, 48 B while it
# stacks them, + 8 B of distance) and afterwards the walls keep the grid in two tables padded to the
# longest wall row (Walls.data in the run's precision and Walls.rest in float64: 8 B per node per wall
# row each), ~110 B/node more with mesh_obstacle's 7 wall rows in f64: about GRID_BYTES_PER_NODE in
# all. VTK takes ~3 us per node on one core. 2^24 nodes is then ~2.5 GB and ~50 s, once (the grid is
# cached): configs/mesh_obstacle.toml needs 0.2 M nodes and can be refined to particles.spacing
# ~0.0019 m (~7 M particles) within the limit, the tests need less; its ring at obstacles[0].scale = 2
# would need 119 M nodes (~18 GB, ~6 min).
# $SPH_MESH_GRID_MAX_NODES sets another limit (for a machine that has the memory and the time).
MAX_GRID_NODES = 2**24
GRID_BYTES_PER_NODE = 150


def max_grid_nodes() -> int:
    try:
        return max(int(os.environ.get("SPH_MESH_GRID_MAX_NODES", MAX_GRID_NODES)), 1)
    except ValueError:
        return MAX_GRID_NODES


def grid_nodes(extent, step: float, margin: float) -> float:
    """Node count (a float: inf when it overflows) of the distance grid around a placed mesh whose
    bounding box has edge lengths ``extent``: the layout ``signed_distance_grid`` uses."""
    n = 1.0
    with np.errstate(all="ignore"):
        for e in np.asarray(extent, dtype=np.float64):
            k = math.ceil((e + 2.0 * margin) / step) + 1.0 if math.isfinite(e) else math.inf
            n *= k
    return n if math.isfinite(n) else math.inf


def _scaled_extent(points: np.ndarray, scale: float, R) -> np.ndarray:
    """Bounding-box edge lengths of ``points`` centred on their box, scaled and rotated (placed_mesh)."""
    b_lo, b_hi = points.min(axis=0), points.max(axis=0)
    with np.errstate(all="ignore"):
        pts = ((points - 0.5 * (b_lo + b_hi)) * scale) @ np.asarray(R, dtype=np.float64).T
        ext = pts.max(axis=0) - pts.min(axis=0)
    return np.where(np.isfinite(ext), ext, math.inf)


def _largest(fits, lo: float, hi: float) -> float:
    """About the largest x in (0, hi] with fits(x), fits true up to a point and true at ``lo`` (> 0):
    bisection of log x."""
    for _ in range(80):
        mid = math.sqrt(lo) * math.sqrt(hi)
        lo, hi = (mid, hi) if fits(mid) else (lo, mid)
    return lo


class MeshCheckError(ValueError):
    """A mesh obstacle this module refuses (one line); the scene's loader reports it as a SceneError
    naming the obstacle's keys (this module imports nothing of the scene's: the scene imports it)."""


def _gb(nbytes: float) -> str:
    return f"{nbytes / 1e9:.3g} GB"


def check_grid_size(extent, step: float, margin: float, what: str, advice: str, small_advice: str = ""):
    """MeshCheckError (one line) when the grid around a placed mesh of bounding-box edges ``extent``
    would exceed the node limit, or the mesh is smaller than a particle spacing (2 x step) in
    every direction. ``what`` starts the message (the key and its value), ``advice`` says what to
    change for a grid that is too large, ``small_advice`` for a mesh that is too small."""
    extent = np.asarray(extent, dtype=np.float64)
    extent = np.where(np.isnan(extent), math.inf, extent)  # inf x 0 of an infinite scale
    dx = 2.0 * step
    size = " x ".join(f"{e:.3g}" for e in extent)
    if not extent.max() >= dx:
        raise MeshCheckError(f"{what}: the placed mesh spans only {size} m, less than the particle spacing "
                         f"({dx:g} m) in every direction, so the particles would not see it (it would vanish); "
                         f"{small_advice or 'scale it up or refine particles.spacing'}")
    nodes, limit = grid_nodes(extent, step, margin), max_grid_nodes()
    if nodes > limit:
        count = (f"about {nodes:.3g} nodes (about {_gb(nodes * GRID_BYTES_PER_NODE)} of memory)"
                 if math.isfinite(nodes) else "more nodes than a float counts")
        raise MeshCheckError(f"{what}: the placed mesh spans {size} m and its signed distance grid (step {step:g} m "
                         f"= particles.spacing / 2, margin {margin:.3g} m) would have {count}, more than the limit of "
                         f"{limit:,} nodes (about {_gb(limit * GRID_BYTES_PER_NODE)}; "
                         f"$SPH_MESH_GRID_MAX_NODES sets another); {advice}")


def read_mesh(path: Path):
    """The file's triangles (PyVista PolyData), VTK's own error printing silenced (the callers say
    what went wrong once: sphcore.scene.check_mesh_file)."""
    import pyvista as pv
    import vtk
    shown = vtk.vtkObject.GetGlobalWarningDisplay()
    vtk.vtkObject.GlobalWarningDisplayOff()
    try:
        mesh = pv.read(str(path))
        if not isinstance(mesh, pv.PolyData):
            mesh = mesh.extract_surface()
        return mesh.triangulate()
    finally:
        vtk.vtkObject.SetGlobalWarningDisplay(shown)


def check_mesh_obstacle(scene, i: int, path: Path):
    """Scene-load checks of mesh obstacle ``i`` (``path``: its file, sphcore.scene.mesh_path, which the
    scene's loader has read already: sphcore.scene.check_mesh_file), each a one-line MeshCheckError
    naming the key: a mesh whose distance grid would exceed MAX_GRID_NODES at its scale and the
    particle spacing, or that is smaller than one particle spacing; a mesh with boundary edges on
    more than 1 % of its triangle sides (not closed enough to have an inside)."""
    from sphcore.motion import rotation_matrix
    ob = scene.obstacles[i]
    path = Path(path)
    file_key = f"obstacles[{i}].file = {ob.file!r}"
    mesh = read_mesh(path).clean()  # shared points: the open edges are the triangles' unshared sides
    R = rotation_matrix(ob.rotation)
    if ob.frame == "container":
        R = rotation_matrix(scene.domain.rotation) @ R  # the container's frame (boundaries.container_frame)
    dx, dom_scale = scene.particles.spacing, scene.domain.scale
    step, margin = 0.5 * dx, (2.0 * scene.sph.support + 2.0) * dx  # as sphcore/boundaries.py build_walls
    points = np.asarray(mesh.points, dtype=np.float64)
    scale = ob.scale * dom_scale
    value = f"obstacles[{i}].scale = {ob.scale!r}" + (f" (x domain.scale = {dom_scale!r})" if dom_scale != 1.0 else "")
    extent = _scaled_extent(points, scale, R)
    limit = max_grid_nodes()
    advice = small_advice = ""
    if not extent.max() >= dx:
        extent1 = _scaled_extent(points, dom_scale, R)  # at obstacles[i].scale = 1
        small_advice = (f"raise obstacles[{i}].scale to at least {ob.scale * dx / extent.max():.3g} (the mesh "
                        f"spans {extent1.max():.3g} m at scale 1) or refine particles.spacing"
                        if 0.0 < extent.max() and math.isfinite(ob.scale * dx / extent.max()) else "")
    elif grid_nodes(extent, step, margin) > limit:  # say what would fit
        ways = []
        if grid_nodes(np.zeros(3), step, margin) <= limit:
            most = _largest(lambda x: grid_nodes(_scaled_extent(points, x * dom_scale, R), step, margin) <= limit,
                            min(ob.scale, 1e-300), min(ob.scale, 1e300))
            if _scaled_extent(points, most * dom_scale, R).max() >= dx:
                ways.append(f"lower obstacles[{i}].scale to at most about {most:.3g}")
        k = 2.0 * scene.sph.support + 2.0
        if grid_nodes(extent, 0.5e6 * dx, 1e6 * k * dx) <= limit:
            coarse = _largest(lambda h: grid_nodes(extent, 0.5 * h, k * h) > limit, dx, 1e6 * dx)
            ways.append(f"raise particles.spacing to at least about {coarse:.3g}")
        advice = " or ".join(ways) or f"lower obstacles[{i}].scale"
    check_grid_size(extent, step, margin, value + f" (mesh {ob.file!r})", advice, small_advice)
    if 100 * mesh.n_open_edges > 3 * mesh.n_cells:
        raise MeshCheckError(f"{file_key}: the mesh is open ({mesh.n_open_edges} boundary edges among its "
                         f"{mesh.n_cells} triangles): a mesh obstacle must be closed enough to have an inside")


def cache_dir() -> Path:
    return Path(os.environ.get("SPH_CACHE_DIR", Path.home() / ".cache" / "sphfluid"))


def placed_mesh(path: Path, center, scale: float, R):
    """The mesh as it sits in the scene (PyVista PolyData, triangles, outward normals)."""
    import pyvista as pv
    if Path(path).is_dir():
        raise IsADirectoryError(f"mesh file {str(path)!r} is a folder, not a mesh file")
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
    b = np.array(mesh.bounds, dtype=np.float64)
    # before anything large: the grid's size (check_mesh_obstacle said it with the keys when the scene loaded)
    check_grid_size(b[1::2] - b[0::2], step, margin, f"mesh obstacle {path.name!r} at scale {scale:g}",
                    "lower the obstacle's scale or raise particles.spacing")
    lo, hi = b[0::2] - margin, b[1::2] + margin
    shape = np.ceil((hi - lo) / step).astype(np.int64) + 1
    nodes = int(np.prod(shape))
    if nodes > 1_000_000:  # VTK takes ~3 us a node on one core and says nothing meanwhile
        log.info(f"mesh obstacle {path.name}: its signed distance grid, {nodes:,} nodes (about {3e-6 * nodes:.0f} s, "
                 "once: it is cached)")
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
