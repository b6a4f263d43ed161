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
