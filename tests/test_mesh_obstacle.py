"""Triangle-mesh obstacles: the signed distance grid matches PyVista's exact distance, it is
cached, and no particle gets into the mesh during a dam break against it."""
import numpy as np
import pytest

from conftest import CONFIGS, scene
from sphcore.scene import SceneError


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SPH_CACHE_DIR", str(tmp_path / "cache"))


def mesh_wall(sim):
    from sphcore.choices import WallKind
    q = int(np.nonzero(sim.walls.kind == WallKind.MESH_OUTSIDE)[0][0])
    return sim.walls.kind[q:q + 1], sim.walls.data[q:q + 1]


def exact_distance(sc, points):
    import pyvista as pv

    from sphcore.boundaries import rotation_matrix
    from sphcore.mesh_sdf import placed_mesh
    from sphcore.scene import mesh_path
    ob = sc.obstacles[0]
    mesh = placed_mesh(mesh_path(sc, ob), ob.center, ob.scale, rotation_matrix(ob.rotation))
    return np.asarray(pv.PolyData(points).compute_implicit_distance(mesh)["implicit_distance"])


def test_distance_grid_matches_the_exact_distance_within_a_cell_and_is_cached(tmp_path):
    from sphcore.physics.walls import min_wall_distance
    from sphcore.solver import Simulation
    sc = scene("mesh_obstacle", "particles.spacing=0.03")
    sim = Simulation(sc, "f64")
    assert len(list((tmp_path / "cache").glob("sdf_*.npz"))) == 1
    kinds, data = mesh_wall(sim)
    rng = np.random.default_rng(0)
    points = np.array(sc.obstacles[0].center) + rng.uniform(-0.2, 0.2, (3000, 3))
    grid_d = np.empty(len(points))
    min_wall_distance(kinds, data, points, grid_d)
    exact = exact_distance(sc, points)
    near = np.abs(exact) < 0.1
    assert near.sum() > 500
    assert np.max(np.abs(grid_d[near] - exact[near])) < 0.5 * sc.particles.spacing  # within one grid cell
    assert (grid_d[exact < -0.01] < 0).all() and (grid_d[exact > 0.01] > 0).all()  # inside is negative
    # the tube's centre line is inside: ring radius 0.12 along y (the ring stands in the yz plane)
    centre_line = np.array(sc.obstacles[0].center) + np.array([[0.0, 0.12, 0.0]])
    out = np.empty(1)
    min_wall_distance(kinds, data, centre_line, out)
    assert abs(out[0] + 0.12 * 0.35) < 0.01


def test_no_particle_enters_the_mesh_during_a_dam_break():
    from sphcore.solver import Simulation
    sc = scene("mesh_obstacle", "particles.spacing=0.03")
    sim = Simulation(sc, "f32")
    assert np.all(exact_distance(sc, sim.state.x.astype(float)) > 0)  # carved out at the start
    worst = np.inf
    while sim.t < 0.45:
        sim.step()
        if sim.step_index % 20 == 0:
            worst = min(worst, exact_distance(sc, sim.state.x[: sim.state.n_owned].astype(float)).min())
    x = sim.state.x[: sim.state.n_owned].astype(float)
    assert sim.leaks == 0
    assert worst > -0.25 * sc.particles.spacing, worst  # the collision guard keeps a gap of 0.25 dx
    # the water did reach the ring
    assert (np.abs(exact_distance(sc, x)) < 2 * sc.particles.spacing).sum() > 20


def test_mesh_obstacles_are_checked_when_the_scene_loads():
    with pytest.raises(SceneError, match=r"obstacles\[0\].file = 'meshes/none.stl': no such file"):
        scene("mesh_obstacle", "obstacles[0].file=meshes/none.stl")
    from conftest import scene_dict
    with pytest.raises(SceneError, match="mesh obstacles need a 3D scene"):
        scene_dict(scene={"dim": 2}, fluid={"blocks": [{"min": [0.1, 0.1], "max": [0.2, 0.2]}]},
                   domain={"size": [1.0, 1.0], "center": [0.5, 0.5]},
                   obstacles=[{"shape": "mesh", "file": str(CONFIGS / "meshes" / "torus.stl"), "center": [0.5, 0.5]}])


# --- the distance grid's size is checked before it is allocated (a scale that makes it huge, or
# the mesh smaller than a particle spacing, is a one-line SceneError, as a bad mesh file is) ---

def refusal(*overrides) -> str:
    """The SceneError of building the mesh_obstacle scene with ``overrides``: when it loads
    (check_mesh_obstacle) or when its walls are built (signed_distance_grid), whichever says it."""
    from sphcore.solver import Simulation
    with pytest.raises(SceneError) as e:
        Simulation(scene("mesh_obstacle", *overrides), "f64")
    text = str(e.value)
    assert "\n" not in text
    return text


def checked(tmp_path, **obstacle):
    """check_mesh_obstacle on mesh_obstacle's obstacle 0 with some of its keys changed (MeshCheckError,
    which the scene's loader reports as a SceneError)."""
    import dataclasses

    from sphcore.mesh_sdf import check_mesh_obstacle
    from sphcore.scene import mesh_path
    sc = scene("mesh_obstacle")
    sc = dataclasses.replace(sc, obstacles=(dataclasses.replace(sc.obstacles[0], **obstacle),))
    check_mesh_obstacle(sc, 0, mesh_path(sc, sc.obstacles[0]))


def test_the_grid_size_estimate_is_the_grid_built(tmp_path):
    from sphcore.boundaries import rotation_matrix
    from sphcore.mesh_sdf import _scaled_extent, grid_nodes, max_grid_nodes, read_mesh, signed_distance_grid
    from sphcore.scene import mesh_path
    for overrides in [("particles.spacing=0.03",), ("particles.spacing=0.04", "obstacles[0].rotation=[30,40,50]")]:
        sc = scene("mesh_obstacle", *overrides)
        ob, dx = sc.obstacles[0], sc.particles.spacing
        R, step, margin = rotation_matrix(ob.rotation), 0.5 * dx, (2.0 * sc.sph.support + 2.0) * dx
        _, _, values = signed_distance_grid(mesh_path(sc, ob), ob.center, ob.scale, R, step, margin)
        points = read_mesh(mesh_path(sc, ob)).clean().points
        assert grid_nodes(_scaled_extent(points, ob.scale, R), step, margin) == values.size
    assert grid_nodes([1e306, 1e306, 1.0], 0.01, 0.1) == np.inf and grid_nodes([np.inf, 1.0, 1.0], 0.01, 0.1) == np.inf
    assert max_grid_nodes() == 2**24


def test_a_scale_whose_grid_is_too_large_is_refused_before_it_is_built(tmp_path):
    """The reported case: obstacles[0].scale = 2 would make a 119 M-node grid (~3 GB just for the
    node coordinates VTK is given, ~6 min of VTK); it is refused at once, with the numbers and
    what would fit, and no grid is written."""
    from sphcore.mesh_sdf import MeshCheckError
    with pytest.raises(MeshCheckError) as e:
        checked(tmp_path, scale=2.0)
    text = str(e.value)
    for part in ["obstacles[0].scale = 2.0", "meshes/torus.stl", "about 1.19e+08 nodes", "GB of memory",
                 "limit of 16,777,216 nodes", "lower obstacles[0].scale to at most about 0.97",
                 "raise particles.spacing to at least about 0.0309"]:
        assert part in text, (part, text)
    text = refusal("obstacles[0].scale=2")  # at load (check_mesh_obstacle) or at the walls (signed_distance_grid)
    for part in ["scale", "2", "1.19e+08 nodes", "limit of 16,777,216 nodes", "particles.spacing"]:
        assert part in text, (part, text)
    assert not list((tmp_path / "cache").glob("sdf_*.npz"))
    checked(tmp_path, scale=0.6)  # 5 M nodes: allowed


def test_the_grid_limit_can_be_set_and_is_checked_where_the_grid_is_built(tmp_path, monkeypatch, capsys):
    """With a lower limit the small test grid (~79,000 nodes) is refused: by the walls' builder
    (signed_distance_grid) and, through the CLI, as one line and exit status 2."""
    from launch.cli import main
    from sphcore.boundaries import rotation_matrix
    from sphcore.mesh_sdf import signed_distance_grid
    from sphcore.scene import mesh_path
    sc = scene("mesh_obstacle", "particles.spacing=0.03")  # (with the limit set, the scene check refuses it)
    monkeypatch.setenv("SPH_MESH_GRID_MAX_NODES", "50000")
    ob = sc.obstacles[0]
    from sphcore.mesh_sdf import MeshCheckError
    with pytest.raises(MeshCheckError, match=r"'torus.stl' at scale 0.12: .* about 7\.\d+e\+04 nodes .* limit of 50,000"):
        signed_distance_grid(mesh_path(sc, ob), ob.center, ob.scale, rotation_matrix(ob.rotation), 0.015, 0.198)
    assert "limit of 50,000 nodes" in refusal("particles.spacing=0.03")
    rc = main(["scene", str(CONFIGS / "mesh_obstacle.toml"), "--set", "particles.spacing=0.03"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert err[0].startswith("sph scene: error: ") and "limit of 50,000 nodes" in err[0]


@pytest.mark.parametrize("scale", ["1e-300", "1e-06", "0.005"])
def test_a_mesh_smaller_than_a_particle_spacing_is_refused(scale, tmp_path):
    text = refusal(f"obstacles[0].scale={scale}")
    assert "less than the particle spacing (0.015 m)" in text and "would vanish" in text, text
    from sphcore.mesh_sdf import MeshCheckError
    with pytest.raises(MeshCheckError, match=rf"obstacles\[0\].scale = {float(scale)!r} .*would vanish\); raise "
                                         r"obstacles\[0\].scale to at least 0\.00556 "):
        checked(tmp_path, scale=float(scale))


def test_a_folder_or_an_open_mesh_is_refused_by_the_scene_check(tmp_path):
    from sphcore.mesh_sdf import MeshCheckError, placed_mesh
    folder = tmp_path / "dir.stl"
    folder.mkdir()
    with pytest.raises(SceneError, match=r"obstacles\[0\].file = .*dir.stl': .* is a folder, not a mesh file"):
        scene("mesh_obstacle", f"obstacles[0].file={str(folder)!r}")
    with pytest.raises(IsADirectoryError, match="is a folder"):
        placed_mesh(folder, [0, 0, 0], 1.0, np.eye(3))
    flat = tmp_path / "flat.stl"  # one triangle: no inside
    flat.write_text("solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\n"
                    "endfacet\nendsolid t\n")
    with pytest.raises(MeshCheckError, match=r"obstacles\[0\].file = .*flat.stl': the mesh is open \(3 boundary edges"):
        checked(tmp_path, file=str(flat), scale=0.1)
    with pytest.raises(SceneError, match=r"flat.stl': the mesh is open"):  # the loader reports it, naming the key
        scene("mesh_obstacle", f"obstacles[0].file={str(flat)!r}", "obstacles[0].scale=0.1")
    (tmp_path / "none.stl").write_text("solid t\nendsolid t\n")
    with pytest.raises(SceneError, match="no triangles"):  # the loader's own checks come first, as before
        scene("mesh_obstacle", f"obstacles[0].file={str(tmp_path / 'none.stl')!r}")


def test_every_shipped_mesh_obstacle_passes_the_scene_check(tmp_path):
    from sphcore.mesh_sdf import check_mesh_obstacle
    from sphcore.scene import load_scene, mesh_path
    found = 0
    for path in sorted(CONFIGS.glob("*.toml")):
        if 'shape = "mesh"' in path.read_text():
            sc = load_scene(path, [])
            for i, ob in enumerate(sc.obstacles):
                if ob.shape == "mesh":
                    check_mesh_obstacle(sc, i, mesh_path(sc, ob))
                    found += 1
    assert found >= 1
