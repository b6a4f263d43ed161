"""ParaView output through PyVista: particles (.vtp) and the fluid surface (.vtp) every K steps, and
a .pvd collection that ParaView (or ``pyvista.PVDReader``) opens as one time series.

    OUT/vtk/particles_s00000100_p0000.vtp   points with id, velocity, density, pressure, peer
    OUT/vtk/surface_s00000100_p0000.vtp     the colour field's 0.5 iso-surface (sphcore/surface.py)
    OUT/particles.pvd, OUT/surface.pvd      one DataSet per (time step, peer): part = peer rank

Each peer writes its own pieces (the surface over its own block of cells, so the pieces meet on the
cut planes); rank 0 rewrites the .pvd files after every output step, atomically, from the names
every peer uses, so a crash leaves a .pvd that lists complete steps only up to the last one.
"""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np


def piece_name(kind: str, step: int, rank: int) -> str:
    return f"{kind}_s{step:08d}_p{rank:04d}.vtp"


class VtkWriter:
    def __init__(self, out: Path, scene, rank: int = 0, world: int = 1):
        self.folder = Path(out) / "vtk"
        self.out = Path(out)
        self.scene, self.rank, self.world = scene, rank, world
        self.every = scene.output.vtk_every
        self.surface = scene.output.surface
        self.steps = []  # (step, t) written so far (rank 0 lists them in the .pvd files)

    def due(self, sim) -> bool:
        return self.every > 0 and sim.step_index % self.every == 0

    def write(self, sim, block=None):
        """Write this peer's pieces for the current step; ``block`` = (lo, hi) world box of its cells
        (None: the whole grid)."""
        import pyvista as pv
        self.folder.mkdir(parents=True, exist_ok=True)
        s = sim.state
        n = s.n_owned
        origin = np.array(sim.scene.origin)  # world coordinates, in float64: exact, unlike float32 far away
        cloud = pv.PolyData(np.ascontiguousarray(s.x[:n], dtype=np.float64) + origin)
        cloud.point_data["id"] = s.id[:n]
        cloud.point_data["velocity"] = np.ascontiguousarray(sim.synchronised_velocity()[:n])
        cloud.point_data["density"] = s.rho[:n]
        cloud.point_data["pressure"] = s.p[:n]
        cloud.point_data["peer"] = np.full(n, self.rank, dtype=np.int32)
        _save(cloud, self.folder / piece_name("particles", sim.step_index, self.rank))
        if self.surface:
            _save(self.surface_mesh(sim, block), self.folder / piece_name("surface", sim.step_index, self.rank))
        self.steps.append((sim.step_index, sim.t))
        if self.rank == 0:
            self.write_collections()

    def surface_mesh(self, sim, block=None):
        from sphcore.surface import colour_field, iso_surface
        g = sim.grid
        lo, hi = block if block is not None else (g.origin.astype(np.float64),
                                                  g.origin.astype(np.float64) + g.ncell * g.cell.astype(np.float64))
        m = max(1, math.ceil(sim.H / (self.scene.output.surface_resolution * sim.dx)))
        step = sim.H / m
        s = sim.state
        vol = s.m / np.where(s.rho > 0, s.rho, sim.prm.rho0)
        field, origin = colour_field(s.x, vol, lo, hi, step, int(sim.kernel), sim.H, self.scene.dim)
        mesh = iso_surface(field, origin, step)
        if any(sim.scene.origin) and mesh.n_points:  # to world coordinates, in float64 (the contour's are float32)
            mesh.points = mesh.points.astype(np.float64) + np.array(sim.scene.origin)
        return mesh

    def write_collections(self):
        kinds = ["particles"] + (["surface"] if self.surface else [])
        for kind in kinds:
            lines = ['<?xml version="1.0"?>', '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">',
                     "  <Collection>"]
            for step, t in self.steps:
                for r in range(self.world):
                    lines.append(f'    <DataSet timestep="{t!r}" part="{r}" file="vtk/{piece_name(kind, step, r)}"/>')
            lines += ["  </Collection>", "</VTKFile>", ""]
            path = self.out / f"{kind}.pvd"
            tmp = path.with_name(f".{path.name}.tmp")
            tmp.write_text("\n".join(lines))
            os.replace(tmp, path)


def _save(mesh, path: Path):
    tmp = path.with_name(f".{path.stem}.tmp.vtp")
    mesh.save(tmp)
    os.replace(tmp, path)
