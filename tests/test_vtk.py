"""ParaView output: the .pvd series reads back in PyVista with the right counts and fields, a 2-peer
run's pieces add up, the surface encloses the fluid, and sph render draws frames and a movie."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from launch.cli import main

ROOT = Path(__file__).resolve().parent.parent
DAM = ["configs/dam_break.toml", "--set", "particles.spacing=0.05", "--no-viewer", "--quiet", "--steps", "40",
       "--vtk", "20", "--set", "output.surface=true"]


def read_step(pvd, index):
    import pyvista as pv
    reader = pv.PVDReader(str(pvd))
    reader.set_active_time_value(reader.time_values[index])
    return reader.time_values, reader.read()


def test_single_run_series_reads_back_with_counts_and_fields(tmp_path):
    assert main(["run", str(ROOT / DAM[0]), *DAM[1:], "--out", str(tmp_path)]) == 0
    final = np.load(tmp_path / "final.npz")
    times, blocks = read_step(tmp_path / "particles.pvd", -1)
    assert len(times) == 2 and times[0] < times[1]
    cloud = blocks[0]
    assert cloud.n_points == len(final["id"])
    for name in ("id", "velocity", "density", "pressure", "peer"):
        assert name in cloud.point_data, name
    assert np.array_equal(np.sort(cloud.point_data["id"]), final["id"])
    _, surface = read_step(tmp_path / "surface.pvd", -1)
    assert surface[0].n_cells > 100


def test_two_peer_pieces_add_up(tmp_path):
    done = subprocess.run([sys.executable, "-m", "launch.cli", "run", *DAM, "--peers", "2", "--out", str(tmp_path)],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    _, blocks = read_step(tmp_path / "particles.pvd", -1)
    assert blocks.n_blocks == 2
    assert sum(b.n_points for b in blocks) == len(np.load(tmp_path / "final.npz")["id"])
    assert {int(b.point_data["peer"][0]) for b in blocks if b.n_points} == {0, 1}
    _, surfaces = read_step(tmp_path / "surface.pvd", -1)
    assert sum(s.n_cells for s in surfaces) > 100


def test_the_surface_of_a_resting_block_lies_half_a_spacing_outside_its_particles():
    from sphcore.choices import Kernel
    from sphcore.surface import colour_field, iso_surface
    dx, H = 0.02, 0.046
    g = (np.arange(10) + 0.5) * dx  # a 0.2 m cube of lattice particles
    x = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    field, origin = colour_field(x, np.full(len(x), dx**3), (-0.1, -0.1, -0.1), (0.3, 0.3, 0.3), dx / 2,
                                 Kernel.WENDLAND_C2, H)
    assert abs(field[20, 20, 20] - 1.0) < 0.03  # c = 1 inside
    b = np.array(iso_surface(field, origin, dx / 2).bounds)
    assert np.all(np.abs(b[0::2] - 0.0) < dx / 2) and np.all(np.abs(b[1::2] - 0.2) < dx / 2)


def test_sph_render_writes_frames_and_a_movie(tmp_path):
    assert main(["run", str(ROOT / DAM[0]), *DAM[1:], "--out", str(tmp_path)]) == 0
    assert main(["render", str(tmp_path), "--size", "320", "240"]) == 0
    frames = sorted((tmp_path / "frames").glob("surface_*.png"))
    assert len(frames) == 2
    import imageio.v2 as imageio
    im = imageio.imread(frames[-1])
    assert im.shape[:2] == (240, 320) and len(np.unique(im.reshape(-1, im.shape[-1]), axis=0)) > 20
    assert (tmp_path / "surface.mp4").stat().st_size > 1000


def test_render_without_a_series_says_what_to_do(tmp_path, capsys):
    assert main(["render", str(tmp_path)]) == 2
    assert "--vtk K --set output.surface=true" in capsys.readouterr().err
