"""``sph render OUT``: PNG frames (and an MP4) of a run's VTK series, drawn off-screen by PyVista.

Reads OUT/surface.pvd (or OUT/particles.pvd with ``--particles``), merges the peers' pieces of
each time step, and draws them with one fixed camera that frames the whole series, so frames line
up into a movie. Off-screen rendering goes through VTK's EGL/OSMesa path (Mesa, installed by
scripts/setup.sh); no display is needed. The MP4 is written with imageio's bundled ffmpeg.
"""
from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

log = logging.getLogger("sph.render")


def read_series(pvd: Path) -> list[tuple[float, list[Path]]]:
    """[(time, [piece files])] of a .pvd collection, in time order."""
    import xml.etree.ElementTree as ET
    root = ET.parse(pvd).getroot()
    steps = {}
    for ds in root.iter("DataSet"):
        steps.setdefault(float(ds.get("timestep")), []).append(pvd.parent / ds.get("file"))
    return sorted(steps.items())


def camera_for(lo, hi):
    """y up (the scenes' convention), from the front-right-above, framing the box [lo, hi]."""
    centre = 0.5 * (lo + hi)
    radius = 0.5 * float(np.linalg.norm(hi - lo))
    direction = np.array([0.55, 0.45, 1.0]) / np.linalg.norm([0.55, 0.45, 1.0])
    return [tuple(centre + 2.6 * radius * direction), tuple(centre), (0.0, 1.0, 0.0)]


def render_series(out: Path, frames_dir: Path, particles: bool = False, mp4: bool = True, width: int = 960,
                  height: int = 640, fps: int = 20, progress=None) -> list[Path]:
    os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
    import pyvista as pv
    kind = "particles" if particles else "surface"
    pvd = out / f"{kind}.pvd"
    if not pvd.is_file():
        hint = "--vtk K" + ("" if particles else " --set output.surface=true")
        raise FileNotFoundError(f"{pvd} not found: run with {hint} first")
    series = read_series(pvd)
    if not series:
        raise FileNotFoundError(f"{pvd} lists no time steps")
    meshes = []
    for t, files in series:
        parts = [pv.read(f) for f in files if f.is_file()]
        parts = [m for m in parts if m.n_points]
        meshes.append((t, pv.merge(parts) if parts else pv.PolyData()))
    bounds = np.array([m.bounds for _, m in meshes if m.n_points])
    if not len(bounds):
        raise ValueError(f"{pvd}: every frame is empty")
    lo, hi = bounds[:, 0::2].min(0), bounds[:, 1::2].max(0)
    frames_dir.mkdir(parents=True, exist_ok=True)
    plotter = pv.Plotter(off_screen=True, window_size=(width, height))
    written = []
    for i, (t, mesh) in enumerate(meshes):
        plotter.clear_actors()
        plotter.add_mesh(pv.Box(bounds=(lo[0], hi[0], lo[1], hi[1], lo[2], hi[2])), style="wireframe", color="grey")
        if mesh.n_points:
            if particles:
                plotter.add_mesh(mesh, scalars="velocity", render_points_as_spheres=True, point_size=4,
                                 cmap="viridis", show_scalar_bar=True, scalar_bar_args={"title": "|v| (m/s)"})
            else:
                plotter.add_mesh(mesh.compute_normals(auto_orient_normals=True), color="#6fa8dc",
                                 smooth_shading=True, specular=0.4, ambient=0.15, diffuse=0.8)
        plotter.add_text(f"t = {t:.3f} s", font_size=12)
        plotter.camera_position = camera_for(lo, hi)
        path = frames_dir / f"{kind}_{i:05d}.png"
        plotter.screenshot(str(path))
        written.append(path)
        if progress:
            progress(i + 1, len(meshes))
    plotter.close()
    if mp4:
        import imageio.v2 as imageio
        movie = out / f"{kind}.mp4"
        with imageio.get_writer(movie, fps=fps, macro_block_size=8) as w:
            for path in written:
                w.append_data(imageio.imread(path))
        written.append(movie)
    return written
