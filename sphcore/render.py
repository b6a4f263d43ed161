"""Splat rendering and sort-last depth compositing (seed 000, section 3.4: framelets composited by depth).

Each particle is drawn as a shaded sphere impostor: its centre is projected with a pinhole camera,
and every pixel inside its screen disk gets the depth of the sphere's front surface there and a
Lambert-shaded colour. A pixel keeps the nearest sample; equal depths go to the lower particle id.
That order is total (ids are unique), so the image does not depend on the order in which
particles, threads or peers draw — which is what makes compositing exact:

    composite(framelets of the peers) == render(all particles)       pixel for pixel

A *framelet* is the rectangle of the screen a peer's particles cover (x0, y0, w, h) with its RGB
(uint8), depth (float32, distance along the view axis, +inf = empty) and id (int64, -1 = empty)
planes. Rendering is parallel over 16 x 16 pixel tiles (gather: each tile walks the particles that
touch it, so every pixel is written by one thread only).

Arrays: x (n, 3) positions in m; values (n,) the quantity coloured; ids (n,) int64.
Images: rgb (H, W, 3) uint8, depth (H, W) float32, id (H, W) int64.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

TILE = 16
BACKGROUND = np.array([24, 26, 32], dtype=np.uint8)
OUTLINE = np.array([200, 200, 200], dtype=np.uint8)

# viridis at t = 0, 1/8, ..., 1 (interpolated linearly to 256 entries)
_VIRIDIS = np.array([[68, 1, 84], [71, 44, 122], [59, 81, 139], [44, 113, 142], [33, 144, 141],
                     [39, 173, 129], [92, 200, 99], [170, 220, 50], [253, 231, 37]], dtype=np.float64)
# categorical colours for peer ranks (Tableau 10)
RANK_COLOURS = np.array([[31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189],
                         [140, 86, 75], [227, 119, 194], [127, 127, 127], [188, 189, 34], [23, 190, 207]],
                        dtype=np.uint8)


def colormap_lut(n: int = 256) -> np.ndarray:
    t = np.linspace(0.0, 1.0, n)
    knots = np.linspace(0.0, 1.0, len(_VIRIDIS))
    return np.stack([np.interp(t, knots, _VIRIDIS[:, c]) for c in range(3)], axis=1).round().astype(np.uint8)


LUT = colormap_lut()


def colours(values: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """(n, 3) uint8 viridis colours of values over [lo, hi] (clamped)."""
    scale = (len(LUT) - 1) / (hi - lo) if hi > lo else 0.0
    index = np.clip(np.rint((np.asarray(values, dtype=np.float64) - lo) * scale), 0, len(LUT) - 1).astype(np.int64)
    return LUT[index]


@dataclass(frozen=True)
class Camera:
    """Pinhole camera looking from ``eye`` at ``target``; ``fov`` is the vertical field of view (deg)."""
    eye: tuple
    target: tuple
    up: tuple = (0.0, 1.0, 0.0)
    fov: float = 40.0
    width: int = 640
    height: int = 480
    name: str = "default"

    def basis(self) -> np.ndarray:
        """(4, 3) float64 rows: eye, right, up, forward (orthonormal)."""
        eye = np.asarray(self.eye, dtype=np.float64)
        f = np.asarray(self.target, dtype=np.float64) - eye
        f /= np.linalg.norm(f)
        r = np.cross(f, np.asarray(self.up, dtype=np.float64))
        if np.linalg.norm(r) < 1e-9:  # looking along up: pick any perpendicular
            r = np.cross(f, [1.0, 0.0, 0.0] if abs(f[0]) < 0.9 else [0.0, 0.0, 1.0])
        r /= np.linalg.norm(r)
        u = np.cross(r, f)
        return np.stack([eye, r, u, f])

    @property
    def focal(self) -> float:
        """Pixels per unit of (view x / view depth)."""
        return 0.5 * self.height / math.tan(math.radians(self.fov) / 2.0)


def framing_camera(lo, hi, width: int = 640, height: int = 480, fov: float = 40.0, dim: int = 3,
                   name: str = "default") -> Camera:
    """A camera that frames the box [lo, hi]: from the front-right-above in 3D, straight on in 2D."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    centre = 0.5 * (lo + hi)
    radius = 0.5 * float(np.linalg.norm((hi - lo)[:dim]))
    direction = np.array([0.0, 0.0, 1.0]) if dim == 2 else np.array([0.55, 0.45, 1.0])
    direction /= np.linalg.norm(direction)
    fov_limit = min(fov, 2.0 * math.degrees(math.atan(math.tan(math.radians(fov) / 2.0) * width / height)))
    distance = 1.05 * radius / math.sin(math.radians(fov_limit) / 2.0)
    return Camera(tuple(centre + distance * direction), tuple(centre), (0.0, 1.0, 0.0), fov, width, height, name)


@njit(cache=True, parallel=True)
def _project(x, basis, focal, width, height, radius, sx, sy, depth, rpx):
    """Screen position (pixels), view depth and screen radius of every particle; rpx = 0 if culled."""
    near = 1e-3
    for i in prange(x.shape[0]):
        px = x[i, 0] - basis[0, 0]
        py = x[i, 1] - basis[0, 1]
        pz = x[i, 2] - basis[0, 2]
        xv = px * basis[1, 0] + py * basis[1, 1] + pz * basis[1, 2]
        yv = px * basis[2, 0] + py * basis[2, 1] + pz * basis[2, 2]
        zv = px * basis[3, 0] + py * basis[3, 1] + pz * basis[3, 2]
        depth[i] = zv
        if zv <= near:
            rpx[i] = 0.0
            continue
        s = focal / zv
        sx[i] = 0.5 * width + xv * s
        sy[i] = 0.5 * height - yv * s
        r = radius * s
        if sx[i] + r < 0.0 or sx[i] - r > width or sy[i] + r < 0.0 or sy[i] - r > height:
            r = 0.0
        rpx[i] = r


@njit(inline="always")
def _tile_range(x, y, r, tiles_x, tiles_y):
    """First and last tile column and row touched by a disk of radius r at (x, y)."""
    return (max(int(math.floor((x - r) / TILE)), 0), min(int(math.floor((x + r) / TILE)), tiles_x - 1),
            max(int(math.floor((y - r) / TILE)), 0), min(int(math.floor((y + r) / TILE)), tiles_y - 1))


@njit(cache=True)
def _bin_tiles(sx, sy, rpx, tiles_x, tiles_y):
    """Particles touching each tile: (start (tiles+1,), list) — a counting sort of (tile, particle)."""
    n_tiles = tiles_x * tiles_y
    count = np.zeros(n_tiles + 1, dtype=np.int64)
    for i in range(sx.shape[0]):
        if rpx[i] <= 0.0:
            continue
        tx0, tx1, ty0, ty1 = _tile_range(sx[i], sy[i], rpx[i], tiles_x, tiles_y)
        for ty in range(ty0, ty1 + 1):
            for tx in range(tx0, tx1 + 1):
                count[ty * tiles_x + tx + 1] += 1
    for t in range(n_tiles):
        count[t + 1] += count[t]
    items = np.empty(count[n_tiles], dtype=np.int64)
    fill = count[:n_tiles].copy()
    for i in range(sx.shape[0]):
        if rpx[i] <= 0.0:
            continue
        tx0, tx1, ty0, ty1 = _tile_range(sx[i], sy[i], rpx[i], tiles_x, tiles_y)
        for ty in range(ty0, ty1 + 1):
            for tx in range(tx0, tx1 + 1):
                t = ty * tiles_x + tx
                items[fill[t]] = i
                fill[t] += 1
    return count, items


@njit(cache=True, parallel=True)
def _splat(sx, sy, depth, rpx, radius, base, ids, start, items, tiles_x, rgb, zbuf, idbuf):
    """Per tile (one thread), per particle touching it, per pixel of its disk in the tile: keep the
    sample if (depth, id) is smaller than what the pixel holds; shade it (ambient + Lambert)."""
    height, width = zbuf.shape
    lx, ly, lz = -0.35, 0.45, -0.82  # light towards the viewer, from the upper left (view space)
    n_tiles = start.shape[0] - 1
    for t in prange(n_tiles):
        x0 = (t % tiles_x) * TILE
        y0 = (t // tiles_x) * TILE
        x1 = min(x0 + TILE, width)
        y1 = min(y0 + TILE, height)
        for k in range(start[t], start[t + 1]):
            i = items[k]
            r = rpx[i]
            r2 = r * r
            px0 = max(int(math.floor(sx[i] - r)), x0)
            px1 = min(int(math.ceil(sx[i] + r)), x1)
            py0 = max(int(math.floor(sy[i] - r)), y0)
            py1 = min(int(math.ceil(sy[i] + r)), y1)
            for py in range(py0, py1):
                dy = py + 0.5 - sy[i]
                for px in range(px0, px1):
                    dx = px + 0.5 - sx[i]
                    d2 = dx * dx + dy * dy
                    if d2 >= r2:
                        continue
                    nz = math.sqrt(1.0 - d2 / r2)
                    z = np.float32(depth[i] - radius * nz)
                    if z < zbuf[py, px] or (z == zbuf[py, px] and ids[i] < idbuf[py, px]):
                        zbuf[py, px] = z
                        idbuf[py, px] = ids[i]
                        lambert = max(0.0, (dx / r) * lx - (dy / r) * ly - nz * lz)
                        shade = 0.3 + 0.7 * lambert
                        for c in range(3):
                            rgb[py, px, c] = np.uint8(min(255.0, base[i, c] * shade))


def render(camera: Camera, x: np.ndarray, base_colours: np.ndarray, ids: np.ndarray, radius: float):
    """(rgb, depth, id) images of particles x with colours base_colours (n, 3) uint8."""
    w, h = camera.width, camera.height
    n = len(x)
    sx, sy, depth, rpx = (np.zeros(n, dtype=np.float64) for _ in range(4))
    if n:
        _project(np.ascontiguousarray(x, dtype=np.float64), camera.basis(), camera.focal, w, h, radius,
                 sx, sy, depth, rpx)
    tiles_x, tiles_y = -(-w // TILE), -(-h // TILE)
    start, items = _bin_tiles(sx, sy, rpx, tiles_x, tiles_y)
    rgb = np.empty((h, w, 3), dtype=np.uint8)
    rgb[:] = BACKGROUND
    zbuf = np.full((h, w), np.inf, dtype=np.float32)
    idbuf = np.full((h, w), -1, dtype=np.int64)
    _splat(sx, sy, depth, rpx, radius, np.ascontiguousarray(base_colours, dtype=np.float64),
           np.ascontiguousarray(ids, dtype=np.int64), start, items, tiles_x, rgb, zbuf, idbuf)
    return rgb, zbuf, idbuf


@dataclass
class Framelet:
    """The part of the screen a peer covers: rectangle (x0, y0, w, h) and its rgb, depth, id planes."""
    rank: int
    x0: int
    y0: int
    rgb: np.ndarray
    depth: np.ndarray
    id: np.ndarray

    @property
    def w(self) -> int:
        return self.depth.shape[1]

    @property
    def h(self) -> int:
        return self.depth.shape[0]


def framelet(rank: int, rgb, depth, idbuf) -> Framelet:
    """Crop full-screen planes to the rectangle of covered pixels (an empty framelet if none)."""
    covered = idbuf >= 0
    rows, cols = np.nonzero(covered.any(1))[0], np.nonzero(covered.any(0))[0]
    if not len(rows):
        return Framelet(rank, 0, 0, np.zeros((0, 0, 3), np.uint8), np.zeros((0, 0), np.float32),
                        np.zeros((0, 0), np.int64))
    y0, y1, x0, x1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    return Framelet(rank, int(x0), int(y0), np.ascontiguousarray(rgb[y0:y1, x0:x1]),
                    np.ascontiguousarray(depth[y0:y1, x0:x1]), np.ascontiguousarray(idbuf[y0:y1, x0:x1]))


@njit(cache=True, parallel=True)
def _composite_into(x0, y0, rgb, depth, idbuf, out_rgb, out_depth, out_id):
    h, w = depth.shape
    for r in prange(h):
        for c in range(w):
            d = depth[r, c]
            i = idbuf[r, c]
            if i < 0:
                continue
            yy, xx = y0 + r, x0 + c
            if d < out_depth[yy, xx] or (d == out_depth[yy, xx] and i < out_id[yy, xx]):
                out_depth[yy, xx] = d
                out_id[yy, xx] = i
                for k in range(3):
                    out_rgb[yy, xx, k] = rgb[r, c, k]


def composite(framelets, width: int, height: int):
    """Sort-last compositing: per pixel the nearest sample of any framelet (ties: lower id)."""
    rgb = np.empty((height, width, 3), dtype=np.uint8)
    rgb[:] = BACKGROUND
    depth = np.full((height, width), np.inf, dtype=np.float32)
    idbuf = np.full((height, width), -1, dtype=np.int64)
    for f in framelets:
        if f.w and f.h:
            if f.x0 < 0 or f.y0 < 0 or f.x0 + f.w > width or f.y0 + f.h > height:
                raise ValueError(f"framelet of peer {f.rank} ({f.x0}, {f.y0}, {f.w}, {f.h}) is off the "
                                 f"{width} x {height} screen")
            _composite_into(f.x0, f.y0, f.rgb, f.depth, f.id, rgb, depth, idbuf)
    return rgb, depth, idbuf


def draw_box(camera: Camera, lo, hi, rgb, depth, dim: int = 3):
    """Draw the edges of box [lo, hi] over an image, hidden where the fluid is nearer (in place)."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    if dim == 2:
        lo, hi = lo.copy(), hi.copy()
        lo[2] = hi[2] = 0.5 * (lo[2] + hi[2])
    corners = np.array([[hi[0] if b & 1 else lo[0], hi[1] if b & 2 else lo[1], hi[2] if b & 4 else lo[2]]
                        for b in range(8)])
    edges = [(a, a | bit) for a in range(8) for bit in (1, 2, 4) if not a & bit]
    basis = camera.basis()
    h, w = depth.shape
    for a, b in edges:
        p, q = corners[a], corners[b]
        n = 2 + int(np.linalg.norm(q - p) / max(np.linalg.norm(hi - lo), 1e-12) * 4 * max(w, h))
        pts = p + np.linspace(0.0, 1.0, n)[:, None] * (q - p)
        rel = pts - basis[0]
        zv = rel @ basis[3]
        ok = zv > 1e-3
        sx = np.floor(0.5 * w + (rel @ basis[1]) * camera.focal / np.where(ok, zv, 1.0)).astype(np.int64)
        sy = np.floor(0.5 * h - (rel @ basis[2]) * camera.focal / np.where(ok, zv, 1.0)).astype(np.int64)
        ok &= (sx >= 0) & (sx < w) & (sy >= 0) & (sy < h)
        sx, sy, zv = sx[ok], sy[ok], zv[ok]
        visible = zv <= depth[sy, sx]
        rgb[sy[visible], sx[visible]] = OUTLINE


def default_range(quantity: str, scene, world: int = 1, scene_range: bool = True) -> tuple[float, float]:
    lo, hi = scene.render.range
    if scene_range and (lo, hi) != (0.0, 0.0):
        return lo, hi
    rho0, c0 = scene.fluid.rest_density, scene.sph.sound_speed
    return {"speed": (0.0, 0.1 * c0), "density": (0.98 * rho0, 1.02 * rho0),
            "pressure": (0.0, 0.02 * rho0 * c0 * c0), "rank": (0.0, max(world - 1, 1))}[quantity]


class SceneRenderer:
    """A scene's cameras and colouring: renders one peer's particles into a framelet, and turns
    composited framelets into the final image (with the domain outline)."""

    def __init__(self, scene, box_lo, box_hi, world: int = 1):
        r = scene.render
        self.scene, self.world = scene, world
        self.box = (np.asarray(box_lo, dtype=np.float64), np.asarray(box_hi, dtype=np.float64))
        self.cameras = {"default": framing_camera(box_lo, box_hi, r.width, r.height, dim=scene.dim)}
        for c in r.cameras:
            self.cameras[c.name] = Camera(tuple(c.eye), tuple(c.target), tuple(c.up), c.fov, r.width, r.height,
                                          c.name)
        self.camera_name = r.camera
        self.radius = r.radius * scene.particles.spacing
        self.quantity = r.color_by
        self.range = default_range(r.color_by, scene, world)

    def set_quantity(self, quantity: str):
        """Colour by another quantity (the scene's render.range applies to its own color_by only)."""
        self.quantity = quantity
        self.range = default_range(quantity, self.scene, self.world, quantity == self.scene.render.color_by)

    @property
    def camera(self) -> Camera:
        return self.cameras[self.camera_name]

    def base_colours(self, rank: int, v, rho, p) -> np.ndarray:
        if self.quantity == "rank":
            return np.broadcast_to(RANK_COLOURS[rank % len(RANK_COLOURS)], (len(rho), 3))
        values = {"speed": lambda: np.sqrt(np.einsum("ij,ij->i", v, v)), "density": lambda: rho,
                  "pressure": lambda: p}[self.quantity]()
        return colours(values, *self.range)

    def framelet(self, rank: int, x, v, rho, p, ids) -> Framelet:
        rgb, depth, idbuf = render(self.camera, x, self.base_colours(rank, v, rho, p), ids, self.radius)
        return framelet(rank, rgb, depth, idbuf)

    def image(self, framelets):
        """Composite framelets and draw the domain outline: (rgb, depth, id)."""
        cam = self.camera
        rgb, depth, idbuf = composite(framelets, cam.width, cam.height)
        draw_box(cam, *self.box, rgb, depth, self.scene.dim)
        return rgb, depth, idbuf
