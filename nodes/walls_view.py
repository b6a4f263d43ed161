"""The walls as the viewer draws them: meshes for the 3D view, and an obstacle layer for the composite.

The peers' splat renderer (sphcore/render.py) draws particles only. Obstacles are static, so the
viewer draws them once per camera and merges them into every composite by depth, the same rule
the peers' framelets follow: a pixel shows an obstacle where the obstacle is nearer than the fluid,
and fluid in front of an obstacle hides it. The layer is made by sphere tracing the obstacles'
signed distance (spheres and boxes analytically, meshes from the same signed-distance grid the
walls use, sphcore/mesh_sdf.py), shaded with the splat renderer's light. Only obstacles are drawn
this way; the container is the outline (sphcore.render.draw_box) and, in 3D, a mesh.
"""
from __future__ import annotations

import numpy as np

OBSTACLE_COLOUR = np.array([176, 160, 136], dtype=np.float64)
CONTAINER_RGBA = [120, 120, 130, 110]
OBSTACLE_RGBA = [176, 160, 136, 255]
_LIGHT = (-0.35, 0.45, -0.82)  # view space, as in sphcore/render.py (_splat)


def _placed(scene):
    """[(shape, centre, R, obstacle)] of the scene's obstacles in world coordinates."""
    from sphcore.boundaries import container_frame, rotation_matrix
    c, R = container_frame(scene)
    s = scene.domain.scale
    out = []
    for ob in scene.obstacles:
        centre, Rob = np.array(ob.center, dtype=float), rotation_matrix(ob.rotation)
        if ob.frame == "container":
            centre, Rob = c + R @ (centre * s), R @ Rob
        out.append((ob.shape, centre, Rob, ob))
    return out


class _MeshDistance:
    """Trilinear signed distance of a placed mesh from its grid; outside the grid, the distance to
    the grid's box (a lower bound, so sphere tracing never steps through the mesh)."""

    def __init__(self, origin, step, values):
        self.origin, self.step, self.values = np.asarray(origin, float), float(step), values
        self.hi = self.origin + step * (np.array(values.shape) - 1)

    def __call__(self, p):
        outside = np.linalg.norm(np.maximum(np.maximum(self.origin - p, p - self.hi), 0.0), axis=-1)
        g = np.clip((p - self.origin) / self.step, 0.0, np.array(self.values.shape) - 1.000001)
        i = np.floor(g).astype(np.int64)
        f = g - i
        v = self.values
        d = 0.0
        for dx in (0, 1):
            for dy in (0, 1):
                for dz in (0, 1):
                    w = (f[:, 0] if dx else 1 - f[:, 0]) * (f[:, 1] if dy else 1 - f[:, 1]) * \
                        (f[:, 2] if dz else 1 - f[:, 2])
                    d = d + w * v[i[:, 0] + dx, i[:, 1] + dy, i[:, 2] + dz]
        return np.where(outside > 0, outside + np.maximum(d, 0.0), d)


def moving_obstacles(scene) -> dict:
    """{obstacle index: sphcore.motion.Motion} of the obstacles that move."""
    from sphcore.motion import Motion
    return {i: m for i, m in enumerate(Motion.of(ob) for ob in scene.obstacles) if m is not None}


def floating_obstacles(scene) -> list:
    """The indices of the floating obstacles (sphcore/motion.py FloatingBody): the peers say where they are."""
    return [i for i, ob in enumerate(scene.obstacles) if ob.density > 0.0]


def body_shifts(scene, bodies) -> dict:
    """{obstacle index: (displacement (3,), orientation (3, 3) or None)} from a frame's "bodies"
    statistic ({index: [x, y, z] or [x, y, z, R row by row]}, nodes/frames.py), off the wire: only
    floating obstacles' entries of finite numbers, and orientations that are rotations, are kept."""
    if not isinstance(bodies, dict):
        return {}
    floating, out = set(floating_obstacles(scene)), {}
    for key, value in list(bodies.items())[:64]:
        try:
            i = int(key)
            x = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            continue
        if i not in floating or x.shape not in ((3,), (12,)) or not np.all(np.isfinite(x)):
            continue
        R = x[3:].reshape(3, 3) if x.size == 12 else None
        if R is not None and not (np.allclose(R @ R.T, np.eye(3), atol=1e-6) and np.linalg.det(R) > 0.0):
            continue
        out[i] = (x[:3], R)
    return out


def _body_at_rest(p, centre, shift, R):
    """The points p of the world where a floating body (centre at t = 0, displaced by ``shift`` and
    turned by ``R`` about its centre) was at t = 0."""
    p = p - shift
    return p if R is None else centre + (p - centre) @ R  # R^T (p - c) per row


def body_transform(scene, i: int, shift, R) -> dict:
    """Transform3D arguments that carry floating obstacle i's mesh (logged where it is at t = 0) to
    where the peers say it is."""
    if R is None:
        return {"translation": shift}
    centre = _placed(scene)[i][1]
    return {"translation": centre - R @ centre + shift, "mat3x3": R}


def obstacle_distance(scene):
    """f(points (n, 3), t = 0) -> (n,) signed distance to the nearest obstacle at time t (moving
    obstacles displaced by X(t), sphcore/motion.py), or None without obstacles."""
    parts = []
    for shape, centre, R, ob in _placed(scene):
        if shape == "sphere":
            parts.append(lambda p, c=centre, r=ob.radius: np.linalg.norm(p - c, axis=-1) - r)
        elif shape == "box":
            half = 0.5 * np.asarray(ob.size, dtype=float)

            def box(p, c=centre, R=R, half=half):
                q = np.abs((p - c) @ R) - half
                return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)
            parts.append(box)
        else:
            from sphcore.mesh_sdf import signed_distance_grid
            from sphcore.scene import mesh_path
            dx = scene.particles.spacing
            H = scene.sph.support * dx
            grid = signed_distance_grid(mesh_path(scene, ob), centre, ob.scale * scene.domain.scale, R, 0.5 * dx,
                                        2.0 * H + 2.0 * dx)  # the walls' own grid (sphcore/boundaries.py)
            parts.append(_MeshDistance(*grid))
    if not parts:
        return None
    moving = moving_obstacles(scene)
    centres = [centre for _, centre, _, _ in _placed(scene)]

    def at_rest(i, p, t):
        """The points p of the world at time t where obstacle i was at t = 0 (motion.py: turned
        about its pivot, then displaced)."""
        motion = moving[i]
        p = p - motion.displacement(t)
        if not motion.rotates:
            return p
        pivot = centres[i] + motion.pivot
        return pivot + (p - pivot) @ motion.rotation(t)  # R^T (p - P) per row

    def distance(p, t=0.0, shifts=None):
        """``shifts``: {obstacle index: (displacement (3,), orientation or None)} of the floating
        bodies (from the peers, ``body_shifts``)."""
        shifts = shifts or {}
        return np.min(np.stack([f(_body_at_rest(p, centres[i], *shifts[i])) if i in shifts
                                else f(at_rest(i, p, t)) if i in moving else f(p)
                                for i, f in enumerate(parts)]), axis=0)
    return distance


def obstacle_transform(scene, i: int, motion, t: float) -> dict:
    """Transform3D arguments that carry obstacle i's mesh (logged where it is at t = 0) to time t."""
    if not motion.rotates:
        return {"translation": motion.displacement(t)}
    R = motion.rotation(t)
    pivot = _placed(scene)[i][1] + motion.pivot
    return {"translation": pivot - R @ pivot + motion.displacement(t), "mat3x3": R}


def obstacle_layer(scene, camera, box, iterations: int = 128, t: float = 0.0, sdf=None, shifts=None):
    """(rgb (H, W, 3) uint8, depth (H, W) float32, +inf where no obstacle) of the scene's obstacles at
    time ``t`` (floating bodies displaced by ``shifts``) seen by ``camera`` (sphcore.render.Camera), or
    None if the scene has none; ``sdf``: the scene's obstacle_distance, if already built."""
    sdf = sdf or obstacle_distance(scene)
    if sdf is None:
        return None
    at_t, when = sdf, t  # (t is the rays' distance below)
    sdf = lambda p: at_t(p, when, shifts)  # noqa: E731
    eye, right, up, forward = camera.basis()
    w, h, focal = camera.width, camera.height, camera.focal
    px, py = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    d = forward + ((px - 0.5 * w) / focal)[..., None] * right - ((py - 0.5 * h) / focal)[..., None] * up
    d = (d / np.linalg.norm(d, axis=-1, keepdims=True)).reshape(-1, 3)
    lo, hi = np.asarray(box[0], float), np.asarray(box[1], float)
    far = float(np.linalg.norm(np.maximum(np.abs(lo - eye), np.abs(hi - eye)))) * 1.5 + 1e-9
    t = np.zeros(len(d))
    active = np.ones(len(d), dtype=bool)
    hit = np.zeros(len(d), dtype=bool)
    scale = float(np.linalg.norm(hi - lo)) or 1.0
    for _ in range(iterations):
        idx = np.nonzero(active)[0]
        if not len(idx):
            break
        dist = sdf(eye + t[idx, None] * d[idx])
        eps = np.maximum(1e-5 * scale, 0.5 * t[idx] / focal)  # half a pixel's footprint
        done = dist < eps
        hit[idx[done]] = True
        t[idx] += np.where(done, 0.0, np.maximum(dist, 0.25 * eps))
        active[idx[done | (t[idx] > far)]] = False
    rgb = np.zeros((h * w, 3), dtype=np.uint8)
    depth = np.full(h * w, np.inf, dtype=np.float32)
    idx = np.nonzero(hit)[0]
    if len(idx):
        p = eye + t[idx, None] * d[idx]
        e = 1e-4 * scale
        n = np.stack([sdf(p + e * axis) - sdf(p - e * axis) for axis in np.eye(3)], axis=1)
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        light = _LIGHT[0] * right + _LIGHT[1] * up + _LIGHT[2] * forward
        shade = 0.3 + 0.7 * np.maximum(0.0, n @ light)
        rgb[idx] = np.clip(OBSTACLE_COLOUR[None] * shade[:, None], 0, 255).astype(np.uint8)
        depth[idx] = (t[idx] * (d[idx] @ forward)).astype(np.float32)
    return rgb.reshape(h, w, 3), depth.reshape(h, w)


def merge_layer(rgb, depth, layer):
    """Put the obstacle layer into a composite (in place): obstacle pixels nearer than the fluid."""
    if layer is None:
        return
    orgb, odepth = layer
    nearer = odepth < depth
    rgb[nearer] = orgb[nearer]
    depth[nearer] = odepth[nearer]


def wall_meshes(scene):
    """{entity: rr.Mesh3D} of the container (unless it is the plain box the outline already draws)
    and every obstacle (meshes as placed in the scene), for the 3D view; PyVista makes the primitives."""
    import pyvista as pv
    import rerun as rr

    from sphcore.boundaries import container_frame
    c, R = container_frame(scene)
    dom, s = scene.domain, scene.domain.scale
    shapes = {}
    if dom.container == "sphere":
        shapes["container"] = (pv.Sphere(radius=dom.radius * s), c, np.eye(3))
    elif dom.container == "cylinder":
        shapes["container"] = (pv.Cylinder(radius=0.5 * dom.size[0] * s, height=dom.size[1] * s,
                                           direction=(0, 1, 0), capping=False), c, R)
    elif dom.container == "box" and scene.dim == 3 and np.any(np.abs(np.asarray(dom.rotation)) > 0):
        half = 0.5 * np.asarray(dom.size, dtype=float) * s
        shapes["container"] = (pv.Box(bounds=np.ravel(np.stack([-half, half], 1))), c, R)
    for i, (shape, centre, Rob, ob) in enumerate(_placed(scene)):
        if shape == "sphere":
            shapes[f"obstacles/{i}"] = (pv.Sphere(radius=ob.radius), centre, np.eye(3))
        elif shape == "box":
            half = 0.5 * np.asarray(ob.size, dtype=float)
            shapes[f"obstacles/{i}"] = (pv.Box(bounds=np.ravel(np.stack([-half, half], 1))), centre, Rob)
        else:
            from sphcore.mesh_sdf import placed_mesh
            from sphcore.scene import mesh_path
            shapes[f"obstacles/{i}"] = (placed_mesh(mesh_path(scene, ob), centre, ob.scale * s, Rob), np.zeros(3),
                                        np.eye(3))
    out = {}
    for name, (mesh, centre, rot) in shapes.items():
        tri = mesh.triangulate()
        faces = np.asarray(tri.faces).reshape(-1, 4)[:, 1:]
        pts = np.asarray(tri.points, dtype=np.float64) @ np.asarray(rot).T + centre
        out[name] = rr.Mesh3D(vertex_positions=pts.astype(np.float32), triangle_indices=faces.astype(np.uint32),
                              albedo_factor=CONTAINER_RGBA if name == "container" else OBSTACLE_RGBA)
    return out
